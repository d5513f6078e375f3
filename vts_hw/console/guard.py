"""Who may do what on the console: every request that changes something passes ``refuse()``.

One door for the pages (docs/decisions/0060-room-console.md): a POST is served only when it
comes from the console's own page (the Origin, when the browser sends one, is this server's,
and the page's token is in the ``X-Console-Token`` header) and, once users exist, when the
session's user has the role the action needs. On 127.0.0.1 without users the person at the
console is ``local`` and may do everything (the machine's login is the check).

Roles: ``operator`` (scans, daily QA, the LED, acknowledging alerts) and ``physicist`` (also
baselines, calibration, tolerances, sign-off). ``ROLE_RANK`` orders them.
"""

from __future__ import annotations

import secrets

from starlette.requests import Request
from starlette.responses import JSONResponse, Response

OPERATOR = "operator"
PHYSICIST = "physicist"
ROLE_RANK = {OPERATOR: 1, PHYSICIST: 2}
LOCAL_USER = "local"


def same_origin(request: Request) -> str:
    """'' when a POST may be served; else why not (one sentence)."""
    origin = request.headers.get("origin")
    host = request.headers.get("host", "")
    if origin is not None and origin != f"{request.url.scheme}://{host}":
        return f"refused: a request from another site ({origin})"
    if origin is None and request.headers.get("sec-fetch-site", "same-origin") not in ("same-origin", "none"):
        return "refused: a request from another site"
    return ""


def user_of(console, request: Request) -> tuple[str, str]:
    """(user name, role) of the request: ``local`` with every right while the console has no users."""
    return LOCAL_USER, PHYSICIST


def refuse(console, request: Request, role: str = OPERATOR) -> Response | None:
    """None when ``request`` may do an action needing ``role``; else the response refusing it."""
    why = same_origin(request)
    if why or not secrets.compare_digest(request.headers.get("x-console-token", ""), console.token):
        return JSONResponse({"error": why or "refused: the request did not come from the console's page"},
                            status_code=403)
    user, has = user_of(console, request)
    if ROLE_RANK.get(has, 0) < ROLE_RANK[role]:
        return JSONResponse({"error": f"refused: {user} is {has}; this needs a {role}"}, status_code=403)
    return None


__all__ = ["refuse", "user_of", "same_origin", "OPERATOR", "PHYSICIST", "ROLE_RANK", "LOCAL_USER"]
