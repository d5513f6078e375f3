"""``trigger.csv``: the neutral rows every trigger backend writes, and the one reader of them.

The format is specified in ``docs/trigger-log-format.md``. Columns ``host_time,
device_time_us, device, kind, text``; beside a backend's own ``cmd``/``reply``/``edge``/``event``
rows (its wire, for people) it writes **neutral rows** (for programs) whose ``text`` is
``key=value`` pairs separated by spaces:

* ``wave_start`` — a square wave started. ``host_time``: its first rising edge, host UTC
  epoch s, as well as the backend knows it; ``device_time_us``: that edge on the device's clock
  when the device reports it. Keys: ``period_s`` (device seconds), ``duty`` (fraction),
  ``high_v``, ``low_v``, ``start_pulse`` (``yes``: the SPECT start pulse went out with the
  first edge), ``time`` (how ``host_time`` is known: :data:`TIME_SOURCES`) and
  ``uncertainty_s`` (the most the true time can be off ``host_time``, either way).
* ``wave_stop`` — the wave stopped. ``host_time``: when the output went idle; keys
  ``rising_edges`` (rising edges sent since the start, when the device counts them: the end is
  then ``start + rising_edges × period``, the last period whole), ``time``, ``uncertainty_s``.
* ``clock`` — the device's clock mapped to host time (``host_time``/``device_time_us``: the
  reference pair); keys ``drift_ppm``, ``drift_se_ppm``, ``residual_s``, ``uncertainty_s``,
  ``samples``.

The sync analysis and the simulated SPECT read these rows only (:func:`wave_from_trigger_log`).
A log written before they existed (no neutral row at all) is converted on read, in one place
(:mod:`vts_hw.recording.trigger_log_legacy`), so old sessions stay sync-checkable
(docs/decisions/0032-neutral-trigger-log.md).
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vts_hw.bounded import TABLE, open_bounded
from vts_hw.errors import DataError

__all__ = ["WAVE_START", "WAVE_STOP", "CLOCK", "NEUTRAL_KINDS", "DEVICE_CLOCK_MAPPED", "HOST_WRITE",
           "TIME_SOURCES", "LOG_HEADER", "wave_start_text", "wave_stop_text", "clock_text",
           "parse_fields", "read_trigger_rows", "WaveInfo", "wave_from_trigger_log", "square_wave_edges"]

LOG_HEADER = ["host_time", "device_time_us", "device", "kind", "text"]

WAVE_START = "wave_start"
WAVE_STOP = "wave_stop"
CLOCK = "clock"
NEUTRAL_KINDS = (WAVE_START, WAVE_STOP, CLOCK)

#: how a neutral row's host time is known
DEVICE_CLOCK_MAPPED = "device_clock_mapped"   # the device timed the edge; its clock fitted to the host's
HOST_WRITE = "host_write"                     # the host time of the write that made it happen
TIME_SOURCES = {
    DEVICE_CLOCK_MAPPED: "the device's own time of the edge, mapped to host time through a fitted clock mapping",
    HOST_WRITE: "the host time just before the write that started or stopped it",
}

#: SPECT gating drift correction is applied only from a clock mapping at least this good
DRIFT_SE_MAX_PPM = 2.0


# ---------------------------------------------------------------------------------- writing

def _num(v: float) -> str:
    return repr(float(v))


def _short(v: float | None) -> float | None:
    """An uncertainty or a residual to 3 significant digits (None stays None)."""
    return None if v is None else float(f"{float(v):.3g}")


def _fields(pairs: dict) -> str:
    out = []
    for key, value in pairs.items():
        if value is None:
            continue
        if isinstance(value, bool):
            text = "yes" if value else "no"
        elif isinstance(value, int):
            text = str(value)
        elif isinstance(value, float):
            text = _num(value)
        else:
            text = str(value)
        if not text or any(c.isspace() for c in text) or "=" in text:
            raise ValueError(f"a trigger-log value has no spaces or '=': {key}={text!r}")
        out.append(f"{key}={text}")
    return " ".join(out)


def _check_time(time_source: str) -> None:
    if time_source not in TIME_SOURCES:
        raise ValueError(f"time must be one of {', '.join(TIME_SOURCES)}, not {time_source!r}")


def wave_start_text(*, period_s: float, duty: float, high_v: float, low_v: float, start_pulse: bool,
                    time_source: str, uncertainty_s: float | None) -> str:
    """The ``text`` of a ``wave_start`` row (``uncertainty_s`` None: not known, left out)."""
    _check_time(time_source)
    if not (period_s > 0 and 0 < duty < 1 and math.isfinite(high_v) and math.isfinite(low_v)):
        raise ValueError(f"not a square wave: period {period_s!r} s, duty {duty!r}, levels {low_v!r}..{high_v!r} V")
    return _fields({"period_s": float(period_s), "duty": float(duty), "high_v": float(high_v),
                    "low_v": float(low_v), "start_pulse": bool(start_pulse), "time": time_source,
                    "uncertainty_s": _short(uncertainty_s)})


def wave_stop_text(*, rising_edges: int | None, time_source: str, uncertainty_s: float | None) -> str:
    """The ``text`` of a ``wave_stop`` row (``rising_edges`` None: the device does not count them)."""
    _check_time(time_source)
    return _fields({"rising_edges": None if rising_edges is None else int(rising_edges),
                    "time": time_source,
                    "uncertainty_s": _short(uncertainty_s)})


def clock_text(*, drift_ppm: float, drift_se_ppm: float | None, residual_s: float | None,
               uncertainty_s: float | None, samples: int | None) -> str:
    """The ``text`` of a ``clock`` row (None: not known, left out; an infinite standard error,
    a drift not measurable from the samples, is written ``inf``)."""
    def opt(v):
        return None if v is None else _short(v) if math.isfinite(v) else "inf"
    return _fields({"drift_ppm": float(drift_ppm), "drift_se_ppm": opt(drift_se_ppm),
                    "residual_s": opt(residual_s), "uncertainty_s": opt(uncertainty_s),
                    "samples": None if samples is None else int(samples)})


# ---------------------------------------------------------------------------------- reading

def parse_fields(text: str) -> dict[str, str]:
    """``key=value key=value`` -> dict (values as text); a token without ``=`` is skipped."""
    out = {}
    for token in (text or "").split():
        key, eq, value = token.partition("=")
        if eq:
            out[key] = value
    return out


def _float(text) -> float | None:
    try:
        v = float(text)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def read_trigger_rows(path: str | os.PathLike) -> list[dict]:
    """Every row of a ``trigger.csv`` as a dict of its columns; DataError naming the file when
    it is missing, unreadable or not a trigger log."""
    path = Path(path)
    try:
        with open_bounded(path, TABLE, "trigger log", newline="") as f:
            rows = list(csv.DictReader(f))
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise DataError(f"{path}: cannot read the trigger log ({e})") from None
    if rows and not {"host_time", "device", "kind", "text"} <= set(rows[0]):
        raise DataError(f"{path}: not a trigger log (columns {', '.join(LOG_HEADER)})")
    return rows


@dataclass(frozen=True)
class WaveInfo:
    """The square wave a trigger log says was sent (host UTC epoch s, volts)."""

    device: str
    start_host: float             # the first rising edge
    period_s: float
    duty: float
    stop_host: float | None       # the wave's end (None: still running when the log ends)
    n_rising: int | None          # rising edges sent, when the device reported it
    high_v: float
    low_v: float
    start_pulse: bool             # the SPECT start pulse came with the first edge
    how: str                      # how start_host is known, in words
    drift_ppm: float | None = None     # the device clock against the host (last clock mapping)
    drift_se_ppm: float | None = None  # its standard error
    time_source: str = HOST_WRITE      # TIME_SOURCES key of start_host
    uncertainty_s: float | None = None  # the most start_host can be off, either way
    converted: bool = False            # read from an old log's wire text (no neutral rows)

    @property
    def host_period_s(self) -> float:
        """The period in host seconds: ``period_s`` (the device's own seconds) corrected by the
        device's drift when the log's last clock mapping measured it to 2 ppm or better (a
        mapping spanning the session: one before and one after the scan); else ``period_s``."""
        if self.drift_ppm is not None and self.drift_se_ppm is not None and self.drift_se_ppm <= DRIFT_SE_MAX_PPM:
            return self.period_s * (1.0 + self.drift_ppm * 1e-6)
        return self.period_s


def _how(time_source: str, uncertainty_s: float | None) -> str:
    words = {DEVICE_CLOCK_MAPPED: "first edge, host time mapped from the device clock",
             HOST_WRITE: "first edge, host time of the write that started it"}.get(time_source, time_source)
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
        from vts_hw.recording.trigger_log_legacy import neutral_rows
        try:
            rows = neutral_rows([r for r in rows if device in (None, r.get("device"))])
        except ValueError as e:
            raise DataError(f"{path}: {e}") from None
    rows = [r for r in rows if r.get("kind") in NEUTRAL_KINDS and device in (None, r.get("device"))
            and _float(r.get("host_time")) is not None]
    starts = [i for i, r in enumerate(rows) if r["kind"] == WAVE_START]
    if not starts:
        raise DataError(f"{path}: no square wave was started in this trigger log"
                        + (f" by {device!r}" if device else ""))
    i = starts[-1]
    row = rows[i]
    dev = row.get("device")
    f = parse_fields(row.get("text"))
    period, duty = _float(f.get("period_s")), _float(f.get("duty"))
    high, low = _float(f.get("high_v")), _float(f.get("low_v"))
    if not period or period <= 0 or duty is None or high is None or low is None:
        raise DataError(f"{path}: the wave_start row of {dev} at {row['host_time']} lacks period_s, duty, "
                        f"high_v or low_v (docs/trigger-log-format.md)")
    start = float(row["host_time"])
    time_source = f.get("time", HOST_WRITE)
    unc = _float(f.get("uncertainty_s"))
    stop, n = None, None
    for r in rows[i + 1:]:
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
            if _float(g.get("drift_ppm")) is not None:
                drift, drift_se = _float(g.get("drift_ppm")), _float(g.get("drift_se_ppm"))
    how = _how(time_source, unc) + (" (converted from an old log's wire text)" if converted else "")
    return WaveInfo(device=dev, start_host=start, period_s=period, duty=duty, stop_host=stop, n_rising=n,
                    high_v=high, low_v=low, start_pulse=f.get("start_pulse") == "yes", how=how,
                    drift_ppm=drift, drift_se_ppm=drift_se, time_source=time_source, uncertainty_s=unc,
                    converted=converted)


MAX_RISING_EDGES = 10**7   # a 1 kHz wave for almost 3 h; a sync wave is about 1 Hz for an hour


def _plausible(path, dev, at, period: float, duty: float, start: float, stop, n) -> None:
    """A wave no trigger device of ours can have made (a duty outside 0-1, a period beyond
    1 µs-1 h, a stop before its start, more than MAX_RISING_EDGES edges) is a DataError naming
    the file: such a log was edited or damaged, and its edges would mean nothing."""
    edges = n if n is not None else ((stop - start) / period if stop is not None else 0)
    why = ("its duty is not between 0 and 1" if not 0 < duty < 1 else
           "its period is not between 1 µs and 1 h" if not 1e-6 <= period <= 3600 else
           "it stops before it starts" if stop is not None and not stop >= start else
           f"it has more than {MAX_RISING_EDGES:.0e} rising edges" if not edges <= MAX_RISING_EDGES else None)
    if why:
        raise DataError(f"{path}: the wave_start row of {dev} at {at} describes no wave a trigger device makes:"
                        f" {why} (period_s={period:g}, duty={duty:g}); the log was edited or damaged")


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
    if wave.n_rising is None:              # cut at the stop: a high phase ends there
        falling = np.minimum(falling, end)
    return rising, falling
