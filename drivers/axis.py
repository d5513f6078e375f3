"""Axis network camera over VAPIX: snapshot, stream, parameters, LED output (and its state), info, clock.

One :class:`AxisCamera` per camera, built on requests with digest authentication (basic only
over HTTPS, never in clear). Every call has a timeout, and every failure is one of the typed
errors of :mod:`.axis_errors` (re-exported here), each with a sentence that names the camera and
says what to do. The password is held only in the auth object: it is never part of a URL, a
repr, a log line or an error message.

Old firmware (VAPIX 2, e.g. an AXIS 211 on 4.4x) is told apart by a 404 on ``param.cgi`` and is
answered on its own paths: ``view/`` and ``admin/param.cgi``, ``io/output.cgi`` for the LED (and its state),
the Brand and Properties parameters for the device info, the JPEG stamps for the clock.
"""

from __future__ import annotations

import statistics
import time
from datetime import datetime, timezone
from typing import TYPE_CHECKING
from urllib.parse import quote

import requests
import urllib3
from requests.auth import HTTPBasicAuth, HTTPDigestAuth

from vts_hw.camera import ClockOffset, Frame, check_whole
from vts_hw.camera_stream import FrameStream
from vts_hw.drivers.axis_errors import (NOT_THE_JSON, AxisError, BadReply, CameraUnauthorized, CameraUnreachable,
                                        NotFound, Refused, TooManyViewers)
from vts_hw.drivers.axis_stream import MultipartConnection, num
from vts_hw.drivers.axis_uptime import read_uptime
from vts_hw.recording.axis_jpeg import inspect_jpeg

if TYPE_CHECKING:
    from vts_hw.config import CameraConfig


#: the most a camera's answer (other than a stream) may hold: a 4K JPEG is a few MiB
MAX_ANSWER = 64 * 2**20


class _AxisAuth(HTTPDigestAuth):
    """Answer a 401 challenge: digest always; basic only over HTTPS (never in clear)."""

    def handle_401(self, r, **kwargs):
        challenge = r.headers.get("www-authenticate", "")
        if "digest" in challenge.lower():
            return super().handle_401(r, **kwargs)
        if "basic" in challenge.lower() and r.url.lower().startswith("https://"):
            r.content
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


def frame_from_bytes(seq: int, jpeg: bytes, host_time: float, problems=()) -> Frame:
    """A Frame with the camera time read from the JPEG's Axis segment (None if absent)."""
    probs = list(problems)
    cam_t = None
    try:
        info = inspect_jpeg(jpeg)
        cam_t = info.timestamp
        probs += [p for p in info.problems if p not in probs and "product" not in p]
    except Exception as exc:  # not a JPEG at all
        probs.append(str(exc))
    return Frame(seq, jpeg, cam_t, host_time, tuple(probs))


class AxisCamera:
    """One Axis camera: the ``axis`` kind of :class:`vts_hw.camera.Camera`.

    ``AxisCamera.from_config(cfg)`` takes a rig.yaml camera entry and its password from the
    environment variable that entry names (``vts_hw.drivers.registry.open_camera`` calls it).
    """

    led_switches = True
    error_class = AxisError   # what its reconnecting stream raises when it gives up
    stream_path = "/axis-cgi/mjpg/video.cgi"

    def __init__(self, name: str, base_url: str, user: str | None = "root", password: str | None = None,
                 *, timeout: float = 5.0, led_port: int = 1, resolution: str = "640x480",
                 fps: float = 25.0, compression: int = 25, clock=time.time, verify: bool | str = True):
        self.name = name
        self.verify = verify if isinstance(verify, bool) else str(verify)  # HTTPS: the system's CAs, or a PEM file
        self.clock = clock  # host clock (UTC epoch s); a simulation on a virtual clock passes its own
        self.base_url = base_url.rstrip("/")
        self.user = user
        self.timeout = timeout
        self.led_port = led_port
        self.resolution = resolution
        self.fps = fps
        self.compression = compression
        self._auth = _AxisAuth(user, password) if (user and password is not None) else None
        self._session = self.new_session()
        self._vapix: int | None = None
        self._output_cgi = "/axis-cgi/io/port.cgi"  # io/output.cgi on VAPIX 2 firmware

    @classmethod
    def from_config(cls, cfg: "CameraConfig", clock=time.time) -> "AxisCamera":
        return cls(cfg.name, cfg.base_url, cfg.user, cfg.password(), timeout=cfg.timeout_s,
                   led_port=cfg.led_port, resolution=cfg.resolution_str, fps=cfg.fps,
                   compression=cfg.compression, clock=clock, verify=cfg.ca_cert or True)

    def __repr__(self) -> str:
        return f"AxisCamera({self.name!r}, {self.base_url!r}, user={self.user!r})"

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

    def request(self, method: str, path: str, *, params=None, json_body=None, stream: bool = False,
                session: requests.Session | None = None, timeout=None) -> requests.Response:
        """One VAPIX request with auth and timeout; HTTP failures become typed errors."""
        url = self.base_url + path
        sess = session or self._session
        deadline = time.monotonic() + self.timeout
        try:
            # verify per request: requests lets REQUESTS_CA_BUNDLE override a session's verify;
            # the body is read here, against one deadline for the whole answer (a camera that
            # trickles a byte at a time never trips a per-read timeout)
            r = sess.request(method, url, params=params, json=json_body, auth=self._auth, stream=True,
                             timeout=timeout or (self.timeout, self.timeout), verify=self.verify)
            if not stream and r.status_code < 400 and r._content is False:   # not read yet
                self._read_whole(r, deadline, path)
        except requests.exceptions.SSLError as exc:
            raise CameraUnreachable(self.name, f"camera {self.name} at {self.base_url}: HTTPS failed "
                                               f"({_tls_reason(exc)}); if the camera has a self-signed "
                                               f"certificate, name it in rig.yaml (ca_cert:)") from None
        except requests.Timeout:
            raise CameraUnreachable(self.name, f"camera {self.name} at {self.base_url} did not answer "
                                               f"within {self.timeout:g} s") from None
        except requests.ConnectionError as exc:
            raise CameraUnreachable(self.name, f"camera {self.name} at {self.base_url} is unreachable "
                                               f"({_reason(exc)})") from None
        except urllib3.exceptions.ReadTimeoutError:
            raise CameraUnreachable(self.name, f"camera {self.name} at {self.base_url} did not answer "
                                               f"within {self.timeout:g} s") from None
        except (requests.exceptions.ChunkedEncodingError,    # the body cut short of its Content-Length
                urllib3.exceptions.HTTPError):
            raise CameraUnreachable(self.name, f"camera {self.name} at {self.base_url} closed the connection "
                                               f"in the middle of its answer to {path}") from None
        self.check_status(r)
        return r

    def _read_whole(self, r: requests.Response, deadline: float, path: str) -> None:
        """The body of ``r``, whole by ``deadline`` (monotonic) and at most ``MAX_ANSWER`` bytes,
        else a camera error naming the camera; the response then answers ``.content`` from memory."""
        body = bytearray()
        try:
            while chunk := r.raw.read1(65536, decode_content=True):   # what has come, not a block
                body += chunk
                if time.monotonic() > deadline:
                    raise CameraUnreachable(self.name, f"camera {self.name} at {self.base_url} did not send its "
                                                       f"answer to {path} within {self.timeout:g} s ({len(body)} "
                                                       f"bytes came, slowly)")
                if len(body) > MAX_ANSWER:
                    raise BadReply(self.name, f"camera {self.name} answered {path} with more than "
                                              f"{MAX_ANSWER // 2**20} MiB")
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
                raise CameraUnauthorized(self.name, f"camera {self.name} asks for basic authentication over "
                                                    f"plain http, which would send the password in clear: "
                                                    f"use scheme: https (or digest on the camera)")
            if self._auth is None:
                raise CameraUnauthorized(self.name, f"camera {self.name} asks for a password and the "
                                                    f"rig config gives none (set password_env)")
            raise CameraUnauthorized(self.name, f"camera {self.name} refused user {self.user!r} (HTTP 401): "
                                                f"check the password")
        if r.status_code == 503:
            r.close()
            raise TooManyViewers(self.name, f"camera {self.name} has too many viewers (HTTP 503): "
                                            f"close other streams and try again")
        if r.status_code == 404:
            r.close()
            raise NotFound(self.name, f"camera {self.name} does not know {r.request.path_url.split('?')[0]} "
                                      f"(HTTP 404)")
        if r.status_code >= 400:
            r.close()
            raise BadReply(self.name, f"camera {self.name} answered HTTP {r.status_code} to "
                                      f"{r.request.path_url.split('?')[0]}")

    def _text(self, path: str, params=None) -> str:
        r = self.request("GET", path, params=params)
        text = r.text
        stripped = text.lstrip()
        if stripped.startswith("# Error:") or stripped.startswith("Error:"):
            msg = (stripped.split(":", 1)[1].strip().splitlines() or ["(no reason given)"])[0]
            raise Refused(self.name, f"camera {self.name} refused {path}: {msg}")
        return text

    # -- images --------------------------------------------------------------------
    def snapshot(self, compression: int | None = None) -> Frame:
        """One JPEG from ``jpg/image.cgi``, with its camera time and host receive time.

        ``compression`` (0-100, VAPIX) overrides the configured one for this request only: the
        camera's own settings, and so its stream, are left as they are."""
        comp = self.compression if compression is None else int(compression)
        if not 0 <= comp <= 100:
            raise ValueError(f"compression must be 0-100, not {comp}")
        r = self.request("GET", "/axis-cgi/jpg/image.cgi",
                         params={"resolution": self.resolution, "compression": comp})
        data = r.content
        host_t = self.clock()
        ctype = r.headers.get("content-type", "")
        if not data.startswith(b"\xff\xd8"):
            raise BadReply(self.name, f"camera {self.name} sent {ctype or 'data'} instead of a JPEG")
        frame = frame_from_bytes(0, data, host_t)
        check_whole(frame, self.name)
        return frame

    def make_frame(self, seq: int, jpeg: bytes, host_time: float, problems=()) -> Frame:
        """A received JPEG as a Frame, timed by its Axis stamp."""
        return frame_from_bytes(seq, jpeg, host_time, problems)

    def open_stream(self, *, fps: float, duration: float | None = None, nbrofframes: int | None = None,
                    first_seq: int = 0, stall_timeout: float = 2.0):
        """One connection of ``mjpg/video.cgi`` (the camera ends it after ``duration`` s or
        ``nbrofframes`` frames when asked)."""
        params: dict[str, object] = {"resolution": self.resolution, "fps": num(fps),
                                     "compression": self.compression}
        if duration is not None:
            params["duration"] = max(1, int(duration + 0.999))
        if nbrofframes is not None:
            params["nbrofframes"] = nbrofframes
        return MultipartConnection(self, self.stream_path, params, stall_timeout=stall_timeout,
                                   first_seq=first_seq, make_frame=self.make_frame)

    def stream(self, **kwargs) -> FrameStream:
        """Frames that reconnect on drops and stalls, with gaps (vts_hw.camera_stream)."""
        return FrameStream(self, **kwargs)

    # -- parameters ----------------------------------------------------------------
    @property
    def vapix_version(self) -> int:
        """3 when ``/axis-cgi/param.cgi`` exists, else 2 (``view/`` and ``admin/param.cgi``)."""
        if self._vapix is None:
            try:
                self._text("/axis-cgi/param.cgi", {"action": "list", "group": "Brand"})
                self._vapix = 3
            except NotFound:
                self._text("/axis-cgi/view/param.cgi", {"action": "list", "group": "Brand"})
                self._vapix = 2
        return self._vapix

    def get_params(self, group: str) -> dict[str, str]:
        """``root.``-less parameter names and values of a group, e.g. ``Image.I0``."""
        path = "/axis-cgi/param.cgi" if self.vapix_version == 3 else "/axis-cgi/view/param.cgi"
        text = self._text(path, {"action": "list", "group": group})
        out = {}
        for line in text.splitlines():
            if "=" in line:
                k, v = line.split("=", 1)
                out[k.strip().removeprefix("root.")] = v.strip()
        if not out:
            raise BadReply(self.name, f"camera {self.name} listed no parameters in group {group!r}")
        return out

    def set_params(self, values: dict[str, object]) -> None:
        path = "/axis-cgi/param.cgi" if self.vapix_version == 3 else "/axis-cgi/admin/param.cgi"
        params = {"action": "update"}
        params.update({k: str(v) for k, v in values.items()})
        text = self._text(path, params)
        if text.strip() != "OK":
            raise BadReply(self.name, f"camera {self.name} did not confirm the update: {text.strip()[:80]!r}")

    # -- LED on the I/O output port -------------------------------------------------
    def _io(self, ask) -> str:
        """``port.cgi``'s answer to ``ask(cgi)`` (a path and its query), else ``output.cgi``'s
        (firmware before 5.00: port.cgi answers 404), remembered for the next call."""
        try:
            return self._text(*ask(self._output_cgi))
        except NotFound:
            if self._output_cgi == "/axis-cgi/io/output.cgi":
                raise
            self._output_cgi = "/axis-cgi/io/output.cgi"
            return self._text(*ask(self._output_cgi))

    def _port(self, action: str) -> None:
        # port.cgi (output.cgi on VAPIX 2) wants the action characters percent-encoded (/ and \)
        query = "?action=" + quote(action, safe=":")
        text = self._io(lambda cgi: (cgi + query,))
        if text.strip() and not text.strip().upper().startswith("OK"):
            cgi = self._output_cgi.rsplit("/", 1)[-1]
            raise BadReply(self.name, f"camera {self.name}: {cgi} answered {text.strip()[:80]!r}")

    def led_on(self) -> None:
        self._port(f"{self.led_port}:/")

    def led_off(self) -> None:
        self._port(f"{self.led_port}:\\")

    def led_pulse(self, ms: int) -> None:
        if not 1 <= int(ms) <= 60000:
            raise ValueError("LED pulse must be 1 to 60000 ms")
        self._port(f"{self.led_port}:/{int(ms)}\\")

    def led_state(self) -> bool | None:
        """Whether the LED's output port is active now, as the camera says: ``port.cgi?checkactive=N``
        answers ``portN=active`` or ``portN=inactive``; VAPIX 2's ``output.cgi?check=N``, ``outputN=1`` or 0."""
        n = self.led_port
        got = self._io(lambda cgi: (cgi, {"checkactive" if cgi.endswith("port.cgi") else "check": n})).strip()
        states = {f"port{n}=active": True, f"port{n}=inactive": False, f"output{n}=1": True, f"output{n}=0": False}
        if got not in states:
            cgi = self._output_cgi.rsplit("/", 1)[-1]
            raise BadReply(self.name, f"camera {self.name}: {cgi} answered {got[:80]!r} when asked the state of "
                                      f"output port {n} (the LED)")
        return states[got]

    # -- device info and clock -------------------------------------------------------
    def device_info(self) -> dict[str, str]:
        """Brand, product, serial number and firmware: basicdeviceinfo.cgi, else param groups."""
        try:
            r = self.request("POST", "/axis-cgi/basicdeviceinfo.cgi",
                             json_body={"apiVersion": "1.0", "method": "getAllProperties"})
            props = r.json()["data"]["propertyList"]
            return {k: str(v) for k, v in props.items()}
        except NotFound:
            pass
        except NOT_THE_JSON:
            raise BadReply(self.name, f"camera {self.name} sent device info that is not the expected JSON") \
                from None
        info = {k.removeprefix("Brand."): v for k, v in self.get_params("Brand").items()}
        props = self.get_params("Properties")
        for key, name in _DEVICE_INFO_PARAMS.items():
            if name in props:
                info[key] = props[name]
        return info

    def uptime(self):
        """How long the camera has run since it started (drivers/axis_uptime.py)."""
        return read_uptime(self)

    def clock_offset(self, samples: int = 5) -> ClockOffset:
        """Camera clock minus host clock.

        From ``time.cgi`` (ms resolution, midpoint of the round trip, best of ``samples``)
        where the camera has it, else from the 10 ms stamps of snapshots (each stamp is
        taken before the image is sent, so the offset is biased low by up to the exposure
        and encode time; the uncertainty says so).
        """
        best = None
        try:
            for _ in range(samples):
                t0 = self.clock()
                r = self.request("POST", "/axis-cgi/time.cgi",
                                 json_body={"apiVersion": "1.0", "method": "getDateTimeInfo"})
                t1 = self.clock()
                cam = _parse_iso(r.json()["data"]["dateTime"])
                rtt = t1 - t0
                if best is None or rtt < best[1]:
                    best = (cam - (t0 + t1) / 2, rtt, (t0 + t1) / 2)
            return ClockOffset(best[0], best[1] / 2 + 0.001, best[2], "time.cgi", samples)
        except NotFound:
            pass
        except NOT_THE_JSON:
            raise BadReply(self.name, f"camera {self.name} sent time.cgi JSON without a readable data.dateTime") \
                from None
        offsets, rtts = [], []
        for _ in range(samples):
            t0 = self.clock()
            f = self.snapshot()
            if f.camera_time is None:
                raise BadReply(self.name, f"camera {self.name} sends JPEGs without the Axis time segment")
            offsets.append(f.camera_time - t0)
            rtts.append(f.host_time - t0)
        return ClockOffset(statistics.median(offsets), max(rtts) + 0.01, self.clock(), "snapshot", samples)


_DEVICE_INFO_PARAMS = {  # basicdeviceinfo.cgi property -> parameter, for firmware without it
    "Version": "Properties.Firmware.Version", "BuildDate": "Properties.Firmware.BuildDate",
    "SerialNumber": "Properties.System.SerialNumber", "HardwareID": "Properties.System.HardwareID",
    "Architecture": "Properties.System.Architecture", "Soc": "Properties.System.Soc",
}


def _tls_reason(exc: Exception) -> str:
    text = str(exc)
    for key, words in (("CERTIFICATE_VERIFY_FAILED", "the camera's certificate could not be verified"),
                       ("WRONG_VERSION_NUMBER", "the camera does not speak HTTPS on that port"),
                       ("Hostname mismatch", "the certificate is for another host"),
                       ("doesn't match", "the certificate is for another host")):
        if key in text:
            return words
    return "TLS error"


def _parse_iso(s: str) -> float:
    s = s.strip().replace("Z", "+00:00")
    dt = datetime.fromisoformat(s)
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=timezone.utc)
    return dt.timestamp()


def _reason(exc: Exception) -> str:
    text = str(exc)
    for key, words in (("Connection refused", "connection refused"),
                       ("Name or service not known", "unknown host"),
                       ("timed out", "timed out"),
                       ("reset by peer", "connection reset"),
                       ("RemoteDisconnected", "connection closed by the camera")):
        if key in text:
            return words
    return type(exc).__name__


__all__ = ["AxisCamera", "AxisError", "CameraUnreachable", "CameraUnauthorized", "TooManyViewers",
           "BadReply", "NotFound", "Refused", "Frame", "ClockOffset", "frame_from_bytes"]
