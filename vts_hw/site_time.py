"""An instant as another program's wall clock shows it, and back.

Some peers read the times they are sent as wall-clock times of their own zone, with no offset:
QATrack+ 3.1 accepts only naive formats (``YYYY-MM-DD hh:mm:ss`` and a few more; even its
``...Z`` form is read as local time) and makes them aware in its ``TIME_ZONE`` (Django, pytz,
``is_dst=None``). So a run's instant must be written as that zone's wall-clock time, and an
instant whose wall-clock time happens twice (the hour repeated when the clocks go back) cannot
be written at all: QATrack+ refuses it ("Invalid datetime for the timezone"), and anything else
would land an hour off. See docs/decisions/0049-qatrack-time-zone.md.
"""

from __future__ import annotations

import datetime as _dt
import math
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

__all__ = ["site_zone", "wall_clock", "RepeatedWallTime", "instant_of", "offset_text", "zone_disagreement"]

WALL_FORMAT = "%Y-%m-%d %H:%M:%S"


class RepeatedWallTime(ValueError):
    """An instant whose wall-clock time happens twice in the zone (the clocks went back)."""


def site_zone(name: str) -> ZoneInfo:
    """The IANA zone ``name``; ValueError naming it when there is no such zone."""
    try:
        if not isinstance(name, str) or not name or name.startswith(("/", ".")) or ".." in name:
            raise ValueError
        return ZoneInfo(name)
    except (ZoneInfoNotFoundError, ValueError, OSError):
        raise ValueError(
            f"{name!r} is not a time zone name (an IANA name such as America/Toronto, Australia/Sydney or UTC)"
        ) from None


def offset_text(delta: _dt.timedelta | None) -> str:
    """``UTC-05:00`` for an offset."""
    minutes = int((delta or _dt.timedelta(0)).total_seconds() // 60)
    sign = "-" if minutes < 0 else "+"
    return f"UTC{sign}{abs(minutes) // 60:02d}:{abs(minutes) % 60:02d}"


def wall_clock(t: float, zone: ZoneInfo) -> _dt.datetime:
    """The naive wall-clock time of the instant ``t`` (UTC epoch s, taken to the whole second
    below) in ``zone``; RepeatedWallTime when that wall-clock time happens twice there."""
    utc = _dt.datetime.fromtimestamp(math.floor(float(t)), _dt.UTC)
    naive = utc.astimezone(zone).replace(tzinfo=None)
    first = naive.replace(tzinfo=zone, fold=0).utcoffset()
    second = naive.replace(tzinfo=zone, fold=1).utcoffset()
    if first != second:
        raise RepeatedWallTime(
            f"{naive:%Y-%m-%d %H:%M:%S} happens twice in {zone.key} (the clocks go back from "
            f"{offset_text(first)} to {offset_text(second)} that night)"
        )
    return naive


def instant_of(text: str) -> float:
    """The instant (UTC epoch s) of an ISO 8601 time with its offset, as QATrack+ answers them
    (``2026-11-26T07:00:00-05:00``); ValueError for a time without an offset."""
    value = _dt.datetime.fromisoformat(str(text).replace("Z", "+00:00"))
    if value.tzinfo is None:
        raise ValueError(f"{text!r} has no UTC offset")
    return value.timestamp()


def zone_disagreement(zone: ZoneInfo, shown: list[str]) -> str | None:
    """None when every time a peer showed (ISO 8601 with its offset) has the offset ``zone``
    gives that instant; else one sentence naming the first that does not."""
    for text in shown:
        try:
            value = _dt.datetime.fromisoformat(str(text).replace("Z", "+00:00"))
        except ValueError:
            continue
        if value.tzinfo is None:
            continue
        ours = value.astimezone(zone).utcoffset()
        if ours != value.utcoffset():
            return (
                f"the site shows {text}, at {offset_text(value.utcoffset())}, where {zone.key} is at "
                f"{offset_text(ours)}"
            )
    return None
