"""``serve``: the room console of one rig, on a local web address, until Ctrl-C.

The threads (docs/decisions/0060-room-console.md): uvicorn's event loop in the calling thread
serves the pages and events; one reader thread per watched camera (the hub's, only while a
page watches it); one marker-detection thread; one thread that keeps the room's facts (clock
offsets, daily QA) fresh; device and store calls made for a request run in the loop's thread
pool. Nothing a browser does can make a reader wait.
"""

from __future__ import annotations

import errno
import ipaddress
import socket
import threading

from vts_hw.errors import UsageError

LOOPBACK_NAMES = ("localhost",)
FACTS_TICK_S = 2.0


class NotOnLoopback(UsageError):
    """Serving off this machine needs users and login, which the console does not have yet."""


def is_loopback(host: str) -> bool:
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_host(host: str) -> None:
    if not is_loopback(host):
        raise NotOnLoopback(f"refused to serve the console on {host}: off this machine it needs users and "
                            f"login, which are not built yet; serve on 127.0.0.1 (reach it from elsewhere "
                            f"through an SSH tunnel)")


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
            raise UsageError(f"port {port} on {host} is in use by another program: give another with --port") \
                from None
        if exc.errno == errno.EACCES:
            raise UsageError(f"port {port} on {host} may not be used by this user: give one above 1023 "
                             f"with --port") from None
        raise UsageError(f"cannot serve on {host} port {port}: {exc.strerror or exc}") from None
    sock.listen(64)
    sock.setblocking(False)
    return sock


def url_of(host: str, port: int) -> str:
    shown = f"[{host}]" if ":" in host else host
    return f"http://{shown}:{port}/"


def serve(rig, *, host: str = "127.0.0.1", port: int = 8040, open_store=None, on_ready=None,
          idle_close_s: float | None = None, marker_hz: float | None = None, scans_dir=None) -> None:
    """Serve the console of ``rig`` (a RigConfig) on ``host:port`` until Ctrl-C (or SIGTERM),
    then close every stream and camera and return. ``open_store()`` gives the results store
    (None: the page says there is none); ``on_ready(url)`` is told once it listens; ``scans_dir``:
    the folder the Scan page's scans go into (default: the working directory, as `vts scan start`)."""
    import uvicorn

    from vts_hw.console.app import Console, create_app
    from vts_hw.console.hub import IDLE_CLOSE_S, FramesHub
    from vts_hw.console.markers import RATE_HZ, MarkerWorker
    from vts_hw.console.room import RoomFacts
    from vts_hw.drivers.registry import open_cameras

    check_host(host)
    sock = bind(host, port)
    cameras = {c.name: c for c in open_cameras(rig.cameras)}
    hub = FramesHub(cameras, idle_close_s=IDLE_CLOSE_S if idle_close_s is None else idle_close_s)
    markers = MarkerWorker(hub, RATE_HZ if marker_hz is None else marker_hz)
    facts = RoomFacts(cameras, rig.rig, open_store)
    console = Console(rig.rig, hub, markers, facts, open_store=open_store)
    console.rig, console.scans_dir = rig, scans_dir      # the Scan page's (scan_page.py)
    stop_facts = threading.Event()

    def keep_facts():
        while not stop_facts.is_set():
            try:
                facts.refresh_due()
            except Exception:           # the page says what it could not read; the thread goes on
                pass
            stop_facts.wait(FACTS_TICK_S)

    facts_thread = threading.Thread(target=keep_facts, name="console-facts", daemon=True)
    facts_thread.start()
    config = uvicorn.Config(create_app(console), log_level="warning", access_log=False,
                            timeout_graceful_shutdown=2, lifespan="off")
    server = _Server(config, lambda: on_ready and on_ready(url_of(host, sock.getsockname()[1])),
                     console.closing.set)
    try:
        server.run(sockets=[sock])
    except KeyboardInterrupt:          # uvicorn stops on Ctrl-C, then raises it again: stopping is the way out
        pass
    finally:
        stop_facts.set()
        markers.close()
        hub.close()
        for cam in cameras.values():
            cam.close()
        sock.close()
        facts_thread.join(FACTS_TICK_S + 1)   # (a daemon: a camera call it waits on cannot hold the exit)


class _Server:
    """uvicorn's server, telling ``ready()`` once it listens and ``stopping()`` when it begins to
    stop (the event streams then end, rather than being cut after the grace period)."""

    def __init__(self, config, ready, stopping):
        import uvicorn

        class Server(uvicorn.Server):
            async def startup(self, sockets=None):
                await super().startup(sockets)
                if self.started:
                    ready()

            async def shutdown(self, sockets=None):
                stopping()
                await super().shutdown(sockets)

        self.server = Server(config)

    def run(self, sockets) -> None:
        self.server.run(sockets=sockets)
        if not self.server.started:
            raise UsageError("the console did not start (see the messages above)")


__all__ = ["serve", "check_host", "is_loopback", "NotOnLoopback", "bind", "url_of"]
