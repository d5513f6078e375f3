"""Who may do what on the console: every request that changes something passes ``refuse()``.

One door for the pages (docs/decisions/0060-room-console.md, 0063-console-users.md): a POST
is served only when it comes from the console's own page (the Origin, when the browser sends
one, is one of the console's own: ``same_origin``, hosts.py; and the page's token is in the
``X-Console-Token`` header) and, when the console has users (``console.auth.required``), when
the request's session (login.py's middleware found it from the cookie) belongs to a user whose
role the action needs. With users, the token is the session's own (``Console.token`` gives it
to the page being rendered). On 127.0.0.1 without users the person at the console is ``local``
and may do everything (the machine's login is the check: on a computer shared with other
people, start it with --login; docs/security.md).

Roles: ``operator`` (scans, daily QA, the LED, acknowledging alerts, pushing to QATrack+) and
``physicist`` (also baselines, calibration, tolerances, sign-off). ``ROLE_RANK`` orders them.
"""

from __future__ import annotations

import secrets
from urllib.parse import urlsplit

from starlette.requests import Request
from starlette.responses import JSONResponse, Response

from vts_hw.console.hosts import Reach
from vts_hw.console.refusals import ANOTHER_SITE, NO_SESSION, NOT_THE_PAGE, ROLE

OPERATOR = "operator"
PHYSICIST = "physicist"
ROLE_RANK = {OPERATOR: 1, PHYSICIST: 2}
LOCAL_USER = "local"


def same_origin(request: Request) -> str:
    """'' when a POST may be served; else why not (one sentence). The Origin must be one of the
    console's own (hosts.Reach.origin_ok: its names, the port the request came in on, or a
    --server-name's through the proxy), never just the request's own Host (which whoever makes
    the request sets); without an Origin, the Referer's origin the same, and a Sec-Fetch-Site
    other than same-origin is refused. A request with none of these (not a browser's) passes on
    to the token check."""
    reach = getattr(request.app.state, "reach", None) if "app" in request.scope else None
    reach = reach if reach is not None else Reach.local()
    port = (request.scope.get("server") or (None, None))[1]
    origin = request.headers.get("origin")
    if origin is not None:
        if not reach.origin_ok(origin, port):
            return f"refused: a request from another site ({origin[:80]})"
        return ""
    site = request.headers.get("sec-fetch-site")
    if site is not None and site not in ("same-origin", "none"):
        return "refused: a request from another site"
    referer = request.headers.get("referer")
    if referer is not None:
        try:
            parts = urlsplit(referer)
            from_ = f"{parts.scheme}://{parts.netloc}"
        except ValueError:
            from_ = ""
        if not reach.origin_ok(from_, port):
            return "refused: a request from another site (its Referer)"
    return ""


def users_required(console) -> bool:
    return console.auth is not None and console.auth.required


def session_of(console, request: Request):
    """The request's live session (login.py's middleware put it in the request's scope), or None."""
    s = request.scope.get("state", {}).get("session")
    if s is None or not console.auth.alive(s):
        return None
    return s


def _acting(console, request: Request) -> tuple[str, str, str]:
    """(user name, role, the page token its POSTs carry) of the request: ``local`` with every
    right and the console's token while the console has no users; ("", "", "") for a request
    without a live session when it has."""
    if not users_required(console):
        return LOCAL_USER, PHYSICIST, console.console_token
    s = session_of(console, request)
    return (s.user, s.role, s.token) if s is not None else ("", "", "")


def user_of(console, request: Request) -> tuple[str, str]:
    """(user name, role) of the request: ``local`` with every right while the console has no
    users; ("", "") for a request without a live session when it has."""
    return _acting(console, request)[:2]


def _a(role: str) -> str:
    return f"an {role}" if role[:1] in "aeiou" else f"a {role}"


def _refused(console, request: Request, kind: str, why: str, status: int, user: str = "") -> Response:
    """The answer refusing ``request`` (``why``, one sentence), its refusal recorded in the
    action log after it is sent (refusals.py: at most one line per kind every few seconds)."""
    refusals = getattr(console, "refusals", None)
    task = refusals.note(kind, request, why, user) if refusals is not None else None
    return JSONResponse({"error": why}, status_code=status, background=task)


def refuse(console, request: Request, role: str = OPERATOR) -> Response | None:
    """None when ``request`` may do an action needing ``role``; else the response refusing it
    (403 with a sentence; 401 when the console has users and the request no live session),
    the refusal recorded in the action log (refusals.py)."""
    why = same_origin(request)
    if why:
        return _refused(console, request, ANOTHER_SITE, why, 403)
    user, has, want = _acting(console, request)  # the session looked up once
    if not user:
        return _refused(console, request, NO_SESSION, "refused: log in first (no session, or it has ended)", 401)
    # (as bytes: a header may carry any byte, and str compare_digest refuses non-ASCII with a TypeError)
    if not want or not secrets.compare_digest(request.headers.get("x-console-token", "").encode(), want.encode()):
        return _refused(
            console, request, NOT_THE_PAGE, "refused: the request did not come from the console's page", 403, user
        )
    if ROLE_RANK.get(has, 0) < ROLE_RANK[role]:
        return _refused(console, request, ROLE, f"refused: {user} is {_a(has)}; this needs {_a(role)}", 403, user)
    return None


__all__ = [
    "refuse",
    "user_of",
    "session_of",
    "same_origin",
    "users_required",
    "OPERATOR",
    "PHYSICIST",
    "ROLE_RANK",
    "LOCAL_USER",
]
