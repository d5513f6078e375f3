"""A department's view: every rig (room) in the results store on one page.

``build_rooms_report(store, "rooms.html")`` (:mod:`vts_hw.report.build`) reads each rig's runs
(:func:`collect_rooms`, here) and writes, beside the page,
each room's full drift report (``rooms-<rig>-drift.html``, linked relatively), then the page:
per room the latest daily state of each camera with a drift sparkline, the days since the last
step test, calibration and SPECT mapping, and the open ACTION items.

Open ACTION item (the page's footnote says the same): a check — the same procedure (daily and
drift QA count as one), the same camera or subject (a marker counts as its camera), the same
quantity — whose latest completed result is ACTION. A later OK or TOLERANCE result of that
check closes it; "since" is the first ACTION of the unbroken run of ACTION results. Motion
analyses judge a patient's scan, not the room, and are never listed; drift baselines have no
state.
"""

from __future__ import annotations

import re
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw import __version__, catalog
from vts_hw.report.drift import COMPLETED, DRIFT_PROCEDURES, collect
from vts_hw.report.model import DriftReport, RunInfo
from vts_hw.report.times import fmt_date
from vts_hw.store.commission import LABELS as STEP_LABELS
from vts_hw.store.commission import Standing, load_state
from vts_hw.tolerance import State, worst

STEPS_PROCEDURES = catalog.family(catalog.STEPS.key)
CALIBRATION_PROCEDURES = catalog.family(catalog.CALIBRATION.key)
MAPPING_PROCEDURES = catalog.family(catalog.MAPPING.key)
COMMISSIONING_PROCEDURES = catalog.family(catalog.COMMISSIONING.key)
#: never open ACTION items (see the docstring): a patient's scan, and baselines (no state)
NOT_ROOM_CHECKS = catalog.not_room_checks()
OPEN_RULE = (
    "An ACTION item is open while the latest completed result of the same check — the same "
    "procedure (daily and drift QA count as one), the same camera or subject, the same quantity — "
    "is ACTION; a later OK or TOLERANCE result of that check closes it. Motion analyses judge a "
    "patient's scan, not the room, and are not listed."
)


@dataclass
class OpenItem:
    """A check whose latest result is ACTION."""

    check: str  # "daily QA", "sync check", ...
    subject: str
    metrics: list[str]
    since: float  # the first ACTION result of the unbroken run
    last_run: int
    last_t: float
    runs: int  # ACTION runs since `since`

    def text(self) -> str:
        return (
            f"{self.check} · {self.subject}: {', '.join(self.metrics)} — ACTION since {fmt_date(self.since)}"
            f" ({self.runs} run{'s' if self.runs != 1 else ''}, last run {self.last_run})"
        )

    def as_dict(self) -> dict:
        return {**self.__dict__, "since_date": fmt_date(self.since), "text": self.text()}


@dataclass
class RoomStatus:
    rig: str
    drift: DriftReport
    last_daily: RunInfo | None  # the latest completed daily/drift run, any time
    last_steps: RunInfo | None
    last_calibration: RunInfo | None
    last_mapping: RunInfo | None
    open_items: list[OpenItem] = field(default_factory=list)
    drift_file: str = ""  # the room's drift report, relative to the rooms page
    commissioned: RunInfo | None = None  # the latest completed commissioning (its operator signed it off)
    commission: Standing | None = None  # where its current commissioning stands (the newest attempt of each step)

    @property
    def label(self) -> str:
        return self.rig or "(no rig name)"

    latest: dict = field(default_factory=dict)  # (check, subject, metric) -> its latest state (any date)

    @property
    def has_daily(self) -> bool:
        """The period holds daily (or drift) QA of a camera."""
        return any(c.points for c in self.drift.cameras.values())

    @property
    def state(self) -> State | None:
        """The worst of the room's latest results, whatever the check: each camera's latest
        daily QA in the period (a camera it could not measure is ACTION), and the latest result
        of every other check of the room (step test, calibration, mapping, sync check ...).
        None, never OK, when the period has no daily QA and nothing else is worse than OK."""
        cams = [c.state for c in self.drift.cameras.values() if c.points]
        st = worst([*cams, *self.latest.values()])
        return st if cams or st != State.OK else None

    def commissioned_text(self) -> str:
        """Its commissioning's state, always with what was skipped and what did not pass (the why of each
        is in the commissioning's report and `vts commission`'s words): "commissioned on DATE: TOLERANCE, 5
        of 9 steps skipped (...) (signed off by NAME)", "commissioning incomplete, not commissioned:
        warm-up aborted; ...", or "not commissioned"."""
        c = self.commission
        if c is None:
            return "not commissioned"
        skipped = (
            (
                f"{len(c.skipped)} of {len(STEP_LABELS)} steps skipped ("
                + ", ".join(STEP_LABELS.get(n, n) for n in c.skipped)
                + ")"
            )
            if c.skipped
            else ""
        )
        if c.complete and c.report is not None:  # complete: a report stands
            who = f"signed off by {c.report.operator}" if c.report.operator else "not signed off"
            return f"commissioned on {fmt_date(c.report.started)}: {c.word}{', ' + skipped if skipped else ''} ({who})"
        parts = c.not_passed_text(why=False) or [
            "every step passed, no report since (`vts commission --resume` writes it)"
        ]
        last = (
            f" (its report of {fmt_date(c.last_report.started)}, {c.last_report.status}, no longer stands)"
            if c.last_report is not None
            else ""
        )
        return "commissioning incomplete, not commissioned: " + "; ".join(parts + ([skipped] if skipped else [])) + last

    def daily_missing_text(self) -> str:
        """What the page says instead of a state when the period has no daily QA."""
        if self.last_daily is None:
            return "no daily QA yet"
        return f"no daily QA in the period (last {fmt_date(self.last_daily.started)})"

    def as_dict(self) -> dict:
        def info(r):
            return None if r is None else r.as_dict()

        return {
            "rig": self.rig,
            "state": str(self.state) if self.state else None,
            "daily": None if self.has_daily else self.daily_missing_text(),
            "cameras": {
                n: {"state": str(c.state), "latest": c.latest.as_dict() if c.latest else None}
                for n, c in self.drift.cameras.items()
                if c.points
            },
            "last_daily": info(self.last_daily),
            "last_steps": info(self.last_steps),
            "last_calibration": info(self.last_calibration),
            "last_mapping": info(self.last_mapping),
            "open_items": [i.as_dict() for i in self.open_items],
            "drift_report": self.drift_file,
            "commissioned": self.commissioned_text(),
            "commissioning": None
            if self.commission is None
            else {
                "id": self.commission.cid,
                "state": self.commission.word,
                "skipped": self.commission.skipped,
                "not_passed": self.commission.not_passed,
            },
            "attention": self.drift.attention(),
        }


@dataclass
class RoomsReport:
    title: str
    since: float | None
    now: float
    rooms: list[RoomStatus]
    software_version: str = __version__
    out: Path | None = None

    @property
    def state(self) -> State | None:
        states = [r.state for r in self.rooms if r.state is not None]
        return worst(states) if states else None

    def results_data(self) -> dict:
        return {
            "report": "rooms",
            "title": self.title,
            "since": self.since,
            "now": self.now,
            "state": str(self.state) if self.state else None,
            "open_rule": OPEN_RULE,
            "out": str(self.out) if self.out else None,
            "software_version": self.software_version,
            "rooms": [r.as_dict() for r in self.rooms],
        }


def days_since(t: float | None, now: float) -> str:
    if t is None:
        return "never"
    d = int((now - t) // 86400)
    return "today" if d <= 0 else "1 day ago" if d == 1 else f"{d} days ago"


def _latest(runs, procedures) -> RunInfo | None:
    done = [r for r in runs if r.procedure in procedures and str(r.status) in COMPLETED]
    return RunInfo.of(done[-1]) if done else None


def _check(procedure: str) -> str:
    return catalog.label(procedure)


def _per_run(measurements, runs):
    """The completed room-check runs among ``runs`` (by time) and per run the state of each
    check key (check, camera or subject, metric) from ``measurements``."""
    not_room = catalog.not_room_checks()
    done = {r.id: r for r in runs if str(r.status) in COMPLETED and r.procedure not in not_room}
    per_run: dict[int, dict[tuple[str, str, str], str]] = defaultdict(dict)
    for m in measurements:
        run = done.get(m.run_id)
        if run is None or str(m.status) not in COMPLETED:
            continue
        key = (_check(run.procedure), (m.subject or "").split("/")[0] or "-", m.metric)
        per_run[m.run_id][key] = str(worst([per_run[m.run_id].get(key, "OK"), str(m.status)]))
    return sorted(done.values(), key=lambda r: (r.started, r.id)), per_run


def latest_states(measurements, runs) -> dict[tuple[str, str, str], str]:
    """The state of the latest completed result of each check (check, camera or subject,
    metric) among ``runs`` (one rig's); a run without measurements counts as its own state."""
    ordered, per_run = _per_run(measurements, runs)
    out: dict[tuple[str, str, str], str] = {}
    for run in ordered:
        got = per_run.get(run.id)
        if got:
            out.update(got)
        else:
            out[(_check(run.procedure), "-", "(run)")] = str(run.status)
    return out


def open_items(measurements, runs) -> list[OpenItem]:
    """The open ACTION items among ``runs`` (one rig's; see the module docstring) from their
    ``measurements`` (any others are ignored)."""
    ordered, per_run = _per_run(measurements, runs)
    if not ordered:
        return []
    open_: dict[tuple, list] = {}
    for run in ordered:
        for key, st in per_run.get(run.id, {}).items():
            if st == "ACTION":
                got = open_.setdefault(key, [run.started, run.id, run.started, 0])
                got[1], got[2], got[3] = run.id, run.started, got[3] + 1
            else:
                open_.pop(key, None)
    grouped: dict[tuple[str, str], OpenItem] = {}
    for (check, subject, metric), (since, last_run, last_t, n) in sorted(open_.items()):
        item = grouped.get((check, subject))
        if item is None:
            grouped[(check, subject)] = OpenItem(check, subject, [metric], since, last_run, last_t, n)
        else:
            item.metrics.append(metric)
            item.since, item.runs = min(item.since, since), max(item.runs, n)
            if last_t > item.last_t:
                item.last_run, item.last_t = last_run, last_t
    return sorted(grouped.values(), key=lambda i: (i.since, i.check, i.subject))


def slug(rig: str) -> str:
    """A file-name-safe form of a rig name ("unnamed" for the empty one)."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", rig).strip("._") or "unnamed"


def drift_file_names(out: Path, rigs: list[str]) -> dict[str, str]:
    """Each rig's drift report file name beside ``out`` (``rooms-<rig>-drift.html``), unique."""
    names, used = {}, set()
    for rig in rigs:
        base = f"{out.stem}-{slug(rig)}-drift"
        name, i = base + out.suffix.lower(), 2
        while name.lower() in used:
            name, i = f"{base}-{i}{out.suffix.lower()}", i + 1
        used.add(name.lower())
        names[rig] = name
    return names


def collect_rooms(
    store, since: float | None = None, now: float | None = None, rigs=None, out: Path | None = None
) -> RoomsReport:
    """Every rig's (or ``rigs``') room data; nothing is written."""
    now = time.time() if now is None else float(now)
    rigs = store.rigs() if rigs is None else list(rigs)
    names = drift_file_names(Path(out or "rooms.html"), rigs)
    all_runs = [r for r in store.runs() if r.started <= now]
    not_room = catalog.not_room_checks()
    checks = tuple(sorted({r.procedure for r in all_runs if r.procedure not in not_room}))
    measurements = store.measurements(procedure=checks) if checks else []
    rooms = []
    for rig in rigs:
        runs = [r for r in all_runs if (r.rig or "") == rig]
        rooms.append(
            RoomStatus(
                rig=rig,
                drift=collect(store, since=since, now=now, rig=rig),
                last_daily=_latest(runs, DRIFT_PROCEDURES),
                last_steps=_latest(runs, STEPS_PROCEDURES),
                last_calibration=_latest(runs, CALIBRATION_PROCEDURES),
                last_mapping=_latest(runs, MAPPING_PROCEDURES),
                open_items=open_items(measurements, runs),
                drift_file=names[rig],
                commissioned=_latest(runs, COMMISSIONING_PROCEDURES),
                commission=load_state(store, rig).standing(store),
                latest=latest_states(measurements, runs),
            )
        )
    return RoomsReport("VTS rooms — department QA overview", since, now, rooms)


__all__ = ["collect_rooms", "open_items", "RoomsReport", "RoomStatus", "OpenItem", "OPEN_RULE"]
