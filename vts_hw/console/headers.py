"""The security headers on every answer of the console (ASGI middleware, outermost: the refusals
of the Host and peer gates, 404s, static files and event streams carry them too).

* ``Content-Security-Policy``: the console's pages load their scripts, styles, pictures and
  events from the console only, with no inline script or style (templates/ and static/ have
  none), are framed by no one (``frame-ancestors 'none'``) and post forms to the console only.
  The reports the console serves (the drift report, the rooms page, a scan's motion report:
  ``DOCUMENT_PATHS``) are self-contained documents with their own inline style and script:
  they get ``DOCUMENT_CSP``, a sandbox (an origin of their own: their script reaches neither
  the console's cookies nor its pages) that may load nothing from the network.
* ``X-Frame-Options: DENY``, ``X-Content-Type-Options: nosniff``, ``Referrer-Policy:
  same-origin`` (not ``no-referrer``: with it a browser sends ``Origin: null`` on the login
  form's POST, which guard.py must refuse), ``Cross-Origin-Opener-Policy`` and
  ``Cross-Origin-Resource-Policy: same-origin`` (no other site embeds a camera's picture),
  ``X-XSS-Protection: 1; mode=block`` (browsers of today ignore it and the CSP is the defence;
  an old one with the XSS auditor blocks the whole page rather than filter parts of it, the
  filtering being what could be abused; web scanners such as wapiti ask for it).
* ``Strict-Transport-Security`` over HTTPS only (the scheme the request came with, through
  the proxy's X-Forwarded-Proto where it is trusted).
* ``Cache-Control: no-store`` on everything but ``/static/`` unless the route set its own: the
  pages hold the page token, the answers the room's state.
A response that sets one of these itself keeps its own.
"""

from __future__ import annotations

PAGE_CSP = (
    "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; "
    "connect-src 'self'; font-src 'self'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'"
)
DOCUMENT_CSP = (
    "default-src 'none'; img-src data:; style-src 'unsafe-inline'; script-src 'unsafe-inline'; "
    "base-uri 'none'; form-action 'none'; frame-ancestors 'none'; sandbox allow-scripts"
)
DOCUMENT_PATHS = ("/history/drift-report", "/history/rooms/", "/scan/files/")
STATIC_PREFIX = "/static/"
HSTS = "max-age=31536000"

_ALWAYS = (
    (b"x-frame-options", b"DENY"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"same-origin"),
    (b"cross-origin-opener-policy", b"same-origin"),
    (b"cross-origin-resource-policy", b"same-origin"),
    (b"x-xss-protection", b"1; mode=block"),
    (b"permissions-policy", b"camera=(), microphone=(), geolocation=(), usb=(), serial=()"),
)


def csp_for(path: str) -> str:
    return DOCUMENT_CSP if path.startswith(DOCUMENT_PATHS) else PAGE_CSP


class SecurityHeaders:
    """ASGI middleware adding the headers above to every HTTP response."""

    def __init__(self, app):
        self.app = app

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path = scope.get("path", "")

        async def with_headers(message):
            if message["type"] == "http.response.start":
                headers = list(message.get("headers", ()))
                have = {k.lower() for k, _ in headers}
                add = [*_ALWAYS, (b"content-security-policy", csp_for(path).encode())]
                if scope.get("scheme") == "https":  # read now: a trusted proxy may have set it
                    add.append((b"strict-transport-security", HSTS.encode()))
                if not path.startswith(STATIC_PREFIX):
                    add.append((b"cache-control", b"no-store"))
                headers += [(k, v) for k, v in add if k not in have]
                message = {**message, "headers": headers}
            await send(message)

        await self.app(scope, receive, with_headers)


__all__ = ["SecurityHeaders", "PAGE_CSP", "DOCUMENT_CSP", "DOCUMENT_PATHS", "csp_for"]
