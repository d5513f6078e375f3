"""Failure records: what a list-mode writer leaves where a list-mode would have gone when it
could not record an acquisition (docs/listmode-format.md, "Failure records").

``<folder>/<stem>.failed.json`` beside the ``<stem>.vtslm`` that is missing: who failed, why,
the time span of the scan it should have recorded (the writer's clock, UTC epoch s) and where
its log is. The simulated SPECT writes them (``vts sim up --spect``); ``vts sync analyze``
reads them when no list-mode given belongs to the session, and ``vts sim down`` lists them.
Only a file format: nothing here knows who writes it.
"""

from __future__ import annotations

import datetime as _dt
import json
import time
from dataclasses import dataclass
from pathlib import Path

from vts_hw.bounded import SMALL, read_text
from vts_hw.files import write_json_atomic

__all__ = ["FORMAT", "SUFFIX", "FailureRecord", "write_failure_record", "read_failure_records", "utc_span"]

FORMAT = "vts-listmode-failure/1"
SUFFIX = ".failed.json"


@dataclass
class FailureRecord:
    """One acquisition that was not recorded. Times UTC epoch s (None: not known)."""

    by: str  # who failed to record, e.g. "the simulated SPECT"
    listmode: str  # the file name it would have written
    reason: str  # one line
    start: float | None  # the scan it should have recorded: start (start pulse)
    end: float | None  # and end (the square wave's last edge)
    failed_at: float
    log: str | None = None  # the writer's log, where there is one
    path: Path | None = None  # the record itself (when read)

    @property
    def span(self) -> tuple[float, float]:
        """(start, end) for matching to a session: the known ends, else the failure time."""
        start = self.start if self.start is not None else self.failed_at
        end = self.end if self.end is not None else max(start, self.failed_at)
        return start, end

    def to_json(self) -> dict:
        return {
            "format": FORMAT,
            "by": self.by,
            "listmode": self.listmode,
            "reason": self.reason,
            "start": self.start,
            "end": self.end,
            "failed_at": self.failed_at,
            "log": self.log,
        }

    def describe(self, scan: str = "the scan") -> str:
        """``<by> failed to record <scan> (<span>): <reason>`` (one clause, no full stop)."""
        return f"{self.by} failed to record {scan} ({utc_span(*self.span)}): {self.reason}"


def write_failure_record(
    folder,
    listmode_name: str,
    reason: str,
    *,
    by: str,
    start: float | None = None,
    end: float | None = None,
    log: str | Path | None = None,
) -> Path:
    """Write ``<folder>/<stem>.failed.json`` for the list-mode ``listmode_name`` that could not
    be recorded; whole or not at all (WriteFailed). Returns its path."""
    name = Path(listmode_name).name
    stem = name[: -len(Path(name).suffix)] if Path(name).suffix else name
    rec = FailureRecord(
        by=by,
        listmode=name,
        reason=" ".join(str(reason).split()),
        start=start,
        end=end,
        failed_at=time.time(),
        log=None if log is None else str(log),
    )
    return write_json_atomic(Path(folder) / f"{stem}{SUFFIX}", rec.to_json())


def read_failure_records(folder) -> list[FailureRecord]:
    """Every failure record in ``folder``, oldest scan first. A file that is not one (unreadable,
    another format) is left out: the records are advice, the list-mode files are the data."""
    folder = Path(folder)
    out = []
    try:
        paths = sorted(folder.glob(f"*{SUFFIX}"))
    except OSError:
        return []
    for p in paths:
        try:
            d = json.loads(read_text(p, SMALL, "list-mode failure note"))
            if not isinstance(d, dict) or d.get("format") != FORMAT:
                continue
            rec = FailureRecord(
                by=str(d["by"]),
                listmode=str(d["listmode"]),
                reason=str(d["reason"]),
                start=_num(d.get("start")),
                end=_num(d.get("end")),
                failed_at=_time(d["failed_at"]),
                log=d.get("log"),
                path=p,
            )
        except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, OverflowError, RecursionError):
            continue
        out.append(rec)
    out.sort(key=lambda r: r.span[0])
    return out


def _num(v) -> float | None:
    """A time of a record that may be absent: None, or :func:`_time`'s."""
    return None if v is None else _time(v)


def _time(v) -> float:
    """A time of a record: a UTC epoch a date can be made of (else ValueError, OverflowError or
    TypeError: the file is not a record vts wrote)."""
    t = float(v)
    _dt.datetime.fromtimestamp(t, _dt.UTC)
    return t


def utc_span(start: float, end: float) -> str:
    """``2026-11-22 10:15:03 to 10:16:02 UTC`` (the date again at the end when it differs)."""
    a = _dt.datetime.fromtimestamp(start, _dt.UTC)
    b = _dt.datetime.fromtimestamp(end, _dt.UTC)
    tail = f"{b:%H:%M:%S}" if a.date() == b.date() else f"{b:%Y-%m-%d %H:%M:%S}"
    return f"{a:%Y-%m-%d %H:%M:%S} to {tail} UTC"
