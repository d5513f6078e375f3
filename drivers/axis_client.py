"""An Axis camera's HTTP client: the VAPIX session, its authentication, its timeouts and its errors.

:class:`AxisClient` is what every HTTP camera kind stands on (the ``axis`` kind's
:class:`~vts_hw.drivers.axis.AxisCamera` and the ``mjpeg`` kind): one ``requests`` session with
digest authentication (basic only over HTTPS, never in clear), a timeout on every call and on
the whole answer, and every failure one of the typed errors of :mod:`.axis_errors`, each with a
sentence that names the camera and says what to do. The password is held only in the auth
object: it is never part of a URL, a repr, a log line or an error message.
"""

from __future__ import annotations

import time

import requests
import urllib3
from requests.auth import HTTPBasicAuth, HTTPDigestAuth

from vts_hw.drivers.axis_errors import (
    AxisError,
    BadReply,
    CameraUnauthorized,
    CameraUnreachable,
    NotFound,
    Refused,
    TooManyViewers,
)

#: the most a camera's answer (other than a stream) may hold: a 4K JPEG is a few MiB
MAX_ANSWER = 64 * 2**20


class _AxisAuth(HTTPDigestAuth):
    """Answer a 401 challenge: digest always; basic only over HTTPS (never in clear)."""

    def handle_401(self, r, **kwargs):
        challenge = r.headers.get("www-authenticate", "")
        if "digest" in challenge.lower():
            return super().handle_401(r, **kwargs)
        if "basic" in challenge.lower() and r.url.lower().startswith("https://"):
            _ = r.content  # the 401 read whole, so its connection can be used again
            r.close()
            prep = r.request.copy()
            HTTPBasicAuth(self.username, self.password)(prep)
            _r = r.connection.send(prep, **kwargs)
            _r.history.append(r)
            _r.request = prep
            return _r
        return r

    def __repr__(self) -> str:  # never show the password
        return f"<AxisAuth user={self.username!r}>"


class AxisClient:
    """The HTTP side of one camera: ``request()`` and ``_text()`` with auth, timeouts and typed
    errors; ``close()`` (a context manager)."""

    error_class = AxisError  # what its reconnecting stream raises when it gives up

    def __init__(
        self,
        name: str,
        base_url: str,
        user: str | None = "root",
        password: str | None = None,
        *,
        timeout: float = 5.0,
        clock=time.time,
        verify: bool | str = True,
    ):
        self.name = name
        self.verify = verify if isinstance(verify, bool) else str(verify)  # HTTPS: the system's CAs, or a PEM file
        self.clock = clock  # host clock (UTC epoch s); a simulation on a virtual clock passes its own
        self.base_url = base_url.rstrip("/")
        self.user = user
        self.timeout = timeout
        self._auth = _AxisAuth(user, password) if (user and password is not None) else None
        self._session = self.new_session()

    def close(self) -> None:
        self._session.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- HTTP ----------------------------------------------------------------------
    def new_session(self) -> requests.Session:
        """A session of its own (a stream in a thread must not share connections)."""
        session = requests.Session()
        session.verify = self.verify
        return session

    def request(
        self,
        method: str,
        path: str,
        *,
        params=None,
        json_body=None,
        stream: bool = False,
        session: requests.Session | None = None,
        timeout=None,
    ) -> requests.Response:
        """One VAPIX request with auth and timeout; HTTP failures become typed errors."""
        url = self.base_url + path
        sess = session or self._session
        deadline = time.monotonic() + self.timeout
        try:
            # verify per request: requests lets REQUESTS_CA_BUNDLE override a session's verify;
            # the body is read here, against one deadline for the whole answer (a camera that
            # trickles a byte at a time never trips a per-read timeout)
            r = sess.request(
                method,
                url,
                params=params,
                json=json_body,
                auth=self._auth,
                stream=True,
                timeout=timeout or (self.timeout, self.timeout),
                verify=self.verify,
            )
            if not stream and r.status_code < 400 and r._content is False:  # not read yet
                self._read_whole(r, deadline, path)
        except requests.exceptions.SSLError as exc:
            raise CameraUnreachable(
                self.name,
                f"camera {self.name} at {self.base_url}: HTTPS failed "
                f"({_tls_reason(exc)}); if the camera has a self-signed "
                f"certificate, name it in rig.yaml (ca_cert:)",
            ) from None
        except requests.Timeout:
            raise CameraUnreachable(
                self.name, f"camera {self.name} at {self.base_url} did not answer within {self.timeout:g} s"
            ) from None
        except requests.ConnectionError as exc:
            raise CameraUnreachable(
                self.name, f"camera {self.name} at {self.base_url} is unreachable ({_reason(exc)})"
            ) from None
        except urllib3.exceptions.ReadTimeoutError:
            raise CameraUnreachable(
                self.name, f"camera {self.name} at {self.base_url} did not answer within {self.timeout:g} s"
            ) from None
        except (
            requests.exceptions.ChunkedEncodingError,  # the body cut short of its Content-Length
            urllib3.exceptions.HTTPError,
        ):
            raise CameraUnreachable(
                self.name,
                f"camera {self.name} at {self.base_url} closed the connection in the middle of its answer to {path}",
            ) from None
        self.check_status(r)
        return r

    def _read_whole(self, r: requests.Response, deadline: float, path: str) -> None:
        """The body of ``r``, whole by ``deadline`` (monotonic) and at most ``MAX_ANSWER`` bytes,
        else a camera error naming the camera; the response then answers ``.content`` from memory."""
        body = bytearray()
        try:
            while chunk := r.raw.read1(65536, decode_content=True):  # what has come, not a block
                body += chunk
                if time.monotonic() > deadline:
                    raise CameraUnreachable(
                        self.name,
                        f"camera {self.name} at {self.base_url} did not send its "
                        f"answer to {path} within {self.timeout:g} s ({len(body)} "
                        f"bytes came, slowly)",
                    )
                if len(body) > MAX_ANSWER:
                    raise BadReply(
                        self.name, f"camera {self.name} answered {path} with more than {MAX_ANSWER // 2**20} MiB"
                    )
        except BaseException:
            r.close()
            raise
        r._content = bytes(body)
        r._content_consumed = True

    def check_status(self, r: requests.Response) -> None:
        if r.status_code == 401:
            r.close()
            challenge = r.headers.get("www-authenticate", "").lower()
            if challenge.startswith("basic") and not r.url.lower().startswith("https://"):
                raise CameraUnauthorized(
                    self.name,
                    f"camera {self.name} asks for basic authentication over "
                    f"plain http, which would send the password in clear: "
                    f"use scheme: https (or digest on the camera)",
                )
            if self._auth is None:
                raise CameraUnauthorized(
                    self.name,
                    f"camera {self.name} asks for a password and the rig config gives none (set password_env)",
                )
            raise CameraUnauthorized(
                self.name, f"camera {self.name} refused user {self.user!r} (HTTP 401): check the password"
            )
        if r.status_code == 503:
            r.close()
            raise TooManyViewers(
                self.name, f"camera {self.name} has too many viewers (HTTP 503): close other streams and try again"
            )
        if r.status_code == 404:
            r.close()
            raise NotFound(self.name, f"camera {self.name} does not know {r.request.path_url.split('?')[0]} (HTTP 404)")
        if r.status_code >= 400:
            r.close()
            raise BadReply(
                self.name, f"camera {self.name} answered HTTP {r.status_code} to {r.request.path_url.split('?')[0]}"
            )

    def _text(self, path: str, params=None) -> str:
        r = self.request("GET", path, params=params)
        text = r.text
        stripped = text.lstrip()
        if stripped.startswith("# Error:") or stripped.startswith("Error:"):
            msg = (stripped.split(":", 1)[1].strip().splitlines() or ["(no reason given)"])[0]
            raise Refused(self.name, f"camera {self.name} refused {path}: {msg}")
        return text


def _tls_reason(exc: Exception) -> str:
    return _first_said(
        exc,
        "TLS error",
        ("CERTIFICATE_VERIFY_FAILED", "the camera's certificate could not be verified"),
        ("WRONG_VERSION_NUMBER", "the camera does not speak HTTPS on that port"),
        ("Hostname mismatch", "the certificate is for another host"),
        ("doesn't match", "the certificate is for another host"),
    )


def _reason(exc: Exception) -> str:
    return _first_said(
        exc,
        type(exc).__name__,
        ("Connection refused", "connection refused"),
        ("Name or service not known", "unknown host"),
        ("timed out", "timed out"),
        ("reset by peer", "connection reset"),
        ("RemoteDisconnected", "connection closed by the camera"),
    )


def _first_said(exc: Exception, otherwise: str, *table: tuple[str, str]) -> str:
    """The words of the first key of ``table`` in ``exc``'s text, else ``otherwise``."""
    text = str(exc)
    return next((words for key, words in table if key in text), otherwise)


__all__ = ["AxisClient", "MAX_ANSWER"]
