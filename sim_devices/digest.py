"""Server-side HTTP digest authentication (RFC 7616 / RFC 2617), as an Axis camera does it
(and :class:`BasicAuth`, for cameras set to basic).

Only what the simulated cameras need: algorithm MD5, ``qop="auth"`` (and the old RFC 2069
form without qop), a realm such as ``AXIS_ACCC8E192567``, a fixed per-server ``opaque`` and
stateless nonces that expire.

A nonce is ``<issue time, hex ms>.<random>.<HMAC of both>``: the server can check that it
made the nonce and how old it is without keeping a table. An expired but genuine nonce is
answered with ``stale=true`` so that clients retry at once with a fresh one and without
asking the user again.

The nonce count ``nc`` is checked leniently: it must be present and hexadecimal when qop is
used, but repeats and gaps are accepted (FFmpeg, curl and requests each count differently
across reconnects, and replay protection is not the point of a simulator).

Usage::

    auth = DigestAuth(realm="AXIS_ACCC8E192567", user="root", password="pass")
    result = auth.check("GET", request.headers.get("Authorization"), request_target)
    if not result.ok:
        send 401 with header ("WWW-Authenticate", auth.challenge(stale=result.stale))
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass
from urllib.parse import urlsplit

__all__ = ["DigestAuth", "BasicAuth", "AuthResult", "parse_auth_params", "digest_response"]


@dataclass(frozen=True)
class AuthResult:
    """The verdict on one ``Authorization`` header. ``reason`` says why it failed."""

    ok: bool
    stale: bool = False
    reason: str = ""


def _md5(text: str) -> str:
    # HTTP Digest (RFC 2617) is MD5 by definition: the simulated camera computes what the real one
    # does, for protocol fidelity; nothing here relies on MD5 to protect anything
    return hashlib.md5(text.encode("utf-8"), usedforsecurity=False).hexdigest()


def digest_response(
    user: str,
    realm: str,
    password: str,
    method: str,
    uri: str,
    nonce: str,
    nc: str | None = None,
    cnonce: str | None = None,
    qop: str | None = None,
) -> str:
    """The ``response`` value a client must send (MD5; with qop, or RFC 2069 style without)."""
    ha1 = _md5(f"{user}:{realm}:{password}")
    ha2 = _md5(f"{method}:{uri}")
    if qop:
        return _md5(f"{ha1}:{nonce}:{nc}:{cnonce}:{qop}:{ha2}")
    return _md5(f"{ha1}:{nonce}:{ha2}")


def parse_auth_params(text: str) -> dict[str, str]:
    """Parse ``key=value, key="quoted, value"`` pairs (keys lower-cased).

    Tolerant of what real clients send: quoted or bare values (FFmpeg quotes ``qop``, curl
    does not), spaces around separators, backslash escapes inside quotes.
    """
    params: dict[str, str] = {}
    i, n = 0, len(text)
    while i < n:
        while i < n and text[i] in " \t,":
            i += 1
        eq = text.find("=", i)
        if eq < 0:
            break
        key = text[i:eq].strip().lower()
        i = eq + 1
        while i < n and text[i] in " \t":
            i += 1
        if i < n and text[i] == '"':
            i += 1
            value = []
            while i < n and text[i] != '"':
                if text[i] == "\\" and i + 1 < n:
                    i += 1
                value.append(text[i])
                i += 1
            i += 1  # closing quote
            params[key] = "".join(value)
        else:
            end = text.find(",", i)
            end = n if end < 0 else end
            params[key] = text[i:end].strip()
            i = end
    return params


class DigestAuth:
    """Issue digest challenges and check answers for one user of one realm.

    ``now`` is the time source for nonce ages (monotonic seconds); tests may replace it.
    """

    def __init__(
        self,
        realm: str,
        user: str,
        password: str,
        nonce_ttl_s: float = 300.0,
        now: Callable[[], float] = time.monotonic,
    ):
        self.realm = realm
        self.user = user
        self.password = password
        self.nonce_ttl_s = nonce_ttl_s
        self.now = now
        self.opaque = secrets.token_hex(16)
        self._secret = secrets.token_bytes(32)

    # --- nonces -----------------------------------------------------------------------
    def _sign(self, stamp: str, rand: str) -> str:
        return hmac.new(self._secret, f"{stamp}.{rand}".encode(), hashlib.sha256).hexdigest()[:32]

    def new_nonce(self) -> str:
        stamp = format(int(self.now() * 1000), "x")
        rand = secrets.token_hex(8)
        return f"{stamp}.{rand}.{self._sign(stamp, rand)}"

    def _nonce_state(self, nonce: str) -> str:
        """'ok', 'stale' (ours but expired) or 'bad' (not made by this server)."""
        parts = nonce.split(".")
        if len(parts) != 3:
            return "bad"
        stamp, rand, sig = parts
        if not hmac.compare_digest(sig.encode(), self._sign(stamp, rand).encode()):  # (bytes: any client text)
            return "bad"
        try:
            age = self.now() - int(stamp, 16) / 1000.0
        except ValueError:
            return "bad"
        return "ok" if -1.0 <= age <= self.nonce_ttl_s else "stale"

    # --- the two halves of the exchange ------------------------------------------------
    def challenge(self, stale: bool = False) -> str:
        """The value of a ``WWW-Authenticate`` header."""
        value = (
            f'Digest realm="{self.realm}", nonce="{self.new_nonce()}", '
            f'algorithm=MD5, qop="auth", opaque="{self.opaque}"'
        )
        return value + (", stale=true" if stale else "")

    def check(self, method: str, header: str | None, request_target: str) -> AuthResult:
        """Check an ``Authorization`` header against this realm's user and password."""
        if not header:
            return AuthResult(False, reason="no credentials")
        scheme, _, rest = header.strip().partition(" ")
        if scheme.lower() != "digest":
            return AuthResult(False, reason=f"{scheme} authentication is not accepted")
        p = parse_auth_params(rest)
        for key in ("username", "realm", "nonce", "uri", "response"):
            if key not in p:
                return AuthResult(False, reason=f"the {key} field is missing")
        if p.get("algorithm", "MD5").upper() != "MD5":
            return AuthResult(False, reason=f"algorithm {p['algorithm']} is not supported")
        if p["realm"] != self.realm:
            return AuthResult(False, reason="wrong realm")
        if "opaque" in p and p["opaque"] != self.opaque:
            return AuthResult(False, reason="wrong opaque")
        if not _same_target(p["uri"], request_target):
            return AuthResult(False, reason="the uri field does not match the request")
        qop = p.get("qop")
        if qop is not None:
            if qop != "auth":
                return AuthResult(False, reason=f"qop {qop} is not supported")
            if "cnonce" not in p or not _is_hex(p.get("nc", "")):
                return AuthResult(False, reason="cnonce or nc missing or malformed")
        state = self._nonce_state(p["nonce"])
        if state == "bad":
            return AuthResult(False, reason="unknown nonce")
        expected = digest_response(
            self.user, self.realm, self.password, method, p["uri"], p["nonce"], p.get("nc"), p.get("cnonce"), qop
        )
        good = hmac.compare_digest(p["username"].encode(), self.user.encode()) & hmac.compare_digest(
            p["response"].lower().encode(), expected.encode()
        )
        if not good:
            return AuthResult(False, reason="wrong user name or password")
        if state == "stale":
            return AuthResult(False, stale=True, reason="nonce expired")
        return AuthResult(True)


def _is_hex(text: str) -> bool:
    try:
        int(text, 16)
    except ValueError:
        return False
    return True


def _same_target(uri: str, request_target: str) -> bool:
    """The digest ``uri`` must name the request target; clients that drop the query or send
    an absolute URI are accepted when the path matches."""
    if uri == request_target:
        return True
    return urlsplit(uri).path == urlsplit(request_target).path


class BasicAuth:
    """HTTP basic authentication for one user of one realm (same interface as DigestAuth).

    Real Axis cameras can be set to basic; the simulated ones use it only when asked (an
    HTTPS camera, or a test that a client never sends a password in clear)."""

    def __init__(self, realm: str, user: str, password: str):
        self.realm = realm
        self.user = user
        self.password = password

    def challenge(self, stale: bool = False) -> str:
        return f'Basic realm="{self.realm}"'

    def check(self, method: str, header: str | None, request_target: str) -> AuthResult:
        if not header:
            return AuthResult(False, reason="no credentials")
        scheme, _, rest = header.strip().partition(" ")
        if scheme.lower() != "basic":
            return AuthResult(False, reason=f"{scheme} authentication is not accepted")
        try:
            user, sep, password = base64.b64decode(rest.strip(), validate=True).decode("utf-8").partition(":")
        except (ValueError, UnicodeDecodeError):
            return AuthResult(False, reason="malformed basic credentials")
        good = sep and hmac.compare_digest(user.encode(), self.user.encode()) & hmac.compare_digest(
            password.encode(), self.password.encode()
        )
        return AuthResult(True) if good else AuthResult(False, reason="wrong user name or password")
