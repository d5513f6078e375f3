"""Time helpers for reports: ``parse_since`` for the CLI and UTC date formatting."""

from __future__ import annotations

import datetime as _dt
import re
import time

from ..errors import VtsError

_UNITS = {"h": 3600.0, "d": 86400.0, "w": 7 * 86400.0}
_RELATIVE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*([hdw])\s*$", re.IGNORECASE)


class BadSince(VtsError, ValueError):
    """A ``--since`` value that is neither a duration nor a date."""


def parse_since(text: str, now: float | None = None) -> float:
    """The start of a report period as UTC epoch seconds.

    ``"12h"``, ``"60d"``, ``"8w"`` count back from ``now`` (default: the current time);
    ``"2026-09-01"`` is that day's 00:00 UTC; ``"2026-09-01T08:30"`` (ISO 8601, UTC unless an
    offset is given) that moment. Anything else raises ``BadSince`` (a ``ValueError``) saying
    what is accepted.
    """
    s = (text or "").strip()
    m = _RELATIVE.match(s)
    if m:
        now = time.time() if now is None else float(now)
        return now - float(m.group(1)) * _UNITS[m.group(2).lower()]
    try:
        dt = _dt.datetime.fromisoformat(s.replace("Z", "+00:00"))
    except ValueError:
        raise BadSince(f"--since {text!r}: expected a duration such as 12h, 60d or 8w, "
                       f"or a UTC date such as 2026-09-01") from None
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=_dt.timezone.utc)
    return dt.timestamp()


def utc(t: float) -> _dt.datetime:
    """Epoch seconds as an aware UTC datetime."""
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc)


def fmt_date(t: float | None) -> str:
    return "–" if t is None else utc(t).strftime("%Y-%m-%d")


def fmt_datetime(t: float | None) -> str:
    return "–" if t is None else utc(t).strftime("%Y-%m-%d %H:%M UTC")
