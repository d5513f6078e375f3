"""The contract every trigger and sync generator keeps, and the log they all write.

A trigger generator sends a repeating square wave into the SPECT gating input and
contact-closure start pulses to the VTS recorder (channel 1) and the SPECT (channel 2).
Backends: our trigger box (serial), a SCPI function generator (VISA), an NI-DAQmx counter.

Each backend declares what it can do in ``capabilities``; asking for anything else raises
:class:`Unsupported` (one sentence naming the device and what it cannot do), never a silent
no-op. Every command and reply, and every edge time a device reports, is appended to the
session's ``trigger.csv`` by :class:`TriggerLog`; beside them each backend writes what it
started and stopped in neutral rows (:meth:`TriggerLog.wave_started`, :meth:`~TriggerLog.wave_stopped`,
:meth:`~TriggerLog.clock_mapped`; docs/trigger-log-format.md), which is all the sync analysis
and the simulated SPECT read.

A backend is registered by name in ``vts_hw.drivers.registry.TRIGGER_BACKENDS`` as a
:class:`TriggerBackend`: its own settings model (the keys of rig.yaml's ``trigger:`` section
beyond the common ones, validated when it is opened) and its constructor.
"""

from __future__ import annotations

import csv
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

from pydantic import BaseModel, ConfigDict

from vts_hw.bounded import ANY_SIZE, TABLE, open_bounded, open_checked
from vts_hw.errors import DeviceError, UsageError
from vts_hw.files import WriteFailed, check_target, open_writable, os_reason
from vts_hw.recording.trigger_log import CLOCK as CLOCK_ROW
from vts_hw.recording.trigger_log import LOG_HEADER, WAVE_START, WAVE_STOP, clock_text, wave_start_text, wave_stop_text

# what a backend can do
FREQUENCY = "frequency"  # set the square wave's frequency
DUTY = "duty"  # set its duty cycle
LEVELS = "levels"  # set its high and low voltages
PULSE = "pulse"  # a start pulse on channel 1 or 2
FIRE = "fire"  # square wave and both start pulses on the same tick
CLOCK = "clock"  # a device clock that can be mapped to host time
EDGES = "edges"  # reports the times of the edges it sent
WATCHDOG = "watchdog"  # switches its output off by itself when the host falls silent

CHANNELS = {1: "VTS start", 2: "SPECT start"}


class TriggerError(DeviceError):
    """A trigger generator failed or refused a command; the message names it."""


class Unsupported(TriggerError):
    """The backend cannot do what was asked."""


class OutOfRange(TriggerError, ValueError):
    """A value outside the device's range. Raised before anything is sent to the device."""


@dataclass(frozen=True)
class TriggerStatus:
    """What the device confirms (not what was asked)."""

    device: str
    running: bool
    frequency_hz: float | None = None
    duty: float | None = None
    high_v: float | None = None
    low_v: float | None = None
    edges: int | None = None  # rising edges since the last start
    first_edge_device_us: int | None = None
    last_edge_device_us: int | None = None
    errors: tuple[str, ...] = ()
    extra: dict = field(default_factory=dict)
    notes: tuple[str, ...] = ()  # what else the device says, one line each (its watchdog)

    def not_a_square_wave(self) -> str | None:
        """What in the confirmed values no square wave can have (None when they describe one):
        a frequency not above 0, a duty not between 0 and 1, a level not finite."""
        f, d = self.frequency_hz, self.duty
        if f is None or not math.isfinite(f) or f <= 0 or d is None or not 0 < d < 1:
            return f"{f!r} Hz at duty {d!r}"
        if any(v is not None and not math.isfinite(v) for v in (self.high_v, self.low_v)):
            return f"levels {self.low_v!r}..{self.high_v!r} V"
        return None


@dataclass(frozen=True)
class ClockMapping:
    """host_time = ref_host + (device_us - ref_device_us) * 1e-6 * (1 + drift_ppm * 1e-6).

    Fitted from round trips; ``residual_s`` is the RMS of the fit, ``uncertainty_s`` half the
    shortest round trip (the most the midpoint can be off by)."""

    ref_host: float
    ref_device_us: int
    drift_ppm: float
    residual_s: float
    uncertainty_s: float
    samples: int

    def to_host(self, device_us: int | float) -> float:
        return self.ref_host + (device_us - self.ref_device_us) * 1e-6 * (1.0 + self.drift_ppm * 1e-6)

    def to_device_us(self, host_t: float) -> float:
        return self.ref_device_us + (host_t - self.ref_host) / (1e-6 * (1.0 + self.drift_ppm * 1e-6))


@runtime_checkable
class TriggerGenerator(Protocol):
    """The contract. Every method returns what the device confirms."""

    name: str
    capabilities: frozenset[str]
    log: TriggerLog  # trigger.csv's lines (TriggerBase gives every backend one)

    def configure(
        self, frequency_hz: float, duty: float = 0.5, high_v: float | None = None, low_v: float | None = None
    ) -> TriggerStatus: ...
    def start(self) -> TriggerStatus: ...  # the square wave alone
    def stop(self) -> TriggerStatus: ...  # ends on a whole period where the device can
    def pulse(self, channel: int, ms: int) -> None: ...
    def fire(self) -> TriggerStatus: ...  # square wave and both start pulses together
    def status(self) -> TriggerStatus: ...
    def clock_mapping(self, samples: int = 20) -> ClockMapping: ...
    def close(self) -> None: ...


class TriggerBase:
    """Shared behaviour: capability checks, channel checks, the log."""

    name: str = "trigger"
    capabilities: frozenset[str] = frozenset()

    def __init__(self, name: str, log: TriggerLog | None = None):
        self.name = name
        self.log = log or TriggerLog(None)

    def require(self, capability: str, what: str | None = None) -> None:
        if capability not in self.capabilities:
            raise Unsupported(f"{self.name} cannot {what or _WHAT.get(capability, capability)}")

    @staticmethod
    def check_channel(channel: int) -> None:
        if channel not in CHANNELS:
            raise ValueError(f"start pulse channel must be 1 (VTS) or 2 (SPECT), not {channel}")

    def clock_mapping(self, samples: int = 20) -> ClockMapping:
        self.require(CLOCK)
        raise NotImplementedError  # pragma: no cover

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self.log.close()


_WHAT = {
    FREQUENCY: "set a frequency",
    DUTY: "set a duty cycle",
    LEVELS: "set output levels",
    PULSE: "send a start pulse",
    FIRE: "start the square wave and the start pulses together",
    CLOCK: "report a device clock to map to host time",
    EDGES: "report edge times",
    WATCHDOG: "switch its output off by itself when the host falls silent",
}


def _check_is_trigger_log(path: Path) -> None:
    """A file that is not a trigger log is never appended to: UsageError (exit 2) naming it. A
    trigger log's first line is its header: ``host_time`` first, ``device``, ``kind`` and ``text``
    among the columns (LOG_HEADER, or a log of another version)."""
    with open_checked(path, ANY_SIZE, "trigger log") as f:  # a device or pipe: refused, never waited on
        first = (f.readline(4096).decode("utf-8", "replace").splitlines() or [""])[0]  # CR-only lines too
    try:
        fields = next(csv.reader([first]), []) if first else []
    except csv.Error:  # a NUL or a quote csv cannot read: not our header
        fields = []
    if not (fields[:1] == [LOG_HEADER[0]] and {"device", "kind", "text"} <= set(fields)):
        raise UsageError(
            f"{path} is not a trigger log (its first line is not a header such as "
            f"{','.join(LOG_HEADER)!r}), so it was left as it was: name a new file or a trigger "
            "log with --log"
        )


class TriggerLog:
    """Append-only ``trigger.csv``: host time, device time (where known), device, kind, text.

    Kinds: ``cmd`` (sent), ``reply`` (received), ``edge`` (an edge time the device reported),
    ``event`` (anything else worth keeping: a reconnect, a fitted clock mapping). Each line
    is flushed as written, so a crash keeps everything logged before it. ``None`` as the path
    keeps the lines in memory only (``lines``).
    """

    def __init__(self, path: str | os.PathLike | None, clock=time.time):
        self.path = Path(path) if path is not None else None
        self.clock = clock
        self.lines: list[list[str]] = []
        self.write_error: WriteFailed | None = None  # the file stopped taking lines (kept in ``lines``)
        self._lock = threading.Lock()
        self._f = None
        if self.path is not None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                # a device, FIFO (appending to it blocks), folder or symbolic link: refused, left as it is
                old = check_target(self.path, "nothing was sent to the device")
                new = old is None or old.st_size == 0
                if not new:
                    _check_is_trigger_log(self.path)
                self._f = open_writable(
                    self.path, "a", newline="", encoding="utf-8", kept="nothing was sent to the device"
                )
                self._w = csv.writer(self._f)
                if new:
                    self._w.writerow(LOG_HEADER)
                    self._f.flush()
            except OSError as exc:
                raise WriteFailed(self.path, os_reason(exc), "nothing was sent to the device") from None

    def write(
        self, device: str, kind: str, text: str, device_us: int | float | None = None, host_time: float | None = None
    ) -> None:
        """Log one line. A file that stops taking lines (disk full) never stops the device: the
        line is kept in memory and ``write_error`` says from which line on the file is short."""
        row = [
            f"{self.clock() if host_time is None else host_time:.6f}",
            "" if device_us is None else f"{device_us:.0f}",
            device,
            kind,
            text,
        ]
        with self._lock:
            self.lines.append(row)
            if self._f is not None and self.path is not None and not self._f.closed and self.write_error is None:
                try:
                    self._w.writerow(row)
                    self._f.flush()
                except OSError as exc:
                    self.write_error = WriteFailed(
                        self.path, os_reason(exc), f"it holds the first {len(self.lines) - 1} line(s) of this run"
                    )

    # -- the neutral rows (docs/trigger-log-format.md) ------------------------------------------

    def wave_started(
        self,
        device: str,
        host_time: float,
        *,
        period_s: float,
        duty: float,
        high_v: float,
        low_v: float,
        start_pulse: bool,
        time_source: str,
        uncertainty_s: float | None,
        device_us: int | None = None,
    ) -> None:
        """A ``wave_start`` row: the square wave's first rising edge at ``host_time``."""
        self.write(
            device,
            WAVE_START,
            wave_start_text(
                period_s=period_s,
                duty=duty,
                high_v=high_v,
                low_v=low_v,
                start_pulse=start_pulse,
                time_source=time_source,
                uncertainty_s=uncertainty_s,
            ),
            device_us=device_us,
            host_time=host_time,
        )

    def wave_stopped(
        self,
        device: str,
        host_time: float,
        *,
        rising_edges: int | None,
        time_source: str,
        uncertainty_s: float | None,
        device_us: int | None = None,
    ) -> None:
        """A ``wave_stop`` row: the output idle from ``host_time`` (after ``rising_edges`` whole
        periods where the device counts them)."""
        self.write(
            device,
            WAVE_STOP,
            wave_stop_text(rising_edges=rising_edges, time_source=time_source, uncertainty_s=uncertainty_s),
            device_us=device_us,
            host_time=host_time,
        )

    def clock_mapped(self, device: str, mapping: ClockMapping, drift_se_ppm: float | None) -> None:
        """A ``clock`` row: the device clock's mapping to host time (its reference pair)."""
        self.write(
            device,
            CLOCK_ROW,
            clock_text(
                drift_ppm=mapping.drift_ppm,
                drift_se_ppm=drift_se_ppm,
                residual_s=mapping.residual_s,
                uncertainty_s=mapping.uncertainty_s,
                samples=mapping.samples,
            ),
            device_us=mapping.ref_device_us,
            host_time=mapping.ref_host,
        )

    def close(self) -> None:
        with self._lock:
            if self._f is not None and self.path is not None and not self._f.closed:  # a file has its path
                try:
                    self._f.close()
                except OSError as exc:  # the last buffered line could not be written
                    self.write_error = self.write_error or WriteFailed(self.path, os_reason(exc))


def read_log(path: str | os.PathLike) -> list[dict]:
    with open_bounded(path, TABLE, "trigger log", newline="") as f:
        return list(csv.DictReader(f))


# ---- backends, registered by name (vts_hw.drivers.registry.TRIGGER_BACKENDS) ----------------------


class BackendSettings(BaseModel):
    """A backend's own keys in rig.yaml's ``trigger:`` section (beside the common ones:
    ``backend``, ``address``, ``frequency_hz``, ``duty``, ``high_v``, ``low_v``, ``pulse_ms``).
    Unknown keys are refused, so a misspelt key is an error naming it."""

    model_config = ConfigDict(extra="forbid", frozen=True)


@dataclass(frozen=True)
class TriggerBackend:
    """One trigger backend: ``open(cfg, settings, log)`` makes the generator from the common
    trigger config (``vts_hw.config.TriggerConfig``) and its validated ``settings``."""

    name: str
    what: str  # in words, for plans and messages
    settings: type[BackendSettings]
    open: Callable[[Any, Any, TriggerLog], TriggerGenerator]
    levels: bool = False  # it sets output levels (LEVELS)
