"""A room console served in this process, for the tests and the screenshots that need its
objects at hand (the marker names the Scan page feeds, the facts): the same objects
`vts console` builds (console/serve.py), uvicorn on 127.0.0.1 in a thread, the facts kept
fresh by a thread as serve() keeps them."""

from __future__ import annotations

import socket
import threading
import time
from types import SimpleNamespace

import uvicorn

from vts_hw.console.app import Console, create_app
from vts_hw.console.hub import FramesHub
from vts_hw.console.markers import MarkerWorker
from vts_hw.console.names import MarkerNames
from vts_hw.console.room import RoomFacts


class LiveConsole:
    """``with LiveConsole(cameras, rig_name, open_store) as live:`` -> ``live.url``,
    ``live.console``, ``live.names``, ``live.facts``."""

    def __init__(self, cameras: dict, rig: str, open_store=None, *, marker_hz: float = 5.0,
                 facts_tick_s: float = 0.5):
        self.names = MarkerNames()
        self.hub = FramesHub(cameras, idle_close_s=2.0)
        self.markers = MarkerWorker(self.hub, marker_hz, self.names)
        self.facts = RoomFacts(cameras, rig, open_store, names=self.names)
        self.console = Console(rig, self.hub, self.markers, self.facts, open_store=open_store)
        self._tick = facts_tick_s
        self._stop = threading.Event()

    def __enter__(self) -> "LiveConsole":
        self._facts = threading.Thread(target=self._keep_facts, daemon=True)
        self._facts.start()
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}/"
        self.server = uvicorn.Server(uvicorn.Config(create_app(self.console), log_level="warning",
                                                    lifespan="off", timeout_graceful_shutdown=1))
        self._serve = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]}, daemon=True)
        self._serve.start()
        end = time.monotonic() + 30
        while not self.server.started and time.monotonic() < end:
            time.sleep(0.05)
        assert self.server.started, "the console did not start"
        return self

    def _keep_facts(self):
        while not self._stop.is_set():
            self.facts.refresh_due()
            self._stop.wait(self._tick)

    def __exit__(self, *exc) -> None:
        self.console.closing.set()
        self.server.should_exit = True
        self._serve.join(10)
        self._stop.set()
        self._facts.join(10)
        self.console.aim.close()
        self.markers.close()
        self.hub.close()
        self.sock.close()


__all__ = ["LiveConsole", "SimpleNamespace"]
