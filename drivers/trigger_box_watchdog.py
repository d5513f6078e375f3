"""The trigger box driver's side of the box's host watchdog (docs/decisions/0083): ``WDOG``, the
heartbeat while the output is on, and a cut logged.

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

:class:`BoxWatchdog` is the driver's part (a mixin of ``TriggerBox``): ``WDOG <s>`` before every
start, ``WDOG?``, the heartbeat started and stopped, and a cut logged once (an event, and the
``wave_stop`` row at the cut of a wave this driver started).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING

from vts_hw.drivers.trigger import TriggerError, TriggerStatus
from vts_hw.drivers.trigger_box_protocol import (
    UNDEFINED_HEADER,
    BoxGone,
    BoxRefused,
    WatchdogState,
    number_text,
    parse_watchdog,
    watchdog_seconds,
)
from vts_hw.recording.trigger_log import DEVICE_CLOCK_MAPPED

if TYPE_CHECKING:
    from vts_hw.drivers.trigger_box_clock import TriggerBoxParts as _Parts
else:
    _Parts = object

#: what a box whose firmware has no watchdog (before 1.1.0) is said to have
NO_WATCHDOG = "no host watchdog: its firmware predates it (1.1.0); vts trigger flash updates it"


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
        self._stop = threading.Event()  # its own: a thread stopped earlier never sees it cleared
        self._thread = threading.Thread(
            target=self._run, args=(self._stop,), name=f"{self.box.name}-heartbeat", daemon=True
        )
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
            except TriggerError as exc:  # a beat missed: said, and the next one tried
                box._log("event", f"heartbeat failed: {exc}")
                return True
            self.beats += 1
        return wd.state == "armed"


class BoxWatchdog(_Parts):
    """The trigger box driver's watchdog (a mixin of :class:`~vts_hw.drivers.trigger_box.TriggerBox`,
    which provides ``query``, ``_command``, ``_parse``, ``_lock``, ``_log``, ``log``, ``name``,
    ``edges``, ``mapping``, ``_wave`` and ``_wave_first_us``)."""

    def _init_watchdog(self, watchdog_s: float, heartbeat: bool, monotonic: Callable[[], float]) -> None:
        """``watchdog_s``: set at every start (0: off, the output then outlives the program; else
        OutOfRange before anything is opened); ``heartbeat``: a thread feeds the box while the output
        is on (without it the caller must, as the protocol tests do); ``monotonic`` times it."""
        self.watchdog_s = watchdog_seconds(watchdog_s)
        self.monotonic = monotonic
        self._last_sent = monotonic()  # when the box last heard from us (its heartbeat)
        self._heartbeat_thread = heartbeat
        self.heartbeat: Heartbeat | None = None  # while the output is on with the watchdog set
        self._cuts_logged: set[int] = set()  # watchdog cuts already written to the log

    def watchdog(self) -> WatchdogState:
        """``WDOG?``: the box's watchdog time, its state and when it cut the wave (a cut is logged
        once, with a ``wave_stop`` row at its time when this driver started that wave)."""
        with self._lock:
            wd = self._parse(
                "WDOG?", self.query("WDOG?"), parse_watchdog, "watchdog state ('<s>,<OFF|IDLE|ARMED|TRIPPED>,<us>')"
            )
            if wd.state == "tripped" and wd.cut_device_us not in self._cuts_logged:
                self._cuts_logged.add(wd.cut_device_us)
                self._watchdog_cut(wd)
        return wd

    def _status_watchdog(self) -> tuple[dict | None, str]:
        """For a status: ``WDOG?`` (and ``TIME?`` after a cut, to say how long ago) as the entry of
        its ``extra`` and its note; a box without a watchdog says so rather than failing the status."""
        try:
            wd = self.watchdog()
        except BoxRefused as exc:
            if exc.code != UNDEFINED_HEADER:
                raise
            return None, NO_WATCHDOG
        now = self.device_time_us() if wd.state == "tripped" else None
        return {"seconds": wd.seconds, "state": wd.state, "cut_device_us": wd.cut_device_us}, wd.describe(now)

    def _check_watchdog(self, st: TriggerStatus) -> None:
        """After a configure: a watchdog asked for that the box has not is said now, before a scan
        records anything, not at the start."""
        if self.watchdog_s and st.extra.get("watchdog", {}) is None:
            raise TriggerError(
                f"{self.where} has {NO_WATCHDOG}; without it a start is refused (if this program "
                f"died, the box would drive the scanner's gating input for ever)"
            )

    def _set_watchdog(self) -> None:
        """``WDOG <s>`` before a start: the box's watchdog as this driver wants it (0 = off). A box
        without one is not switched on unless no watchdog was asked for."""
        try:
            self._command(f"WDOG {number_text(self.watchdog_s)}")
        except BoxRefused as exc:
            if exc.code != UNDEFINED_HEADER:
                raise
            if self.watchdog_s:  # asked for and not there (none asked for: none needed)
                raise BoxRefused(
                    f"{self.where} has no host watchdog (its firmware predates 1.1.0): switched on, "
                    f"it would drive the scanner's gating input for ever if this program died, so "
                    f"its output was left off; vts trigger flash updates it",
                    exc.code,
                    exc.device_message,
                ) from None

    def _start_heartbeat(self, st: TriggerStatus) -> None:
        if not st.running or self.watchdog_s == 0:
            return
        if self.heartbeat is not None:
            self.heartbeat.stop()
        self.heartbeat = Heartbeat(self, heartbeat_every(self.watchdog_s), self.monotonic)
        if self._heartbeat_thread:
            self.heartbeat.start()

    def _stop_heartbeat(self) -> None:
        if self.heartbeat is not None:
            self.heartbeat.stop()

    def _watchdog_cut(self, wd: WatchdogState) -> None:
        """The box cut the wave: an event line, and the ``wave_stop`` row of a wave this driver
        started, at the cut (through the clock mapping, else from the first edge's device time)."""
        self._stop_heartbeat()
        cut = wd.cut_device_us
        if cut is None:  # a tripped watchdog says when it cut (WDOG?)
            raise TriggerError(f"{self.where}: its watchdog tripped without saying when it cut the wave")
        self._log(
            "event",
            f"the box's watchdog cut the square wave at device time {cut} us (output off "
            f"mid-period): it had heard nothing from this host for {wd.seconds:g} s",
            device_us=cut,
        )
        m, first = self.mapping, self._wave_first_us
        unc: float | None
        if m is not None:
            host, how, unc = m.to_host(cut), DEVICE_CLOCK_MAPPED, m.uncertainty_s
        elif self._wave is not None and first is not None:
            start, _, how, unc = self._wave
            host = start + (cut - first) * 1e-6
        else:  # a wave another program started, and no clock mapping: the event line says when
            return
        n = self.edges()[0]
        self._wave = None
        self.log.wave_stopped(self.name, host, rising_edges=n, time_source=how, uncertainty_s=unc, device_us=cut)
