"""A small client of QATrack+'s REST API (the part the push uses), over requests.

What it relies on (qatrackplus/qatrackplus, qatrack/api/ and docs/api/guide.rst):
- token authentication: header ``Authorization: Token KEY``; a token for a user and password
  from ``POST api/get-token/`` (``{"token": ...}``);
- ``GET api/qa/unittestcollections/?unit__name=U&test_list__name=L&active=true``: the unit's
  assignment of a test list (paginated ``{count, next, previous, results}``, each with ``url``);
- ``GET api/qa/testlistinstances/?user_key=K``: the instances posted with that key (the
  ``user_key`` field is unique in QATrack+; a second post with it is a 400);
- ``POST api/qa/testlistinstances/`` (JSON): 201 with the new instance (its ``url``); 400
  with Django REST framework's error shape (``{"field": ["message"]}``, ``non_field_errors``,
  or ``{"detail": "message"}``).

Errors are three kinds, each one sentence without any credential:
``Unreachable`` (down, timeout, 5xx, 429: try again later), ``Refused`` (a 4xx about what was
sent: the user must fix something), ``AuthRefused`` (401/403, or get-token said no).
"""

from __future__ import annotations

import re
import time
from urllib.parse import urljoin, urlsplit

import requests

from vts_hw.errors import VtsError

#: the longest answer read from QATrack+ (its pages of instances are far shorter)
MAX_ANSWER = 32 * 2**20


class QATrackError(VtsError):
    """Something went wrong talking to QATrack+ (the message is one sentence)."""

    exit_code = 3


class Unreachable(QATrackError):
    """QATrack+ did not answer usefully (down, timeout, 5xx, 429): worth trying again later."""

    def __init__(self, message: str, down: bool = False):
        super().__init__(message)
        self.down = down  # not listening / not answering at all (vs. one request failing)


class Refused(QATrackError):
    """QATrack+ refused a request (4xx): ``words`` is its own message."""

    exit_code = 4

    def __init__(self, message: str, status: int, words: str, body=None):
        super().__init__(message)
        self.status, self.words, self.body = status, words, body


class AuthRefused(Refused):
    """QATrack+ refused the credentials (401/403, or get-token refused the user/password)."""


def drf_words(body, limit: int = 400) -> str:
    """QATrack+'s own words from a Django REST framework error body, on one line:
    ``{"detail": m}`` -> m; ``{"field": [m, ...]}`` -> "field: m"; ``non_field_errors`` -> m."""
    parts: list[str] = []

    def walk(value, field="", depth=0):
        if depth > 20:  # QATrack+'s errors are shallow; a deeper body is not one
            return
        if isinstance(value, dict):
            for k, v in value.items():
                walk(v, "" if k in ("detail", "non_field_errors") else (f"{field}.{k}" if field else str(k)), depth + 1)
        elif isinstance(value, list):
            for v in value:
                walk(v, field, depth + 1)
        elif value is not None:
            text = " ".join(str(value).split())
            parts.append(f"{field}: {text}" if field else text)

    walk(body)
    words = "; ".join(parts) or "(no message)"
    return words if len(words) <= limit else words[: limit - 3] + "..."


class QATrackClient:
    """Talks to one QATrack+ site. ``credentials`` is ``("token", T)`` or ``("login", USER, PW)``
    (config_qatrack.QATrackConfig.credentials()); the token is asked for on first use."""

    def __init__(self, url: str, credentials: tuple, timeout: float = 10.0, session=None):
        self.url = url if url.endswith("/") else url + "/"
        self.api = self.url + "api/"
        self.timeout = float(timeout)
        self._credentials = tuple(credentials)
        self._token: str | None = self._credentials[1] if self._credentials[0] == "token" else None
        self._session = session or requests.Session()
        self._utc: dict[tuple[str, str], str] = {}
        self._shown_times: list[str] = []

    def close(self) -> None:
        self._session.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- plumbing ---------------------------------------------------------------------------

    def _scrub(self, text: str) -> str:
        for secret in self._credentials[1:] + ((self._token,) if self._token else ()):
            if secret:
                text = text.replace(secret, "***")
        return text

    def _send(self, method: str, url: str, *, auth: bool = True, **kw) -> requests.Response:
        """One request, read whole within ``timeout`` seconds (a server that trickles its answer
        is as unreachable as one that does not answer); errors as the module says."""
        where = urlsplit(url)._replace(query="").geturl()
        headers = {"Accept": "application/json"}
        if auth:
            headers["Authorization"] = f"Token {self.token()}"
        deadline = time.monotonic() + self.timeout
        try:
            resp = self._session.request(
                method, url, headers=headers, timeout=self.timeout, allow_redirects=False, stream=True, **kw
            )
            if resp._content is False:  # not read yet (a session that answers from memory has read it)
                with resp:
                    body = bytearray()
                    while chunk := resp.raw.read1(65536, decode_content=True):  # what has come, not a block
                        body += chunk
                        if time.monotonic() > deadline:
                            raise requests.Timeout()
                        if len(body) > MAX_ANSWER:
                            raise Unreachable(
                                f"QATrack+ answered {method} {where} with more than {MAX_ANSWER // 2**20} MiB",
                                down=False,
                            )
                    resp._content = bytes(body)
        except requests.Timeout:
            raise Unreachable(
                f"QATrack+ did not answer within {self.timeout:g} s ({method} {where})", down=True
            ) from None
        except requests.ConnectionError as exc:
            reason = self._scrub(str(exc))
            short = "connection refused" if "refused" in reason.lower() else "cannot connect"
            raise Unreachable(f"QATrack+ is not reachable at {self.url} ({short})", down=True) from None
        except requests.RequestException as exc:
            raise Unreachable(
                f"QATrack+ request failed ({method} {where}: {self._scrub(type(exc).__name__)})", down=True
            ) from None
        if resp.status_code >= 500 or resp.status_code == 429:
            raise Unreachable(
                f"QATrack+ answered {resp.status_code} {resp.reason or ''}".rstrip()
                + f" to {method} {where}: {self._scrub(drf_words(_json(resp)))}"
            )
        if 300 <= resp.status_code < 400:
            target = resp.headers.get("Location", "?")
            if "/accounts/login" in target or not urlsplit(target).path.startswith(urlsplit(self.api).path):
                why = (
                    f"qatrack.url {self.url} is not the QATrack+ site's root: the site sent {method} {where} "
                    f"to {target} (its login page) instead of answering its API"
                )
            else:
                why = (
                    f"QATrack+ redirected {method} {where} to {target} (is qatrack.url the site's root, "
                    f"with the right scheme?)"
                )
            raise Refused(why, resp.status_code, "redirect")
        if resp.status_code >= 400:
            words = self._scrub(drf_words(_json(resp)))
            if resp.status_code == 403:
                raise AuthRefused(
                    f"QATrack+ does not let this user {method} {where} (403): {words} "
                    f"(the user of the token needs the permission qa.add_testlistinstance)",
                    403,
                    words,
                    _json(resp),
                )
            if resp.status_code == 404 and not isinstance(_json(resp, None), dict):
                raise Refused(
                    f"QATrack+ has no {where} (404: {words}): is qatrack.url the root of a QATrack+ 3 site?", 404, words
                )
            kind = AuthRefused if resp.status_code == 401 else Refused
            raise kind(
                f"QATrack+ refused {method} {where} ({resp.status_code}): {words}", resp.status_code, words, _json(resp)
            )
        return resp

    def _get_json(self, url: str, params=None) -> dict:
        resp = self._send("GET", url, params=params)
        body = _json(resp)
        if not isinstance(body, dict):
            raise Unreachable(f"QATrack+ answered GET {url} with something that is not a JSON object")
        return body

    def _all(self, url: str, params: dict) -> list[dict]:
        """Every result of a paginated list (following ``next`` on the same site)."""
        body = self._get_json(url, params)
        out = _results(body, url)
        pages = 0
        while body.get("next") and pages < 100:
            if not isinstance(body["next"], str):
                raise Unreachable(f"QATrack+ answered GET {url} with a next page that is not a link")
            nxt = urljoin(self.api, body["next"])
            if urlsplit(nxt).netloc != urlsplit(self.api).netloc:
                break  # never send the token to another host
            body = self._get_json(nxt)
            out += _results(body, url)
            pages += 1
        return out

    # -- the API ----------------------------------------------------------------------------

    def token(self) -> str:
        """The API token (asked for at api/get-token/ with the user and password the first time)."""
        if self._token is None:
            _, user, password = self._credentials
            try:
                resp = self._send(
                    "POST", self.api + "get-token/", auth=False, data={"username": user, "password": password}
                )
            except Refused as exc:
                raise AuthRefused(
                    f"QATrack+ refused the user and password at api/get-token/ ({exc.status}): {exc.words}",
                    exc.status,
                    exc.words,
                ) from None
            token = _json(resp).get("token") if isinstance(_json(resp), dict) else None
            if not token:
                raise Unreachable("QATrack+ answered api/get-token/ without a token")
            self._token = str(token)
        return self._token

    def assignment(self, unit: str, test_list: str) -> str:
        """The URL of the unit's (active) assignment of ``test_list``; Refused when there is
        none or more than one."""
        key = (unit, test_list)
        if key not in self._utc:
            found = self._all(
                self.api + "qa/unittestcollections/",
                {"unit__name": unit, "test_list__name": test_list, "active": "true"},
            )
            if not found:
                raise Refused(
                    f"QATrack+ has no active assignment of test list {test_list!r} to unit "
                    f"{unit!r} (check qatrack.unit and the test_list name)",
                    404,
                    "not found",
                )
            if len(found) > 1:
                raise Refused(
                    f"QATrack+ has {len(found)} active assignments of test list {test_list!r} to "
                    f"unit {unit!r}; the push needs exactly one",
                    409,
                    "ambiguous",
                )
            if not isinstance(found[0].get("url"), str) or not found[0]["url"]:
                raise Unreachable(
                    f"QATrack+ listed the assignment of test list {test_list!r} to unit {unit!r} without its url"
                )
            self._utc[key] = str(found[0]["url"])
            self._shown_times += [t for t in (found[0].get("due_date"),) if isinstance(t, str)]
        return self._utc[key]

    def shown_times(self) -> list[str]:
        """Times as the site shows them, with its UTC offset (an assignment's due date, the newest
        instances' creation): what tells whether ``qatrack.time_zone`` is the site's zone."""
        url = self.api + "qa/testlistinstances/"
        body = self._get_json(url, {"limit": 5, "ordering": "-created"})
        for r in _results(body, url):
            self._shown_times += [r[k] for k in ("created", "work_completed") if isinstance(r.get(k), str)]
        return list(self._shown_times)

    def instance_with_key(self, user_key: str) -> str | None:
        """The URL of the test list instance posted with ``user_key``, None when there is none."""
        url = self.api + "qa/testlistinstances/"
        results = _results(self._get_json(url, {"user_key": user_key}), url)
        return str(results[0].get("url") or results[0].get("site_url") or "") if results else None

    def create_instance(self, payload: dict) -> dict:
        """POST a test list instance; its JSON (with ``url``)."""
        body = _json(self._send("POST", self.api + "qa/testlistinstances/", json=payload))
        if not isinstance(body, dict):
            raise Unreachable("QATrack+ answered the new test list instance with something that is not JSON")
        return body


def _results(body: dict, url: str) -> list[dict]:
    """The ``results`` of one page of a list: objects, or Unreachable naming the list."""
    results = body.get("results") or []
    if not isinstance(results, list) or not all(isinstance(r, dict) for r in results):
        raise Unreachable(f"QATrack+ answered GET {url} with results that are not a list of objects")
    return results


_NOT_JSON = object()


def _json(resp, fallback=_NOT_JSON):
    """The answer's JSON; for an answer that is not JSON, ``fallback`` when given, else
    ``{"detail": ...}`` with its HTML title or first words."""
    try:
        return resp.json()
    except (ValueError, RecursionError):  # not JSON, or nested too deeply to read
        if fallback is not _NOT_JSON:
            return fallback
        text = resp.text or ""
        title = re.search(r"<title>(.*?)</title>", text, re.I | re.S)
        text = " ".join((title.group(1) if title else text).split())
        return {"detail": text[:200] or f"HTTP {resp.status_code}"}
