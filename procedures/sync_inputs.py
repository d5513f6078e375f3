"""What the sync check reads before it analyses anything: the scan session, its calibration,
and *which* list-mode belongs to it.

* :func:`check_session` — the session folder, its manifest and its trigger log, or one sentence.
* :func:`session_span` — when the session recorded (host UTC epoch s): the recording's start and
  finish from the manifest (for a session that never finished: its last frame or trigger-log
  line), and the trigger's fire time (the start pulse) from ``trigger.csv``.
* :func:`choose_listmode` — of the list-mode files given (a shell glob may give several), the
  one that belongs to the session, by the header's wall-clock ``start_time`` and duration
  (allowing the SPECT's clock ``CLOCK_SLACK_S`` off the host's): started by the session's start
  pulse when it sent one (the SPECT starts on it), else overlapping the recording (a SPECT
  started by hand). None → one sentence naming the files and both time spans, or, when the
  writer left a failure record for this scan beside them (docs/listmode-format.md, "Failure
  records"), why it was not recorded. Several → one sentence asking to name one. The reasons:
  docs/decisions/0025-which-listmode.md.
"""

from __future__ import annotations

import datetime as _dt
import math
from dataclasses import dataclass
from pathlib import Path

from vts_hw.bounded import TABLE, open_bounded
from vts_hw.errors import DataError
from vts_hw.recording.folder import load_manifest, read_index
from vts_hw.recording.trigger_wave import wave_from_trigger_log
from vts_hw.spect.listmode import read_listmode_span
from vts_hw.spect.listmode.failures import read_failure_records, utc_span

__all__ = [
    "CLOCK_SLACK_S",
    "SessionSpan",
    "check_session",
    "session_span",
    "choose_listmode",
]

# How far the SPECT's wall clock (the list-mode header's start_time) may be off the host's when
# matching a list-mode to a session: the format allows seconds (the simulated SPECT: ±3 s);
# 10 s is over three times that, and shorter than a scan, so the start pulses of two scans are
# further apart than this (docs/decisions/0025-which-listmode.md).
CLOCK_SLACK_S = 10.0
_GLOB = set("*?[")


# ----------------------------------------------------------------------------- the session


def check_session(folder) -> dict:
    """The session's manifest; DataError naming the folder when it is not a scan session."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: no such session folder")
    manifest = load_manifest(folder, missing_ok=True)
    if manifest is None:
        raise DataError(f"{folder}: not a session folder (no manifest.json)")
    if not manifest.get("cameras"):
        raise DataError(f"{folder / 'manifest.json'}: not a recording manifest (no cameras)")
    if not (folder / "trigger.csv").exists():
        raise DataError(
            f"{folder}: no trigger.csv: the session has no trigger log to time the "
            f"SPECT against (was it recorded with trigger backend none?)"
        )
    return manifest


@dataclass
class SessionSpan:
    """When a session recorded (host UTC epoch s); ``fire`` the trigger's first edge, and
    ``start_pulse`` whether the SPECT start pulse came with it."""

    start: float
    end: float
    fire: float | None = None
    start_pulse: bool = False
    period_s: float | None = None

    def text(self) -> str:
        what = "its start pulse" if self.start_pulse else "the trigger"
        fired = "" if self.fire is None else f", {what} at {_dt.datetime.fromtimestamp(self.fire, _dt.UTC):%H:%M:%S}"
        return f"recorded {utc_span(self.start, self.end)}{fired}"


def _num(v) -> float | None:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _trigger_rows(folder: Path) -> list[float]:
    import csv

    try:
        with open_bounded(folder / "trigger.csv", TABLE, "trigger log", newline="") as f:
            return [t for t in (_num(r.get("host_time")) for r in csv.DictReader(f)) if t is not None]
    except (OSError, UnicodeDecodeError, csv.Error):
        return []


def _last_frame_times(folder: Path, manifest: dict) -> list[float]:
    """The last host receive time in each camera's index (a session that never finished)."""
    out = []
    for name in manifest.get("cameras", {}):
        try:
            rows = read_index(folder / f"{name}.index.csv")
        except (OSError, DataError, UnicodeDecodeError):
            continue
        times = [r.host_time for r in rows if r.host_time is not None]
        if times:
            out.append(max(times))
    return out


def session_span(folder, manifest: dict | None = None) -> SessionSpan | None:
    """When the session at ``folder`` recorded, or None when nothing in it says (see module)."""
    folder = Path(folder)
    manifest = manifest if manifest is not None else check_session(folder)
    times = (manifest.get("scan") or {}).get("times") or {}
    trig = manifest.get("trigger") or {}
    fire, pulse, period = _num(trig.get("fire_time")) if trig.get("fired") else None, False, None
    try:
        wave = wave_from_trigger_log(folder / "trigger.csv")
        fire, pulse, period = wave.start_host, wave.start_pulse, wave.period_s
    except DataError:
        pass
    rows = _trigger_rows(folder)
    start = next(
        (t for t in (_num(manifest.get("started")), _num(times.get("recording_started"))) if t is not None), None
    )
    if start is None:
        start = fire if fire is not None else (min(rows) if rows else None)
    end = next((t for t in (_num(manifest.get("finished")), _num(times.get("finished"))) if t is not None), None)
    if end is None:  # killed, recovered, or still recording: what it holds
        last = rows + _last_frame_times(folder, manifest) + ([fire] if fire is not None else [])
        end = max(last) if last else None
    if start is None or end is None:
        return None
    return SessionSpan(start=start, end=max(start, end), fire=fire, start_pulse=pulse, period_s=period)


# ----------------------------------------------------------------------------- the list-mode


@dataclass
class _Candidate:
    path: Path
    start: float | None = None  # SPECT wall clock, UTC epoch s
    end: float | None = None
    error: str | None = None

    @property
    def times(self) -> tuple[float, float]:
        """(start, end) of a file that could be read (its error None: both are set)."""
        if self.start is None or self.end is None:
            raise ValueError(f"{self.path.name}: its acquisition times were not read ({self.error})")
        return self.start, self.end

    def text(self) -> str:
        if self.error is not None:
            return f"{self.path.name} ({self.error})"
        return f"{self.path.name} acquired {utc_span(*self.times)} (SPECT clock)"


def _overlaps(span: SessionSpan, start: float, end: float, slack: float) -> bool:
    return start <= span.end + slack and end >= span.start - slack


def _started_by_pulse(span: SessionSpan, fire: float, start: float, slack: float) -> bool:
    """Started by this session's start pulse (sent at ``fire``): within the slack of it (the start
    delay is under a period of the wave, docs/decisions/0017)."""
    return fire - slack <= start <= fire + (span.period_s or 0.0) + slack


def _fits(span: SessionSpan, start: float, end: float, slack: float) -> bool:
    """An acquisition of this session: started by its start pulse when the session sent one
    (the SPECT starts on it), else overlapping its recording (a SPECT started by hand)."""
    if span.start_pulse and span.fire is not None:
        return _started_by_pulse(span, span.fire, start, slack)
    return _overlaps(span, start, end, slack)


def choose_listmode(
    session, candidates, *, manifest: dict | None = None, slack_s: float = CLOCK_SLACK_S
) -> tuple[Path, list[str]]:
    """The list-mode of ``candidates`` (paths; a shell pattern that matched nothing arrives as
    itself) that belongs to the session, and notes on the choice. DataError otherwise (module)."""
    session = Path(session)
    paths = list(dict.fromkeys(Path(c) for c in candidates))
    if not paths:
        raise DataError(f"{session}: no list-mode file given (--listmode FILE)")
    span = session_span(session, manifest)
    cands, patterns = [], []
    for p in paths:
        if not p.exists() and _GLOB & set(str(p)):
            patterns.append(p)  # a glob that matched nothing: the shell passed it on
            continue
        try:
            start, dur = read_listmode_span(p)
            cands.append(_Candidate(p, start, start + dur))
        except DataError as exc:
            if len(paths) == 1:
                raise
            cands.append(_Candidate(p, error=str(exc).removeprefix(f"{p}: ")))
    readable = [c for c in cands if c.error is None]
    skipped = [f"{c.path}: {c.error}" for c in cands if c.error is not None]
    if span is None:
        if len(readable) == 1 and len(cands) == 1:
            return readable[0].path, [
                f"{session}: no recording times in the manifest: "
                f"{readable[0].path.name} was not checked against the session"
            ]
        if readable:
            raise DataError(
                f"{session}: its manifest has no recording times to tell which of "
                f"{len(readable)} list-mode files belongs to it: name one with --listmode"
            )
    else:
        match = [c for c in readable if _fits(span, *c.times, slack_s)]
        if len(match) == 1:
            notes = skipped
            if len(cands) + len(patterns) > 1:
                notes = [
                    f"list-mode {match[0].path.name} chosen of {len(cands)} given: the only one "
                    + (
                        "this session's start pulse started"
                        if span.start_pulse and span.fire is not None
                        else "whose acquisition overlaps the session"
                    )
                ] + skipped
            return match[0].path, notes
        if match:
            raise DataError(
                f"{len(match)} list-mode files fit {session} ({span.text()}): "
                + "; ".join(c.text() for c in match)
                + ": name the one of this scan with --listmode"
            )
    raise DataError(_nothing_belongs(session, span, cands, patterns, slack_s))


def _nothing_belongs(
    session: Path, span: SessionSpan | None, cands: list[_Candidate], patterns: list[Path], slack_s: float
) -> str:
    """The sentence for: no list-mode given belongs to the session (a failure record that
    covers it, if its writer left one beside them, says why)."""
    folders = dict.fromkeys(p.parent for p in [c.path for c in cands] + patterns if not (_GLOB & set(str(p.parent))))
    if span is not None:
        records = [r for f in folders for r in read_failure_records(f)]
        for r in [r for r in records if _fits(span, *r.span, slack_s)][-1:]:
            return f"{r.describe('this scan')} (record {r.path}" + (f", log {r.log})" if r.log else ")")
    when = f" ({span.text()})" if span is not None else ""
    if not cands:
        return (
            f"{', '.join(str(p) for p in patterns)}: no list-mode file matches, and no failure "
            f"record there covers {session}{when}: was its list-mode written or copied there?"
        )
    slack = f" (allowing the SPECT's clock {slack_s:g} s off the host's: --clock-slack)"
    if len(cands) == 1 and span is not None and cands[0].error is None:
        c = cands[0]
        return (
            f"{c.path} and {session} do not belong together: the list-mode was acquired "
            f"{utc_span(*c.times)} (SPECT clock), the session {span.text()}{slack}"
        )
    return (
        f"none of the {len(cands)} list-mode files given belongs to {session}{when}: "
        + "; ".join(c.text() for c in cands)
        + (slack if span is not None else "")
    )
