"""The commissioning report's content (issue 24 §3), read from the store: the devices (models,
firmware, serial numbers, the settings locked), each step with its state and run, every figure
against its tolerance window with its state, what was skipped and why, and the sign-off.
Rendered by report/commission_html.py and report/commission_pdf.py through the report door
(report/renderers.py, ``"commission"``). Decision 0069."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw import __version__
from vts_hw.bounded import SMALL, read_text
from vts_hw.tolerance import State, worst

#: the ledger's own measures, and the per-marker positions of a baseline: not figures of the room
NOT_FIGURES = {"commission_id", "step_passed", "step_run", "step_skipped", "baseline_x_px", "baseline_y_px"}
#: a step's row when its newest attempt did not pass
NOT_PASSED = ("NOT RUN", "NOT PASSED", "ABORTED")
WORDS = {
    "OK": "OK: within tolerance",
    "TOLERANCE": "TOLERANCE: within the action limits; review it",
    "ACTION": "ACTION: outside the action limits; act before the room is used",
}


@dataclass
class StepRow:
    name: str
    label: str
    state: str  # OK / TOLERANCE / ACTION, "SKIPPED", "NOT RUN", "NOT PASSED", "ABORTED"
    run_id: int | None
    started: float | None
    notes: str = ""


@dataclass
class FigureRow:
    step: str
    subject: str
    metric: str
    value: float | None
    unit: str
    state: str
    window: str  # the tolerance window in words, or why none


@dataclass
class CommissionReport:
    rig: str
    cid: int
    now: float
    steps: list[StepRow]
    figures: list[FigureRow]
    cameras: list[dict] = field(default_factory=list)
    trigger: dict | None = None
    skipped: list[tuple[str, str]] = field(default_factory=list)
    signed_by: str = ""
    signed_at: float | None = None
    title: str = "VTS room commissioning"
    software_version: str = __version__

    @property
    def complete(self) -> bool:
        return all(s.state in ("OK", "TOLERANCE", "SKIPPED") for s in self.steps)

    @property
    def state(self) -> State:
        """The worst step and figure; a step skipped counts as TOLERANCE, one not passed (not run,
        stopped, aborted: its newest attempt) as ACTION."""
        got = [
            State.ACTION if s.state in NOT_PASSED else State.TOLERANCE if s.state == "SKIPPED" else State(s.state)
            for s in self.steps
        ]
        return worst(got + [State(f.state) for f in self.figures]) if got else State.ACTION

    def as_dict(self) -> dict:
        return {
            "rig": self.rig,
            "commission_id": self.cid,
            "state": str(self.state),
            "complete": self.complete,
            "signed_by": self.signed_by or None,
            "signed_at": self.signed_at,
            "steps": [s.__dict__ for s in self.steps],
            "figures": [f.__dict__ for f in self.figures],
            "cameras": self.cameras,
            "trigger": self.trigger,
            "skipped": self.skipped,
        }


def _artifact_json(store, run_id: int, name: str) -> dict | None:
    for a in store.artifacts(run_id):
        if Path(a.path).name == name:
            try:
                return json.loads(read_text(Path(a.path), SMALL, name))
            except (OSError, ValueError):
                return {"problem": f"{a.path} could not be read"}
    return None


def _window_text(w) -> str:
    return "no window (the procedure's own verdict)" if w is None else w.describe()


def build_commission_report(
    store,
    state,
    steps: list[tuple[str, str]],
    *,
    signed_by: str = "",
    signed_at: float | None = None,
    now: float | None = None,
) -> CommissionReport:
    """The report of the commissioning ``state`` (vts_hw.store.commission.CommissionState);
    ``steps``: (name, label) of every step in order."""
    rows, figures, skipped = [], [], []
    cameras, trigger = [], None
    for name, label in steps:
        s = state.steps.get(name)
        if s is None:
            rows.append(StepRow(name, label, "NOT RUN", None, None))
            continue
        if s.skipped:
            why = s.notes.split("skipped: ", 1)[-1]
            rows.append(StepRow(name, label, "SKIPPED", s.run_id, s.started, why))
            skipped.append((label, why))
            continue
        if s.aborted:  # the newest attempt raised or its process died: no figures of it
            rows.append(StepRow(name, label, "ABORTED", s.run_id, s.started, s.why()))
            continue
        own = s.step_run or s.run_id
        word = s.status if s.passed and s.status in ("OK", "TOLERANCE") else "NOT PASSED"
        rows.append(StepRow(name, label, word, own, s.started, s.notes))
        ms = [m for m in store.measurements(run_id=own) if m.metric not in NOT_FIGURES]
        windows = store.windows(m.tolerance_id for m in ms)
        for m in ms:
            w = windows.get(m.tolerance_id)
            figures.append(FigureRow(label, m.subject, m.metric, m.value, m.unit, str(m.status), _window_text(w)))
        if name == "cameras":
            cameras = (_artifact_json(store, s.run_id, "devices.json") or {}).get("cameras", [])
        if name == "trigger":
            trigger = _artifact_json(store, s.run_id, "trigger.json")
    return CommissionReport(
        state.rig,
        state.cid,
        time.time() if now is None else now,
        rows,
        figures,
        cameras,
        trigger,
        skipped,
        signed_by,
        signed_at,
    )


__all__ = ["CommissionReport", "StepRow", "FigureRow", "build_commission_report", "WORDS", "NOT_PASSED"]
