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

The sync analysis and the simulated SPECT read these rows only, as the wave they describe
(:func:`vts_hw.recording.trigger_wave.wave_from_trigger_log`). A log written before they existed
(no neutral row at all) is converted on read, in one place
(:mod:`vts_hw.recording.trigger_log_legacy`), so old sessions stay sync-checkable
(docs/decisions/0032-neutral-trigger-log.md).
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

from vts_hw.bounded import TABLE, open_bounded
from vts_hw.errors import DataError

__all__ = [
    "WAVE_START",
    "WAVE_STOP",
    "CLOCK",
    "NEUTRAL_KINDS",
    "DEVICE_CLOCK_MAPPED",
    "HOST_WRITE",
    "TIME_SOURCES",
    "LOG_HEADER",
    "wave_start_text",
    "wave_stop_text",
    "clock_text",
    "parse_fields",
    "read_trigger_rows",
    "finite_float",
]

LOG_HEADER = ["host_time", "device_time_us", "device", "kind", "text"]

WAVE_START = "wave_start"
WAVE_STOP = "wave_stop"
CLOCK = "clock"
NEUTRAL_KINDS = (WAVE_START, WAVE_STOP, CLOCK)

#: how a neutral row's host time is known
DEVICE_CLOCK_MAPPED = "device_clock_mapped"  # the device timed the edge; its clock fitted to the host's
HOST_WRITE = "host_write"  # the host time of the write that made it happen
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


def wave_start_text(
    *,
    period_s: float,
    duty: float,
    high_v: float,
    low_v: float,
    start_pulse: bool,
    time_source: str,
    uncertainty_s: float | None,
) -> str:
    """The ``text`` of a ``wave_start`` row (``uncertainty_s`` None: not known, left out)."""
    _check_time(time_source)
    if not (period_s > 0 and 0 < duty < 1 and math.isfinite(high_v) and math.isfinite(low_v)):
        raise ValueError(f"not a square wave: period {period_s!r} s, duty {duty!r}, levels {low_v!r}..{high_v!r} V")
    return _fields(
        {
            "period_s": float(period_s),
            "duty": float(duty),
            "high_v": float(high_v),
            "low_v": float(low_v),
            "start_pulse": bool(start_pulse),
            "time": time_source,
            "uncertainty_s": _short(uncertainty_s),
        }
    )


def wave_stop_text(*, rising_edges: int | None, time_source: str, uncertainty_s: float | None) -> str:
    """The ``text`` of a ``wave_stop`` row (``rising_edges`` None: the device does not count them)."""
    _check_time(time_source)
    return _fields(
        {
            "rising_edges": None if rising_edges is None else int(rising_edges),
            "time": time_source,
            "uncertainty_s": _short(uncertainty_s),
        }
    )


def clock_text(
    *,
    drift_ppm: float,
    drift_se_ppm: float | None,
    residual_s: float | None,
    uncertainty_s: float | None,
    samples: int | None,
) -> str:
    """The ``text`` of a ``clock`` row (None: not known, left out; an infinite standard error,
    a drift not measurable from the samples, is written ``inf``)."""

    def opt(v):
        return None if v is None else _short(v) if math.isfinite(v) else "inf"

    return _fields(
        {
            "drift_ppm": float(drift_ppm),
            "drift_se_ppm": opt(drift_se_ppm),
            "residual_s": opt(residual_s),
            "uncertainty_s": opt(uncertainty_s),
            "samples": None if samples is None else int(samples),
        }
    )


# ---------------------------------------------------------------------------------- reading


def parse_fields(text: str | None) -> dict[str, str]:
    """``key=value key=value`` -> dict (values as text); a token without ``=`` is skipped."""
    out = {}
    for token in (text or "").split():
        key, eq, value = token.partition("=")
        if eq:
            out[key] = value
    return out


def finite_float(text) -> float | None:
    """A field's number, None when it is missing, not a number or not finite."""
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
