"""The trigger side of a scan session: the generator checked, its clock mapped, fired, watched
and stopped (:class:`ScanTrigger`), for :class:`~vts_hw.procedures.scan.ScanSession`.

Only ``check()`` raises, before anything is recorded; every later failure is kept in
``ScanTrigger.info["errors"]`` and the recordings go on.
"""

from __future__ import annotations

import dataclasses
import inspect
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from vts_hw.config import RigConfig
from vts_hw.drivers.registry import open_trigger
from vts_hw.drivers.trigger import CLOCK, EDGES, FIRE, LEVELS, WATCHDOG, TriggerError, TriggerGenerator, TriggerLog
from vts_hw.errors import DeviceError, VtsError

STATUS_EVERY = 5  # a backend without edge counts: its full status every 5 polls
BOOT_WAIT_S = 2.0  # a trigger box reset by the opening of its port is answering by then


class ScanError(DeviceError):
    """The scan could not start, or had to stop before the trigger; the message says why."""

    def __init__(self, message: str, exit_code: int | None = None):
        super().__init__(message)
        if exit_code is not None:
            self.exit_code = exit_code


def plain_dict(obj) -> dict | None:
    """A dataclass as a JSON-ready dict for the manifest (tuples as lists; None stays None)."""
    if obj is None:
        return None
    d = dataclasses.asdict(obj)
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def why(exc: BaseException) -> str:
    """What went wrong, in one line: our errors as they say it, others with their type."""
    return str(exc) if isinstance(exc, VtsError) else f"{type(exc).__name__}: {exc}"


@runtime_checkable
class _Identifies(Protocol):
    """A generator that says what it is (the trigger box's ``*IDN?``)."""

    def identify(self) -> Any: ...


class ScanTrigger:
    """The session's trigger generator: checked, fired, watched and stopped.

    Only ``check()`` raises (before anything is recorded). Every later failure is kept in
    :attr:`info` (``errors``) and the scan goes on recording.
    """

    def __init__(self, rig: RigConfig, clock=time.time, trigger: Callable[[], TriggerGenerator] | None = None):
        """``trigger``: gives the generator when the check first needs it (the room's:
        ``lambda: room.trigger``, which the room closes); without it the rig's is opened here."""
        self.rig = rig
        self._given = trigger
        self.cfg = rig.trigger
        self.clock = clock
        self.gen: TriggerGenerator | None = None
        self.log: TriggerLog | None = None
        self.fired: bool | None = False  # None: not known (a fire that raised)
        self.edges: int | None = None
        self._polls = 0
        self.lost = False  # the device failed during the scan: no more polling
        self._closed = False
        self._lock = threading.Lock()
        c = self.cfg
        self.info: dict = {"backend": c.backend, "address": c.address, "fired": False, "errors": []}
        if c.backend == "none":
            self.info.update(mode="none", note="no trigger generator (trigger backend none): recording only")
        else:
            self.info["asked"] = {
                "frequency_hz": c.frequency_hz,
                "duty": c.duty,
                "high_v": c.high_v,
                "low_v": c.low_v,
                "pulse_ms": c.pulse_ms,
            }

    @property
    def present(self) -> bool:
        return self.cfg.backend != "none"

    def caps(self) -> frozenset:
        return getattr(self.gen, "capabilities", frozenset())

    def error(self, when: str, exc: BaseException | str) -> None:
        text = f"{when}: {exc if isinstance(exc, str) else why(exc)}"
        with self._lock:
            if text not in self.info["errors"]:
                self.info["errors"].append(text)

    # -- before the recording --------------------------------------------------------------------
    def check(self) -> None:
        """Open, read the status, stop a square wave left running, configure, map the clock.

        The log is kept in memory until :meth:`attach_log` (no file before the scan starts)."""
        if not self.present:
            return
        try:
            self.gen = gen = (
                self._given() if self._given is not None else open_trigger(self.rig, None, clock=self.clock)
            )
            self.log = gen.log
            if isinstance(gen, _Identifies):
                self.info["idn"] = self._identify(gen)
            st = gen.status()
            if st.running:
                self.info["was_running"] = True
                gen.stop()
            levels = (self.cfg.high_v, self.cfg.low_v) if LEVELS in self.caps() else (None, None)
            if LEVELS not in self.caps():  # fixed TTL levels: nothing to ask
                for key in ("high_v", "low_v"):
                    self.info["asked"].pop(key)
            self.info["confirmed"] = plain_dict(gen.configure(self.cfg.frequency_hz, self.cfg.duty, *levels))
            self.info["device"] = gen.name
            self.info["capabilities"] = sorted(self.caps())
            if WATCHDOG not in self.caps():  # said before the scan, kept in the manifest (decision 0083)
                self.info["no_watchdog"] = (
                    f"the {self.cfg.backend} trigger cannot switch its square wave off by itself: "
                    "if this computer stops during the scan (killed, crashed), the wave stays on "
                    "until `vts trigger stop`"
                )
        except Exception as exc:
            self.close()
            where = f"{self.cfg.backend} trigger at {self.cfg.address}"
            raise ScanError(
                f"cannot start the scan: {why(exc)}"
                if isinstance(exc, VtsError)
                else f"cannot start the scan: the {where} failed ({why(exc)})",
                getattr(exc, "exit_code", None),
            ) from None
        self.map_clock("clock_mapping_before")

    def _identify(self, gen: _Identifies) -> str:
        """``*IDN?``, once more after a pause if it timed out: opening a real Uno's port resets
        the board, and its bootloader holds the line for about 1.5 s (docs/decisions/0011)."""
        try:
            return gen.identify().raw
        except TriggerError as exc:
            if type(exc) is not TriggerError:  # refused or gone: not a board still booting
                raise
            time.sleep(BOOT_WAIT_S)
            return gen.identify().raw

    def map_clock(self, key: str) -> None:
        if self.gen is None or CLOCK not in self.caps():
            return
        try:
            self.info[key] = plain_dict(self.gen.clock_mapping())
        except Exception as exc:
            self.error("clock mapping", exc)

    def attach_log(self, path: Path) -> None:
        """Write what was logged so far to ``path`` (trigger.csv) and log there from now on."""
        if self.gen is None:
            return
        mem, log = self.gen.log, TriggerLog(path, clock=self.clock)
        for host, dev, device, kind, text in mem.lines:
            log.write(device, kind, text, device_us=float(dev) if dev else None, host_time=float(host))
        self.gen.log = self.log = log
        self.info["log"] = path.name

    # -- the scan --------------------------------------------------------------------------------
    def fire(self) -> None:
        """Start pulses and square wave together; the square wave alone where there are no pulses."""
        if self.gen is None:
            return
        sent = self.clock()
        try:
            if FIRE in self.caps():
                kw = (
                    {"pulse_ms": self.cfg.pulse_ms} if "pulse_ms" in inspect.signature(self.gen.fire).parameters else {}
                )
                st = self.gen.fire(**kw)
                self.info.update(mode="start pulses and square wave", start_pulses=True)
            else:
                st = self.gen.start()
                self.info.update(
                    mode="square wave only",
                    start_pulses=False,
                    note=f"{self.gen.name} cannot send start pulses: the square wave was started "
                    f"alone; the SPECT is started by hand",
                )
        except Exception as exc:
            self.info["fire_sent_host_time"] = sent
            self.error("fire", exc)
            self.fired = None  # unknown: stop() switches the output off to be sure
            return
        self.fired = True
        first = st.extra.get("first_edge_host")
        self.info.update(
            fired=True,
            fire_sent_host_time=sent,
            fire_confirmed_host_time=self.clock(),
            fire_time=first if first is not None else sent,
            fire_time_source=(
                "first rising edge, device clock mapped to host"
                if first is not None
                else "host time when the command was sent"
            ),
            fire_status=plain_dict(st),
        )
        self.edges = st.edges

    def poll(self) -> None:
        """Read the edges so far (trigger box), else the status every few calls; a failure is
        noted, not raised."""
        if self.gen is None or not self.fired or self.lost:
            return
        self._polls += 1
        try:
            if EDGES in self.caps() and hasattr(self.gen, "edges"):
                self.edges = self.gen.edges()[0]
            elif self._polls % STATUS_EVERY == 0:
                st = self.gen.status()
                if not st.running:
                    self.error("during the scan", f"{self.gen.name} reports its output off")
        except Exception as exc:
            self.error("during the scan", exc)
            self.lost = True  # not asked again until the stop: one sentence, not one a second

    def stop(self) -> None:
        """Square wave off where it may be on (the trigger box ends its period first)."""
        if self.gen is None or self.fired is False:
            return
        try:
            st = self.gen.stop()
            self.info["stop_status"] = plain_dict(st)
            self.info["stopped_host_time"] = self.clock()
            for e in st.errors:  # queued during the scan: e.g. the trigger box's watchdog cut the wave
                self.error("stop", f"{self.gen.name} reports {e}")
            if st.edges is not None:
                self.edges = st.edges
        except Exception as exc:
            self.error("stop", exc)
            self.lost = True

    def finish(self) -> None:
        """After the recordings are closed: the clock mapped again (over the whole session), closed."""
        if self.gen is None:
            return
        if self.fired and not self.lost:
            self.map_clock("clock_mapping_after")
        self.info["edges"] = self.edges
        self.close()

    def close(self) -> None:
        if self.gen is not None and not self._closed:
            self._closed = True
            try:
                self.gen.close()
            except Exception as exc:
                self.error("close", exc)

    def live(self) -> dict:
        with self._lock:
            errors = list(self.info["errors"])
        return {
            "backend": self.cfg.backend,
            "mode": self.info.get("mode"),
            "fired": self.fired,
            "edges": self.edges,
            "fire_time": self.info.get("fire_time"),
            "errors": errors,
        }


# ---- the session -------------------------------------------------------------------------------
