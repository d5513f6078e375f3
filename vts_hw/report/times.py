"""Time helpers for reports: ``parse_since`` for the CLI and UTC date formatting."""

from __future__ import annotations

import datetime as _dt
import math
import re
import time

from vts_hw.errors import ConfigError

_UNITS = {"h": 3600.0, "d": 86400.0, "w": 7 * 86400.0}
_RELATIVE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([hdw])\s*$", re.IGNORECASE)


class BadSince(ConfigError, ValueError):
    """A ``--since`` value that is neither a duration nor a date, or one outside 1970 .. now
    (a usage error: exit 2)."""


def _shown(text: str) -> str:
    """The value as given, quoted, cut to a readable length."""
    t = repr(text or "")
    return t if len(t) <= 40 else t[:36] + "…" + t[-1]


EARLIEST = 0.0  # 1970-01-01: no run can be older; a period reaching further back is a typo


def parse_since(text: str, now: float | None = None) -> float | None:
    """The start of a report period as UTC epoch seconds (None for ``all``: the whole store).

    ``"12h"``, ``"60d"``, ``"8w"`` count back from ``now`` (default: the current time);
    ``"2026-09-01"`` is that day's 00:00 UTC; ``"2026-09-01T08:30"`` (ISO 8601, UTC unless an
    offset is given) that moment; ``"all"`` every run. Anything else, a start before
    1970-01-01 (``1000000d``) or after ``now``, raises ``BadSince`` (a ``ConfigError``, exit 2,
    and a ``ValueError``) in one sentence saying what is accepted.
    """
    s = (text or "").strip()
    now = time.time() if now is None else float(now)
    if s.lower() == "all":
        return None
    m = _RELATIVE.match(s)
    if m:
        back = float(m.group(1)) * _UNITS[m.group(2).lower()]
        start = now - back
        if not math.isfinite(start) or start < EARLIEST:
            raise BadSince(
                f"--since {_shown(text)} reaches back before 1970-01-01, earlier than any run can be: "
                f"give at most {int((now - EARLIEST) // 86400)}d, a date, or --since all"
            )
        return start
    try:
        dt = _dt.datetime.fromisoformat(s.replace("Z", "+00:00"))
        if dt.tzinfo is None:
            dt = dt.replace(tzinfo=_dt.UTC)
        start = dt.timestamp()
    except (ValueError, OverflowError, OSError):
        raise BadSince(
            f"--since {_shown(text)}: expected a duration such as 12h, 60d or 8w, a UTC date such as 2026-09-01, or all"
        ) from None
    if start < EARLIEST:
        raise BadSince(
            f"--since {_shown(text)} is before 1970-01-01, earlier than any run can be: "
            f"give a later date, or --since all"
        )
    if start > now:
        raise BadSince(
            f"--since {_shown(text)} is in the future (now is {fmt_datetime(now)}): "
            f"give a date up to today, or a duration such as 60d"
        )
    return start


def utc(t: float) -> _dt.datetime:
    """Epoch seconds as an aware UTC datetime."""
    return _dt.datetime.fromtimestamp(t, _dt.UTC)


def fmt_date(t: float | None) -> str:
    return "–" if t is None else utc(t).strftime("%Y-%m-%d")


def fmt_datetime(t: float | None) -> str:
    return "–" if t is None else utc(t).strftime("%Y-%m-%d %H:%M UTC")
