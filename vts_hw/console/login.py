"""Logging in to the console: the login page, logging out, and the door every request passes.

``SessionDoor`` (ASGI middleware) stands in front of every page when the console has users
(``console.auth.required``): a request without a live session gets the login page (a GET of
a page: 303 to ``/login?next=...``) or HTTP 401 with a sentence (a picture, an event stream,
a POST). Only ``/login`` and ``/static/`` pass without one. A request of a live session
counts as activity (``Auth.touch``), except ``/session`` (the pages' own check, every few
seconds); an event stream whose session ends (its time is up, logout, user disabled) is ended
by the door at its next event. Then the page's script (static/auth.js) goes to the login page.

* ``GET /login``, ``POST /login`` (a form: name, password, next): on success a new session (its
  cookie HttpOnly, SameSite=Strict, Secure over HTTPS) and 303 to ``next`` (a path of this
  console only); on failure the same page, HTTP 401, "wrong user name or password" for both;
  a name locked after wrong passwords says for how long. The form must come from this site.
* ``POST /logout``: the session ends, its cookie is cleared, 303 to the login page.
* ``GET /session``: who is logged in (name, role, when the session ends), 401 without one.
Logins, refused logins, lock-outs (the wrong password that locks a name: ``locked out``) and
each try while locked (``login refused: locked``) go to the action log, under the name only
when it is a user's (a password typed in the name field is never logged), as do logouts.
"""

from __future__ import annotations

import asyncio
import functools
import secrets
from urllib.parse import parse_qs, quote

from starlette.requests import Request
from starlette.responses import JSONResponse, RedirectResponse, Response
from starlette.routing import Route

from vts_hw.console import guard
from vts_hw.console.inputs import body_bytes
from vts_hw.console.refusals import NO_SESSION
from vts_hw.console.sessions import LOCK_AFTER, current

OPEN_PATHS = ("/login",)
OPEN_PREFIXES = ("/static/",)
PROBE = "/session"
FORM_MAX = 8192
FORM_COOKIE = "vts_login_form"  # the login form's own token (login CSRF), sent to /login only


class _SessionEnded(Exception):
    """Raised into a streaming response whose session has ended: the door ends it cleanly."""


def _wants_page(request: Request) -> bool:
    return request.method in ("GET", "HEAD") and "text/html" in request.headers.get("accept", "")


class SessionDoor:
    """The ASGI middleware described in the module docstring."""

    def __init__(self, app, console):
        self.app = app
        self.console = console

    async def __call__(self, scope, receive, send):
        auth = self.console.auth
        path = scope.get("path", "")
        if (
            scope["type"] != "http"
            or auth is None
            or not auth.required
            or path in OPEN_PATHS
            or path.startswith(OPEN_PREFIXES)
        ):
            await self.app(scope, receive, send)
            return
        request = Request(scope)
        s = auth.session(request.cookies.get(auth.cookie_name))
        if s is None:
            if _wants_page(request):
                here = path + (f"?{scope['query_string'].decode('latin-1')}" if scope.get("query_string") else "")
                resp: Response = RedirectResponse(f"/login?next={quote(here, safe='')}", status_code=303)
            else:
                why = "refused: log in first (no session, or it has ended)"
                # a POST is an action: its refusal recorded (refusals.py); a read is only refused
                task = self.console.refusals.note(NO_SESSION, request, why) if request.method == "POST" else None
                resp = JSONResponse({"error": why}, status_code=401, background=task)
            await resp(scope, receive, send)
            return
        if path != PROBE:
            auth.touch(s)
        scope.setdefault("state", {})["session"] = s
        started = ended = False

        async def watched(message):
            nonlocal started, ended
            if message["type"] == "http.response.start":
                started = True
            elif message["type"] == "http.response.body" and message.get("more_body"):
                if not auth.alive(s):
                    ended = True
                    raise _SessionEnded()
                auth.touch(s)
            await send(message)

        token = current.set(s)
        try:
            await self.app(scope, receive, watched)
        except _SessionEnded:
            pass
        except BaseExceptionGroup as group:  # (a task group's, around a stream)
            if not ended or group.subgroup(_SessionEnded) is None:
                raise
        finally:
            current.reset(token)
        if ended and started:
            await send({"type": "http.response.body", "body": b"", "more_body": False})


async def _form(request: Request) -> dict[str, str] | None:
    """The login form's fields (application/x-www-form-urlencoded, as the page sends it), None for
    anything else; a body over ``FORM_MAX`` bytes is BadInput, 413 (the standard library parses
    it: no extra package)."""
    if request.headers.get("content-type", "").split(";")[0].strip() != "application/x-www-form-urlencoded":
        return None
    body = await body_bytes(request, FORM_MAX)  # (413 beyond it)
    try:
        fields = parse_qs(body.decode("utf-8"), keep_blank_values=True)
    except UnicodeDecodeError:
        return None
    if any(len(v) > 1 for v in fields.values()):  # a field twice: not the page's form
        return None
    return {k: v[0] for k, v in fields.items()}


def _safe_next(value: str) -> str:
    """A path of this console to go to after login ('/' for anything else: no other site). A
    control character or a space is refused too: a browser drops tabs and newlines from a URL,
    so ``/<TAB>/evil.example`` would lead to ``//evil.example``, another site."""
    if (
        not value.startswith("/")
        or value.startswith("//")
        or "\\" in value
        or any(c <= " " or c == "\x7f" for c in value)
    ):
        return "/"
    return value


def login_routes(console, templates) -> list[Route]:
    auth = console.auth

    def page(request: Request, *, error: str = "", status: int = 200, next_: str = "/", name: str = ""):
        ended = request.query_params.get("ended") == "1"
        note = "" if error else ("your session has ended: log in again" if ended else "")
        csrf_token = secrets.token_urlsafe(24)  # each form shown its own: the POST must bring it back
        resp = templates.TemplateResponse(
            request,
            "login.html",
            {
                "rig": console.rig_name,
                "error": error,
                "note": note,
                "next": _safe_next(next_),
                "name": name,
                "csrf_token": csrf_token,
            },
            status_code=status,
            headers={"Cache-Control": "no-store"},
        )
        resp.set_cookie(FORM_COOKIE, csrf_token, httponly=True, samesite="strict", secure=auth.secure, path="/login")
        return resp

    async def login_page(request: Request):
        return page(request, next_=request.query_params.get("next", "/"))

    async def login_post(request: Request):
        why = guard.same_origin(request)
        if why:
            return JSONResponse({"error": why}, status_code=403)
        form = await _form(request)
        if form is None:
            return page(request, error="the login form could not be read: send it from this page", status=400)
        # the form this console showed (its token, also in a cookie only this site's pages send
        # back): a login from anywhere else is not taken, whatever its Origin says (login CSRF)
        if not secrets.compare_digest(
            form.get("csrf_token", "").encode(), (request.cookies.get(FORM_COOKIE) or "\0").encode()
        ):
            return page(
                request,
                error="this login form is not one the console gave (or it is old): log in from the form shown here",
                status=400,
                next_=form.get("next", "/"),
            )
        name, password, next_ = form.get("name", "").strip(), form.get("password", ""), form.get("next", "/")
        known = name in auth.known_names()
        who, where = name if known else "(not a user)", {"from": request.client.host if request.client else ""}
        locked = auth.locked_for(name)
        if locked > 0:
            await asyncio.to_thread(
                functools.partial(
                    console.actions.record,
                    who,
                    "login refused: locked",
                    {**where, "locked_for_s": round(locked)},
                    role="",
                )
            )
            return page(
                request,
                error=f"too many wrong passwords for {name}: try again in {locked:.0f} s",
                status=429,
                next_=next_,
                name=name,
            )
        s = await asyncio.to_thread(auth.login, name, password)
        if s is None:
            locked = auth.locked_for(name)  # this wrong password locked the name
            await asyncio.to_thread(functools.partial(console.actions.record, who, "login refused", where, role=""))
            if locked > 0:
                await asyncio.to_thread(
                    functools.partial(
                        console.actions.record,
                        who,
                        "locked out",
                        {**where, "after": f"{LOCK_AFTER} wrong passwords in a row", "for_s": round(locked)},
                        role="",
                    )
                )
            return page(
                request, error="wrong user name or password", status=401, next_=next_, name=name if known else ""
            )
        await asyncio.to_thread(
            functools.partial(
                console.actions.record,
                s.user,
                "logged in",
                {"from": request.client.host if request.client else ""},
                role=s.role,
            )
        )
        resp = RedirectResponse(_safe_next(next_), status_code=303)
        resp.set_cookie(auth.cookie_name, s.key, httponly=True, samesite="strict", secure=auth.secure, path="/")
        return resp

    async def logout(request: Request):
        why = guard.same_origin(request)
        if why:
            return JSONResponse({"error": why}, status_code=403)
        s = guard.session_of(console, request)
        if s is not None and not secrets.compare_digest(
            request.headers.get("x-console-token", "").encode(), s.token.encode()
        ):
            return JSONResponse({"error": "refused: the request did not come from the console's page"}, status_code=403)
        if s is not None:
            auth.logout(s.key)
            await asyncio.to_thread(functools.partial(console.actions.record, s.user, "logged out", {}, role=s.role))
        resp = RedirectResponse("/login", status_code=303)
        resp.delete_cookie(auth.cookie_name, path="/", secure=auth.secure, httponly=True, samesite="strict")
        return resp

    async def session(request: Request):
        s = guard.session_of(console, request)
        if s is None:
            return JSONResponse({"error": "refused: log in first (no session, or it has ended)"}, status_code=401)
        return JSONResponse(
            {
                "required": True,
                "user": s.user,
                "role": s.role,
                "ends": auth.ends(s),
                "idle_s": auth.idle_s,
                "token": s.token,
            },
            headers={"Cache-Control": "no-store"},
        )

    return [
        Route("/login", login_page, methods=["GET"]),
        Route("/login", login_post, methods=["POST"]),
        Route("/logout", logout, methods=["POST"]),
        Route(PROBE, session),
    ]


def no_login_routes(console) -> list[Route]:
    """Without users: ``/session`` says so (the pages' script then shows nothing)."""

    async def session(request: Request):
        return JSONResponse({"required": False, "user": guard.LOCAL_USER, "role": guard.PHYSICIST})

    return [Route(PROBE, session)]


__all__ = ["SessionDoor", "login_routes", "no_login_routes"]
