"""The console's web application (Starlette): the Room page, its live events, pictures and switches.

The event loop never waits on a device or the store: frames come out of the hub's slots (a
lock held for a pointer copy), device and store calls go to threads (``asyncio.to_thread``).
Live updates are server-sent events (``GET /events``): per camera ``frame`` (a new picture's
``seq`` and age), ``markers`` (what detection found on a frame, in its pixels) and, every
second, ``room`` (what each camera is doing, its LED, clock offset and daily QA). The page
fetches a picture (``GET /frame/{camera}``: the camera's own JPEG bytes, never re-encoded) when
it is told of one and has shown the last: one picture in flight per camera, so a slow browser
sees fewer pictures and asks nothing more of the hub. Every POST must come from the console's
own page: the Origin (when the browser sends one) must be one of the console's own, and the
page's token must be in the ``X-Console-Token`` header (guard.py). With users
(``console.auth``), every request but the login page's needs a session (login.py's
``SessionDoor``).

In front of every route (static files, event streams and the login page included), outermost
first: the security headers (headers.py), with ``--proxy`` the peer gate and the proxy's
X-Forwarded-* (hosts.py, uvicorn's ProxyHeadersMiddleware), the Host gate (hosts.py: only the
names the console serves under, ``Console.reach``), then the session door.
"""

from __future__ import annotations

import asyncio
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles
from starlette.templating import Jinja2Templates

from vts_hw import __version__
from vts_hw.console import guard
from vts_hw.console.actions import MemoryActions
from vts_hw.console.aim_checks import AimChecks
from vts_hw.console.aim_page import aim_routes
from vts_hw.console.answers import after_answer, refused_input, unexpected
from vts_hw.console.headers import SecurityHeaders
from vts_hw.console.history import history_routes
from vts_hw.console.history_reports import Reports
from vts_hw.console.hosts import HostGate, PeerGate, Reach
from vts_hw.console.inputs import BadInput, StrictRequests
from vts_hw.console.login import SessionDoor, login_routes, no_login_routes
from vts_hw.console.qa_page import qa_routes
from vts_hw.console.refusals import Refusals
from vts_hw.console.scan_page import scan_routes
from vts_hw.console.sessions import current
from vts_hw.console.web import event_stream, no_camera, sse, switch_asked, wanted_cameras

HERE = Path(__file__).resolve().parent
EVENT_TICK_S = 0.04  # how often an event stream looks for new frames (25 Hz)
ROOM_EVERY_S = 1.0  # ... and sends the room's state


class Console:
    """What the pages need: the hub, the marker worker, the room's facts, the rig (its name, its config)."""

    aim: AimChecks  # made by the aim checks' routes (aim_page.py), closed by whoever serves the console
    reports: Reports  # made by the History page's routes (history.py), closed likewise

    def __init__(
        self,
        rig_name: str,
        hub,
        markers,
        facts,
        *,
        token: str | None = None,
        open_store=None,
        actions=None,
        auth=None,
        rig_config=None,
        scans_dir=None,
        reach: Reach | None = None,
    ):
        self.rig_name = rig_name
        #: the RigConfig the pages that run procedures run them on (Daily QA, Scan, aim checks);
        #: None: those pages say the console was started without one
        self.rig_config = rig_config
        #: the folder the Scan page's scans go into (None: the working directory, as `vts scan start`)
        self.scans_dir = scans_dir
        #: a callable giving the results store, opened read-only (None: the pages say there is none)
        self.open_store = open_store if open_store is not None else getattr(facts, "open_store", None)
        self.hub = hub
        self.markers = markers
        #: what each marker is (names.MarkerNames): the Scan page names its band markers here
        self.names = getattr(markers, "names", None)
        self.facts = facts
        #: the page token of a console without users (with users each session has its own)
        self.console_token = token or secrets.token_urlsafe(24)
        self.closing = asyncio.Event()
        #: who did what here (actions.py): the store's log where there is one
        self.actions = actions if actions is not None else MemoryActions(rig_name)
        #: users and sessions (sessions.Auth); None: no users, the person here is ``local``
        self.auth = auth
        #: refused POSTs into the action log, a line per kind every few seconds (refusals.py)
        self.refusals = Refusals(self.actions)
        #: the names the console answers to, its POSTs' origins, its proxy (hosts.py)
        self.reach = reach if reach is not None else Reach.local()

    @property
    def token(self) -> str:
        """The page token for the page being rendered: its session's (with users), else the console's."""
        s = current.get()
        return s.token if s is not None else self.console_token

    def room(self) -> dict:
        cams = []
        for name in self.hub.names:
            cams.append({**self.hub.status(name), **self.facts.view(name)})
        return {"rig": self.rig_name, "now": time.time(), "cameras": cams, "phantom": self.markers.phantom_said()}


@dataclass(frozen=True)
class Page:
    """A page of the console after the Room page: ``routes(console, templates)`` gives its Starlette
    routes (from its module), ``nav`` its link's text in the nav bar and ``href`` where it goes
    (none: a part of another page), ``here`` what its templates set ``here`` to (its link marked)."""

    routes: Callable[[Console, Jinja2Templates], list]
    here: str = ""
    nav: str = ""
    href: str = ""


#: the console's pages, in the nav bar's order: a new page is its module (+ its template) and one
#: line here (docs/develop/checklists.md "A console page"); the Room page is this module's own
PAGES: list[Page] = [
    Page(scan_routes, "scan", "Scan", "/scan"),
    Page(qa_routes, "qa", "Daily QA", "/qa"),
    Page(history_routes, "history", "History", "/history"),
    Page(aim_routes),  # the Room page's aim & focus (aim_checks.py)
]


def nav_pages() -> list[tuple[str, str, str]]:
    """The nav bar's links, (here, href, text): the Room page, then each page of PAGES with one."""
    return [("room", "/", "Room"), *((p.here, p.href, p.nav) for p in PAGES if p.nav)]


class _ConsoleApp(Starlette):
    """Starlette, whose error middleware answers an unexpected exception (answers.unexpected: one
    sentence, 500, a log line without the exception's words) and then raises it again for the
    server to log with its traceback and words, which might hold what the request carried. Here
    it ends once answered: its frames go to the debug log (answers.after_answer), never its words."""

    async def __call__(self, scope, receive, send) -> None:
        try:
            await super().__call__(scope, receive, send)
        except Exception as exc:
            if scope.get("type") != "http":
                raise
            after_answer(exc)


def create_app(console: Console) -> Starlette:
    templates = Jinja2Templates(directory=str(HERE / "templates"))
    templates.env.globals["nav_pages"] = nav_pages()

    async def room_page(request: Request):
        return templates.TemplateResponse(
            request,
            "room.html",
            {"rig": console.rig_name, "cameras": console.hub.names, "token": console.token, "version": __version__},
        )

    async def room_json(request: Request):
        return JSONResponse(await asyncio.to_thread(console.room))

    async def frame(request: Request):
        name = request.path_params["camera"]
        bad = no_camera(console, name)
        if bad is not None:
            return bad
        latest = console.hub.latest(name)
        if latest is None:
            return JSONResponse({"error": f"camera {name}: no picture yet"}, status_code=503)
        return Response(
            latest.frame.jpeg,
            media_type="image/jpeg",
            headers={
                "Cache-Control": "no-store",
                "X-Frame-Seq": str(latest.seq),
                "X-Frame-Arrival": f"{latest.arrival:.3f}",
            },
        )

    async def events(request: Request):
        wanted = wanted_cameras(console, request)
        sent_seq: dict[str, int | None] = {n: None for n in wanted}
        sent_marks: dict[str, object] = {n: None for n in wanted}  # the Found sent (a new picture, or named again)
        next_room = 0.0

        async def poll(now: float) -> list[bytes]:
            nonlocal next_room
            out = []
            if now >= next_room:
                next_room = now + ROOM_EVERY_S
                out.append(sse("room", await asyncio.to_thread(console.room)))
            for n in wanted:
                lt = console.hub.latest(n)
                if lt is not None and lt.seq != sent_seq[n]:
                    sent_seq[n] = lt.seq
                    out.append(sse("frame", {"camera": n, "seq": lt.seq, "arrival": lt.arrival}))
                found = console.markers.found(n)
                if found is not None and found is not sent_marks[n]:
                    sent_marks[n] = found
                    out.append(sse("markers", found.as_dict()))
            return out

        def opened():
            for n in wanted:
                console.hub.watch(n)

        def closed():
            for n in wanted:
                console.hub.unwatch(n)

        return event_stream(console, EVENT_TICK_S, poll, opened=opened, closed=closed)

    async def led(request: Request):
        name, on, refused = await switch_asked(console, request)
        if refused is not None:
            return refused
        facts = await asyncio.to_thread(console.facts.switch_led, name, on)
        user, role = guard.user_of(console, request)  # asked, whether it took or not (the camera says)
        await asyncio.to_thread(
            lambda: console.actions.record(
                user,
                f"LED {'on' if on else 'off'}",
                {"camera": name, "took": not facts["led_error"], "read back": facts["led"]},
                role=role,
            )
        )
        return JSONResponse(facts, status_code=200 if not facts["led_error"] else 502)

    routes = [
        Route("/", room_page),
        Route("/api/room", room_json),
        Route("/frame/{camera}", frame),
        Route("/events", events),
        Route("/camera/{camera}/led", led, methods=["POST"]),
        *(
            login_routes(console, templates)
            if console.auth is not None and console.auth.required
            else no_login_routes(console)
        ),
        *(r for page in PAGES for r in page.routes(console, templates)),  # each a module of its own
        Mount("/static", StaticFiles(directory=str(HERE / "static")), name="static"),
    ]
    reach = console.reach
    middleware = [Middleware(SecurityHeaders)]
    if reach.proxied:
        from uvicorn.middleware.proxy_headers import ProxyHeadersMiddleware

        middleware += [
            Middleware(PeerGate, reach=reach),
            Middleware(ProxyHeadersMiddleware, trusted_hosts=reach.trusted_proxies()),
        ]
    middleware += [
        Middleware(HostGate, reach=reach),
        Middleware(SessionDoor, console=console),
        Middleware(StrictRequests),
    ]  # inputs.py: no parameter twice, no body too large
    app = _ConsoleApp(
        routes=routes,
        middleware=middleware,  # answers.py: one sentence, never a traceback
        exception_handlers={BadInput: refused_input, Exception: unexpected},
    )
    app.state.reach = reach  # guard.same_origin's origins
    return app


__all__ = ["Console", "Page", "PAGES", "create_app", "nav_pages"]
