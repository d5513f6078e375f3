"""``serve``: the room console of one rig, on a local web address, until Ctrl-C.

The threads (docs/decisions/0060-room-console.md): uvicorn's event loop in the calling thread
serves the pages and events; one reader thread per watched camera (the hub's, only while a
page watches it); one marker-detection thread; one thread that keeps the room's facts (clock
offsets, daily QA) fresh; device and store calls made for a request run in the loop's thread
pool. Nothing a browser does can make a reader wait. What is refused before anything is read,
bound or opened is serve_checks.py's.
"""

from __future__ import annotations

import asyncio
import errno
import socket
import threading
import time

from vts_hw.console.actions import durable_actions
from vts_hw.console.app import Console, create_app
from vts_hw.console.hub import IDLE_CLOSE_S, FramesHub
from vts_hw.console.markers import RATE_HZ, MarkerWorker
from vts_hw.console.names import MarkerNames
from vts_hw.console.phantom import PhantomNames
from vts_hw.console.room import RoomFacts
from vts_hw.console.scans_folder import scans_folder
from vts_hw.console.serve_checks import check_host, check_users, login_required
from vts_hw.console.sessions import IDLE_S, MAX_S, USERS_EVERY_S, Auth
from vts_hw.errors import UsageError, VtsError
from vts_hw.room import Room

FACTS_TICK_S = 2.0
SCAN_STOP_S = 120.0  # a scan running when the console stops: closed within this (docs/decisions/0082)


def bind(host: str, port: int) -> socket.socket:
    """The listening socket, bound now, so that a port in use is one sentence (exit 2)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise UsageError(f"port {port} on {host} is in use by another program: give another with --port") from None
        if exc.errno == errno.EACCES:
            raise UsageError(
                f"port {port} on {host} may not be used by this user: give one above 1023 with --port"
            ) from None
        raise UsageError(f"cannot serve on {host} port {port}: {exc.strerror or exc}") from None
    sock.listen(64)
    sock.setblocking(False)
    return sock


def url_of(host: str, port: int, tls: bool = False) -> str:
    shown = f"[{host}]" if ":" in host else host
    return f"{'https' if tls else 'http'}://{shown}:{port}/"


def _auth(host, login, behind_proxy, tls, open_store, session_idle_s, session_max_s):
    """The console's users and sessions (None: no login, the person here is ``local``), after
    checking that a console needing a login has users; before anything is bound or opened."""
    if not login_required(host, login, behind_proxy):
        return None
    if open_store is None:
        check_users(host, 0, "(none named)")
    where = ""

    def load_users():
        nonlocal where
        with open_store() as store:
            where = store.url
            return store.users(active_only=True)

    auth = Auth(
        required=True,
        secure=tls or behind_proxy,
        load_users=load_users,
        idle_s=IDLE_S if session_idle_s is None else session_idle_s,
        max_s=MAX_S if session_max_s is None else session_max_s,
    )
    try:
        n = auth.refresh_users()
    except VtsError as exc:
        check_users(host, 0, "", why_not=str(exc))
    check_users(host, n, where)
    return auth


def serve(
    rig,
    *,
    host: str = "127.0.0.1",
    port: int = 8040,
    open_store=None,
    open_write_store=None,
    on_ready=None,
    idle_close_s: float | None = None,
    marker_hz: float | None = None,
    login: bool = False,
    behind_proxy: bool = False,
    certfile: str | None = None,
    keyfile: str | None = None,
    session_idle_s: float | None = None,
    session_max_s: float | None = None,
    scans_dir=None,
    proxy: str | None = None,
    server_names=(),
) -> None:
    """Serve the console of ``rig`` (a RigConfig) on ``host:port`` until Ctrl-C (or SIGTERM),
    then close every stream and camera and return. ``open_store()`` gives the results store
    read-only (None: the page says there is none), ``open_write_store()`` the same store to
    append the action log to (both needed: its first action, ``console started``, is written
    before any camera is opened, else refused: actions.durable_actions); ``on_ready(url)`` is
    told once it listens. Off this machine (or with ``login``/``behind_proxy``) the store must
    hold users and (off this machine) HTTPS be given (``certfile``/``keyfile``) or a proxy said: refused
    (UsageError, exit 2) before anything is bound or opened otherwise (check_host: plain HTTP only
    on this machine or to the ``proxy``; ``server_names``: names answered besides the loopback
    ones, ``host`` and the certificate's). ``scans_dir``: the folder the Scan page's scans go
    into, a folder of scans only (scans_folder.py; default: ``scans/`` beside the per-user store)."""
    import uvicorn

    reach = check_host(
        host, certfile=certfile, keyfile=keyfile, behind_proxy=behind_proxy, proxy=proxy, server_names=server_names
    )
    tls = reach.tls
    auth = _auth(host, login, reach.proxied, tls, open_store, session_idle_s, session_max_s)
    scans = scans_folder(scans_dir)
    sock = bind(host, port)
    try:  # the action log is the store's, its first action written now, before any camera opens (actions.py)
        actions = durable_actions(open_write_store, open_store, rig.rig, url_of(host, sock.getsockname()[1], tls))
    except BaseException:
        sock.close()
        raise
    room = Room(rig)  # the room's cameras, closed with it when the console stops
    try:
        cameras = {c.name: c for c in room.cameras}
    except BaseException as exc:
        room.__exit__(type(exc), exc, exc.__traceback__)  # what was opened closed; this error goes on
        sock.close()
        raise
    hub = FramesHub(cameras, idle_close_s=IDLE_CLOSE_S if idle_close_s is None else idle_close_s)
    names = MarkerNames()
    markers = MarkerWorker(
        hub, RATE_HZ if marker_hz is None else marker_hz, names, phantom=PhantomNames.for_rig(names, rig)
    )
    facts = RoomFacts(cameras, rig.rig, open_store, names=names)
    console = Console(
        rig.rig,
        hub,
        markers,
        facts,
        open_store=open_store,
        actions=actions,
        auth=auth,
        rig_config=rig,
        scans_dir=scans,
        reach=reach,
    )
    stop_facts = threading.Event()

    def keep_facts():
        users_due = time.monotonic() + USERS_EVERY_S
        while not stop_facts.is_set():
            try:
                facts.refresh_due()
            except Exception:  # the page says what it could not read; the thread goes on
                pass
            if auth is not None and time.monotonic() >= users_due:
                users_due = time.monotonic() + USERS_EVERY_S
                try:  # a user disabled (or with another role) is logged out within USERS_EVERY_S
                    auth.refresh_users()
                    auth.sweep()
                except Exception:  # the store away a moment: the users as they were
                    pass
            stop_facts.wait(FACTS_TICK_S)

    facts_thread = threading.Thread(target=keep_facts, name="console-facts", daemon=True)
    facts_thread.start()
    # the proxy's X-Forwarded-* are taken by the app (create_app: from the proxy only), never by uvicorn
    # ($FORWARDED_ALLOW_IPS would widen it); no Server header
    config = uvicorn.Config(
        create_app(console),
        log_level="warning",
        access_log=False,
        timeout_graceful_shutdown=2,
        lifespan="off",
        proxy_headers=False,
        server_header=False,
        ssl_certfile=certfile if tls else None,
        ssl_keyfile=keyfile if tls else None,
    )

    def finish_scan() -> None:
        """A Scan-page scan still running when the console stops (Ctrl-C, SIGTERM): stopped as
        interrupted, its wave off and its recording closed, before the server closes (uvicorn
        raises SIGTERM again once closed, which ends the process at once)."""
        desk = getattr(console, "scan_desk", None)
        run = desk.run if desk is not None else None
        if run is not None and run.thread.is_alive():
            run.stop_and_wait("interrupted", SCAN_STOP_S)

    server = _Server(
        config,
        lambda: on_ready and on_ready(url_of(host, sock.getsockname()[1], tls)),
        console.closing.set,
        finish_scan,
    )
    try:
        server.run(sockets=[sock])
    except KeyboardInterrupt:  # uvicorn stops on Ctrl-C, then raises it again: stopping is the way out
        pass
    finally:
        stop_facts.set()
        console.aim.close()  # the aim checks (aim_page.py) end before the hub and cameras
        console.reports.close()  # the rooms report's temporary folder (history_reports.py)
        markers.close()
        hub.close()
        try:
            room.close()
        finally:
            sock.close()
        facts_thread.join(FACTS_TICK_S + 1)  # (a daemon: a camera call it waits on cannot hold the exit)


class _Server:
    """uvicorn's server, telling ``ready()`` once it listens and ``stopping()`` when it begins to
    stop (the event streams then end, rather than being cut after the grace period), then waiting
    for ``finish()`` (in a worker thread: a second Ctrl-C meanwhile is only noted by uvicorn)
    before it closes."""

    def __init__(self, config, ready, stopping, finish=lambda: None):
        import uvicorn

        class Server(uvicorn.Server):
            async def startup(self, sockets=None):
                await super().startup(sockets)
                if self.started:
                    ready()

            async def shutdown(self, sockets=None):
                stopping()
                await asyncio.to_thread(finish)
                await super().shutdown(sockets)

        self.server = Server(config)

    def run(self, sockets) -> None:
        self.server.run(sockets=sockets)
        if not self.server.started:
            raise UsageError("the console did not start (see the messages above)")


__all__ = ["serve", "bind", "url_of"]
