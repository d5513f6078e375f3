"""The square wave a ``trigger.csv`` says was sent, read from its neutral rows
(:mod:`vts_hw.recording.trigger_log`); a log written before them is converted first
(:mod:`vts_hw.recording.trigger_log_legacy`). The sync analysis and the simulated SPECT read
the wave here."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vts_hw.errors import DataError
from vts_hw.recording.trigger_log import (
    CLOCK,
    DEVICE_CLOCK_MAPPED,
    DRIFT_SE_MAX_PPM,
    HOST_WRITE,
    NEUTRAL_KINDS,
    WAVE_START,
    WAVE_STOP,
    finite_float,
    parse_fields,
    read_trigger_rows,
)
from vts_hw.recording.trigger_log_legacy import neutral_rows


@dataclass(frozen=True)
class WaveInfo:
    """The square wave a trigger log says was sent (host UTC epoch s, volts)."""

    device: str | None  # None: the log's row names none (a short line)
    start_host: float  # the first rising edge
    period_s: float
    duty: float
    stop_host: float | None  # the wave's end (None: still running when the log ends)
    n_rising: int | None  # rising edges sent, when the device reported it
    high_v: float
    low_v: float
    start_pulse: bool  # the SPECT start pulse came with the first edge
    how: str  # how start_host is known, in words
    drift_ppm: float | None = None  # the device clock against the host (last clock mapping)
    drift_se_ppm: float | None = None  # its standard error
    time_source: str = HOST_WRITE  # TIME_SOURCES key of start_host
    uncertainty_s: float | None = None  # the most start_host can be off, either way
    converted: bool = False  # read from an old log's wire text (no neutral rows)

    @property
    def host_period_s(self) -> float:
        """The period in host seconds: ``period_s`` (the device's own seconds) corrected by the
        device's drift when the log's last clock mapping measured it to 2 ppm or better (a
        mapping spanning the session: one before and one after the scan); else ``period_s``."""
        if self.drift_ppm is not None and self.drift_se_ppm is not None and self.drift_se_ppm <= DRIFT_SE_MAX_PPM:
            return self.period_s * (1.0 + self.drift_ppm * 1e-6)
        return self.period_s


def _how(time_source: str, uncertainty_s: float | None) -> str:
    words = {
        DEVICE_CLOCK_MAPPED: "first edge, host time mapped from the device clock",
        HOST_WRITE: "first edge, host time of the write that started it",
    }.get(time_source, time_source)
    return words + (f" (± {uncertainty_s * 1e3:.3g} ms)" if uncertainty_s is not None else "")


def wave_from_trigger_log(path, device: str | None = None) -> WaveInfo:
    """The last square wave started in a ``trigger.csv`` (of ``device``, if named), from its
    neutral rows: the ``wave_start``, the first ``wave_stop`` of that device after it, and the
    device's last ``clock`` row. A log with no neutral row at all was written before them: it
    is converted first (:func:`vts_hw.recording.trigger_log_legacy.neutral_rows`). DataError
    naming the file when no wave was started."""
    path = Path(path)
    rows = read_trigger_rows(path)
    converted = not any(r.get("kind") in NEUTRAL_KINDS for r in rows)
    if converted:
        try:
            rows = neutral_rows([r for r in rows if device in (None, r.get("device"))])
        except ValueError as e:
            raise DataError(f"{path}: {e}") from None
    rows = [
        r
        for r in rows
        if r.get("kind") in NEUTRAL_KINDS
        and device in (None, r.get("device"))
        and finite_float(r.get("host_time")) is not None
    ]
    starts = [i for i, r in enumerate(rows) if r["kind"] == WAVE_START]
    if not starts:
        raise DataError(
            f"{path}: no square wave was started in this trigger log" + (f" by {device!r}" if device else "")
        )
    i = starts[-1]
    row = rows[i]
    dev = row.get("device")
    f = parse_fields(row.get("text"))
    period, duty = finite_float(f.get("period_s")), finite_float(f.get("duty"))
    high, low = finite_float(f.get("high_v")), finite_float(f.get("low_v"))
    if not period or period <= 0 or duty is None or high is None or low is None:
        raise DataError(
            f"{path}: the wave_start row of {dev} at {row['host_time']} lacks period_s, duty, "
            f"high_v or low_v (docs/trigger-log-format.md)"
        )
    start = float(row["host_time"])
    time_source = f.get("time", HOST_WRITE)
    unc = finite_float(f.get("uncertainty_s"))
    stop, n = None, None
    for r in rows[i + 1 :]:
        if r.get("device") == dev and r["kind"] == WAVE_STOP:
            g = parse_fields(r.get("text"))
            n = int(g["rising_edges"]) if g.get("rising_edges", "").isdigit() else None
            stop = start + n * period if n is not None else float(r["host_time"])
            break
    _plausible(path, dev, row["host_time"], period, duty, start, stop, n)
    drift, drift_se = None, None
    for r in rows:
        if r.get("device") == dev and r["kind"] == CLOCK:
            g = parse_fields(r.get("text"))
            if finite_float(g.get("drift_ppm")) is not None:
                drift, drift_se = finite_float(g.get("drift_ppm")), finite_float(g.get("drift_se_ppm"))
    how = _how(time_source, unc) + (" (converted from an old log's wire text)" if converted else "")
    return WaveInfo(
        device=dev,
        start_host=start,
        period_s=period,
        duty=duty,
        stop_host=stop,
        n_rising=n,
        high_v=high,
        low_v=low,
        start_pulse=f.get("start_pulse") == "yes",
        how=how,
        drift_ppm=drift,
        drift_se_ppm=drift_se,
        time_source=time_source,
        uncertainty_s=unc,
        converted=converted,
    )


MAX_RISING_EDGES = 10**7  # a 1 kHz wave for almost 3 h; a sync wave is about 1 Hz for an hour


def _plausible(path, dev, at, period: float, duty: float, start: float, stop, n) -> None:
    """A wave no trigger device of ours can have made (a duty outside 0-1, a period beyond
    1 µs-1 h, a stop before its start, more than MAX_RISING_EDGES edges) is a DataError naming
    the file: such a log was edited or damaged, and its edges would mean nothing."""
    edges = n if n is not None else ((stop - start) / period if stop is not None else 0)
    why = (
        "its duty is not between 0 and 1"
        if not 0 < duty < 1
        else "its period is not between 1 µs and 1 h"
        if not 1e-6 <= period <= 3600
        else "it stops before it starts"
        if stop is not None and not stop >= start
        else f"it has more than {MAX_RISING_EDGES:.0e} rising edges"
        if not edges <= MAX_RISING_EDGES
        else None
    )
    if why:
        raise DataError(
            f"{path}: the wave_start row of {dev} at {at} describes no wave a trigger device makes:"
            f" {why} (period_s={period:g}, duty={duty:g}); the log was edited or damaged"
        )


def square_wave_edges(wave: WaveInfo, until: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(rising, falling) host times of the wave a log describes, up to its stop (or ``until``
    when it was still running; required then)."""
    end = wave.stop_host if wave.stop_host is not None else until
    if end is None:
        raise ValueError(f"the wave of {wave.device} was never stopped: give `until`")
    P = wave.period_s
    n = wave.n_rising if wave.n_rising is not None else max(0, math.ceil((end - wave.start_host) / P - 1e-9))
    rising = wave.start_host + np.arange(n) * P
    falling = rising + wave.duty * P
    if wave.n_rising is None:  # cut at the stop: a high phase ends there
        falling = np.minimum(falling, end)
    return rising, falling
