"""The history of the other QA runs in the drift report: sync checks, SPECT mappings, camera
calibrations and motion analyses.

:func:`collect_history` reads, per procedure, the runs of the report period (one rig, or every
rig when ``rig`` is None): the last :data:`LAST_N` with their date, state and key figures for a
table, and every run's main figure for a small trend plot. :meth:`ProcedureHistory.attention`
gives the line the report's "attention" list shows when the latest sync check, mapping or
calibration is not OK (a motion analysis judges a patient's scan, not the room: never listed).
"""

from __future__ import annotations

import math
from collections import defaultdict
from dataclasses import dataclass, field

from vts_hw import catalog
from vts_hw.catalog import Figure
from vts_hw.report.times import fmt_date
from vts_hw.tolerance import State, Window

COMPLETED = ("OK", "TOLERANCE", "ACTION")
LAST_N = 10  # runs listed per procedure, newest first


@dataclass(frozen=True)
class Spec:
    """A section of the history: the procedures of one check (vts_hw.catalog) and their figures."""

    key: str
    title: str
    procedures: tuple[str, ...]
    figures: tuple[Figure, ...]
    trend: int = 0  # index of the figure plotted over time
    room_check: bool = True  # judged as the room's QA ("attention"; open ACTION items)


def specs() -> tuple[Spec, ...]:
    """One section per check of the catalog that has a history title, in the catalog's order
    (read at each call: a procedure added to the catalog gets its section)."""
    return tuple(
        Spec(key, title, names, p.figures, 0, p.judges == "room") for key, title, names, p in catalog.sections()
    )


@dataclass
class HistoryRun:
    id: int
    procedure: str
    started: float
    status: str
    rig: str = ""
    values: list = field(default_factory=list)  # per figure: (value or None, state or "")
    not_ok: list = field(default_factory=list)  # "metric (subject)" of the measures not OK

    @property
    def completed(self) -> bool:
        return self.status in COMPLETED

    def as_dict(self, spec: Spec) -> dict:
        return {
            "id": self.id,
            "procedure": self.procedure,
            "started": self.started,
            "date": fmt_date(self.started),
            "status": self.status,
            "rig": self.rig,
            "not_ok": list(self.not_ok),
            "figures": {f.label: {"value": v, "state": s} for f, (v, s) in zip(spec.figures, self.values)},
        }


@dataclass
class ProcedureHistory:
    spec: Spec
    runs: list[HistoryRun]  # every run of the period, oldest first
    window_now: Window | None = None  # the trend figure's window in effect now

    @property
    def title(self) -> str:
        return self.spec.title

    @property
    def shown(self) -> list[HistoryRun]:
        """The last LAST_N runs, newest first."""
        return list(reversed(self.runs[-LAST_N:]))

    @property
    def latest(self) -> HistoryRun | None:
        done = [r for r in self.runs if r.completed]
        return done[-1] if done else None

    @property
    def trend_figure(self) -> Figure:
        return self.spec.figures[self.spec.trend]

    def trend_points(self) -> list[tuple[float, float, str]]:
        """(time, value, state) of the trend figure, completed runs with a value."""
        return [
            (r.started, r.values[self.spec.trend][0], r.values[self.spec.trend][1] or r.status)
            for r in self.runs
            if r.completed and r.values[self.spec.trend][0] is not None
        ]

    @property
    def has_plot(self) -> bool:
        return len(self.trend_points()) >= 2

    def attention(self) -> tuple[int, str] | None:
        """(rank, line) when the latest completed run of a room check is not OK."""
        latest = self.latest
        if not self.spec.room_check or latest is None or latest.status == "OK":
            return None
        what = catalog.label(latest.procedure)
        room = f" ({latest.rig})" if latest.rig else ""
        bad = ", ".join(latest.not_ok) or "see its run"
        return (
            State(latest.status).rank,
            f"{what}{room}: {latest.status} in run {latest.id} on {fmt_date(latest.started)} ({bad})",
        )

    def results_data(self) -> dict:
        return {
            "key": self.spec.key,
            "title": self.title,
            "runs": len(self.runs),
            "latest": None if self.latest is None else self.latest.as_dict(self.spec),
            "shown": [r.as_dict(self.spec) for r in self.shown],
        }


def _value(f: Figure, by_subject: dict[tuple[str, str], tuple]) -> tuple[float | None, str]:
    if f.subject is not None:
        got = by_subject.get((f.metric, f.subject))
        return (got[0], got[1]) if got else (None, "")
    cands = [v for (m, s), v in by_subject.items() if m == f.metric and s != f.exclude and v[0] is not None]
    if not cands:
        return None, ""
    v, st = max(cands, key=lambda x: x[0])
    return v, st


def collect_history(store, since: float | None, now: float, rig: str | None) -> list[ProcedureHistory]:
    """The history of each section of the catalog (:func:`specs`) with runs in the period (rig None: all rigs)."""
    all_specs = specs()
    procs = tuple(p for s in all_specs for p in s.procedures)
    runs = [
        r
        for r in store.runs(procedure=procs, since=since)
        if r.started <= now and (rig is None or (r.rig or "") == rig)
    ]
    if not runs:
        return []
    ids = {r.id for r in runs}
    meas: dict[int, dict] = defaultdict(dict)
    for m in store.measurements(procedure=procs, since=since):
        if m.run_id in ids:
            v = None if m.value is None or (isinstance(m.value, float) and math.isnan(m.value)) else float(m.value)
            meas[m.run_id][(m.metric, m.subject)] = (v, str(m.status))
    defaults = catalog.windows()  # a trend metric's window where the store has none
    out = []
    for spec in all_specs:
        mine = [r for r in runs if r.procedure in spec.procedures]
        if not mine:
            continue
        hist = []
        for r in mine:
            by = meas.get(r.id, {})
            hist.append(
                HistoryRun(
                    r.id,
                    r.procedure,
                    r.started,
                    str(r.status or "unfinished"),
                    r.rig or "",
                    [_value(f, by) for f in spec.figures],
                    sorted(f"{m} ({s})" for (m, s), (_, st) in by.items() if st != "OK"),
                )
            )
        metric = spec.figures[spec.trend].metric
        got = store.tolerance(metric, at=now)
        out.append(ProcedureHistory(spec, hist, got[1] if got is not None else defaults.get(metric)))
    return out


__all__ = ["specs", "ProcedureHistory", "HistoryRun", "collect_history"]
