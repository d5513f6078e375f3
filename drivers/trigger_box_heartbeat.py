"""The host's heartbeat to the trigger box's watchdog, while its output is on (docs/decisions/0083).

The box counts every command line as a heartbeat and cuts its square wave when none came for the
watchdog time (firmware/trigger_box/watchdog.h). A scan already sends ``EDGES?`` every second, but
the heartbeat must not depend on what the program happens to be doing: :class:`Heartbeat` is a
daemon thread of the driver that, whenever the driver has sent nothing for ``every_s``, asks
``WDOG?`` (the box takes it as a heartbeat, and its answer says whether the watchdog has tripped).
It takes the driver's serial lock like any other command, so it never splits an exchange.

It stops by itself when the box says the output is off (stopped, or cut by the watchdog: the cut
is logged by the driver) or the watchdog off, and on :meth:`Heartbeat.stop` (the driver's stop,
reset and close). A killed process takes the thread with it: that silence is what the box waits
for.
"""

from __future__ import annotations

import threading
from typing import Callable

from vts_hw.drivers.trigger import TriggerError
from vts_hw.drivers.trigger_box_protocol import BoxGone


def heartbeat_every(watchdog_s: float) -> float:
    """How long the driver may stay silent: a quarter of the watchdog time, at most 1 s (so a
    host has at least three beats' grace before the box gives up on it)."""
    return min(1.0, watchdog_s / 4)


class Heartbeat:
    """``beat_if_due()`` in a daemon thread, checked four times per ``every_s``.

    ``box`` is the driver: its ``_lock``, ``_closed``, ``_last_sent`` (the ``monotonic`` time of the
    last command it wrote), ``watchdog()`` and ``_log``; ``monotonic`` is the driver's (the
    protocol tests freeze it, and call ``beat_if_due`` themselves).
    """

    def __init__(self, box, every_s: float, monotonic: Callable[[], float]):
        self.box = box
        self.every_s = every_s
        self.monotonic = monotonic
        self.beats = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def start(self) -> None:
        if self.running:
            return
        self._stop = threading.Event()      # its own: a thread stopped earlier never sees it cleared
        self._thread = threading.Thread(target=self._run, args=(self._stop,), name=f"{self.box.name}-heartbeat",
                                        daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """No beat after this returns (a beat under way holds the driver's lock, and the next one
        sees the stop first); the thread ends at its next wake-up. Safe with the lock held."""
        self._stop.set()
        self._thread = None

    def _run(self, stop: threading.Event) -> None:
        while not stop.wait(self.every_s / 4):
            if not self.beat_if_due(stop):
                return

    def beat_if_due(self, stop: threading.Event | None = None) -> bool:
        """One ``WDOG?`` if the driver has been silent for ``every_s``; False when there is no
        more reason to beat (stopped, the output off, the watchdog off, the port gone or closed)."""
        box = self.box
        with box._lock:
            if (stop or self._stop).is_set() or box._closed:
                return False
            if self.monotonic() - box._last_sent < self.every_s:
                return True
            try:
                wd = box.watchdog()
            except BoxGone:
                return False
            except TriggerError as exc:   # a beat missed: said, and the next one tried
                box._log("event", f"heartbeat failed: {exc}")
                return True
            self.beats += 1
        return wd.state == "armed"
