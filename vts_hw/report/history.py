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

from vts_hw.tolerance import DEFAULT_TOLERANCES, State, Window
from vts_hw.report.times import fmt_date

COMPLETED = ("OK", "TOLERANCE", "ACTION")
LAST_N = 10                 # runs listed per procedure, newest first


@dataclass(frozen=True)
class Figure:
    """A column of a history table: a metric (one subject, or the worst of all of them)."""
    metric: str
    label: str
    fmt: str
    subject: str | None = None          # None: the largest value over the subjects
    exclude: str | None = None          # with subject None: a subject left out (the set's figure)


@dataclass(frozen=True)
class Spec:
    key: str
    title: str
    procedures: tuple[str, ...]
    figures: tuple[Figure, ...]
    trend: int = 0                      # index of the figure plotted over time
    room_check: bool = True             # judged as the room's QA ("attention"; open ACTION items)


SPECS = (
    Spec("sync", "Sync checks (VTS against SPECT)", ("sync",),
         (Figure("sync_max_abs_dt_ms", "max |Δt| ms", ".1f"), Figure("sync_events_both", "events seen by both", "g"),
          Figure("sync_events_one_system", "seen by one only", "g"))),
    Spec("spect_mapping", "SPECT mappings (VTS → SPECT)", ("spect_mapping",),
         (Figure("mapping_tre_rms_mm", "TRE RMS mm", ".3f"), Figure("mapping_fre_mm", "FRE mm", ".3f"))),
    # "calibration_cameras": the N-camera runs' name before one calibration (decision 0056), read as one
    Spec("calibration", "Camera calibrations", ("calibration", "calibration_cameras"),
         (Figure("calibration_rms_px", "RMS of the set px", ".3f", subject="set"),
          Figure("calibration_rms_px", "worst camera px", ".3f", exclude="set"),
          Figure("calibration_converged", "converged", "g", subject="set"))),
    Spec("motion", "Motion analyses (patient scans)", ("motion",),
         (Figure("motion_body_max_mm", "max shift mm", ".2f"), Figure("motion_body_max_deg", "max turn °", ".2f"),
          Figure("motion_pose_coverage", "pose known (share of time)", ".3f")), room_check=False),
)

LABELS = {"sync": "sync check", "spect_mapping": "SPECT mapping", "calibration": "camera calibration",
          "calibration_cameras": "camera calibration", "motion": "motion analysis", "sphere-steps": "step test",
          "daily": "daily QA", "drift": "daily QA", "drift-baseline": "drift baseline"}


@dataclass
class HistoryRun:
    id: int
    procedure: str
    started: float
    status: str
    rig: str = ""
    values: list = field(default_factory=list)     # per figure: (value or None, state or "")
    not_ok: list = field(default_factory=list)     # "metric (subject)" of the measures not OK

    @property
    def completed(self) -> bool:
        return self.status in COMPLETED

    def as_dict(self, spec: Spec) -> dict:
        return {"id": self.id, "procedure": self.procedure, "started": self.started, "date": fmt_date(self.started),
                "status": self.status, "rig": self.rig, "not_ok": list(self.not_ok),
                "figures": {f.label: {"value": v, "state": s} for f, (v, s) in zip(spec.figures, self.values)}}


@dataclass
class ProcedureHistory:
    spec: Spec
    runs: list[HistoryRun]             # every run of the period, oldest first
    window_now: Window | None = None   # the trend figure's window in effect now

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
        return [(r.started, r.values[self.spec.trend][0], r.values[self.spec.trend][1] or r.status)
                for r in self.runs if r.completed and r.values[self.spec.trend][0] is not None]

    @property
    def has_plot(self) -> bool:
        return len(self.trend_points()) >= 2

    def attention(self) -> tuple[int, str] | None:
        """(rank, line) when the latest completed run of a room check is not OK."""
        latest = self.latest
        if not self.spec.room_check or latest is None or latest.status == "OK":
            return None
        what = LABELS.get(latest.procedure, latest.procedure)
        room = f" ({latest.rig})" if latest.rig else ""
        bad = ", ".join(latest.not_ok) or "see its run"
        return (State(latest.status).rank,
                f"{what}{room}: {latest.status} in run {latest.id} on {fmt_date(latest.started)} ({bad})")

    def results_data(self) -> dict:
        return {"key": self.spec.key, "title": self.title, "runs": len(self.runs),
                "latest": None if self.latest is None else self.latest.as_dict(self.spec),
                "shown": [r.as_dict(self.spec) for r in self.shown]}


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
    """The history of each procedure of :data:`SPECS` with runs in the period (rig None: all rigs)."""
    procs = tuple(p for s in SPECS for p in s.procedures)
    runs = [r for r in store.runs(procedure=procs, since=since)
            if r.started <= now and (rig is None or (r.rig or "") == rig)]
    if not runs:
        return []
    ids = {r.id for r in runs}
    meas: dict[int, dict] = defaultdict(dict)
    for m in store.measurements(procedure=procs, since=since):
        if m.run_id in ids:
            v = None if m.value is None or (isinstance(m.value, float) and math.isnan(m.value)) else float(m.value)
            meas[m.run_id][(m.metric, m.subject)] = (v, str(m.status))
    out = []
    for spec in SPECS:
        mine = [r for r in runs if r.procedure in spec.procedures]
        if not mine:
            continue
        hist = []
        for r in mine:
            by = meas.get(r.id, {})
            hist.append(HistoryRun(r.id, r.procedure, r.started, str(r.status or "unfinished"), r.rig or "",
                                   [_value(f, by) for f in spec.figures],
                                   sorted(f"{m} ({s})" for (m, s), (_, st) in by.items() if st != "OK")))
        metric = spec.figures[spec.trend].metric
        got = store.tolerance(metric, at=now)
        out.append(ProcedureHistory(spec, hist, got[1] if got is not None else DEFAULT_TOLERANCES.get(metric)))
    return out


__all__ = ["SPECS", "LABELS", "ProcedureHistory", "HistoryRun", "collect_history"]
