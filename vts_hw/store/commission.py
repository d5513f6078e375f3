"""The state of a room's commissioning, kept in the results store (decision 0069).

Every step of the sequence leaves a run of ``commission-step`` (vts_hw.catalog.COMMISSION_STEP)
whose measures name the step (their subject): ``commission_id`` (which commissioning: the run id
of its first step's run), ``step_passed`` (1 passed, 0 stopped), ``step_skipped`` (1, the reason
in the notes), and ``step_run`` (the step's own run, for a step that is a procedure of its own:
calibration, mapping, step test, sync check, drift baseline, stored under their own names through
the one recorder). A step that raised (a device failed, Ctrl-C) is a ``commission-step`` run
aborted with the reason. Nothing is ever rewritten: a step run again after a fix is a newer run
of the same step, and the newest of each step is the commissioning's state; the older runs stay.

:class:`Ledger` writes (the procedure gets it as its ``ledger``); :func:`load_state` reads.
"""

from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass, field

from vts_hw.catalog import COMMISSION_STEP, COMMISSIONING
from vts_hw.results import Measure, overall_state
from vts_hw.store.errors import StoreError
from vts_hw.store.recorder import Recorder, record
from vts_hw.tolerance import State

KEYS = ("commission_id", "step_passed", "step_run", "step_skipped")


@dataclass
class _Entry:
    """A ledger run's content, in the one result shape the recorder takes."""
    procedure: str
    measures: list
    data: dict = field(default_factory=dict)

    @property
    def state(self) -> State:
        return overall_state(self.measures)

    def results(self) -> str:
        return ""

    def results_data(self) -> dict:
        return dict(self.data)

    def plot(self, path=None) -> bytes:
        raise NotImplementedError


@dataclass
class StepState:
    step: str
    run_id: int            # the commission-step run
    started: float
    status: str
    passed: bool
    skipped: bool
    step_run: int | None   # the step's own run (a procedure's), else None: its figures are in run_id
    notes: str


@dataclass
class CommissionState:
    """A rig's current commissioning: its id, the newest run of each step, its newest report run."""
    rig: str
    cid: int | None = None
    steps: dict[str, StepState] = field(default_factory=dict)
    report_run: int | None = None

    @property
    def done(self) -> dict[str, bool]:
        return {n: s.passed or s.skipped for n, s in self.steps.items()}


def load_state(store, rig: str) -> CommissionState:
    """The newest commissioning of ``rig`` in ``store`` (cid None when there is none)."""
    names = (COMMISSION_STEP.name, COMMISSIONING.name)
    runs = {r.id: r for r in store.runs(procedure=names) if (r.rig or "") == rig and r.status != "running"}
    keyed: dict[int, dict[str, object]] = defaultdict(dict)
    for m in store.measurements(procedure=names, metric=KEYS):
        if m.run_id in runs:
            keyed[m.run_id][m.metric] = m
    st = CommissionState(rig)
    with_cid = [rid for rid in sorted(runs) if "commission_id" in keyed[rid]]
    if not with_cid:
        return st
    st.cid = int(keyed[with_cid[-1]]["commission_id"].value)
    for rid in with_cid:
        k, run = keyed[rid], runs[rid]
        if int(k["commission_id"].value) != st.cid:
            continue
        if run.procedure == COMMISSIONING.name:
            st.report_run = rid
            continue
        step = k["commission_id"].subject
        ref = k.get("step_run")
        st.steps[step] = StepState(step, rid, run.started, run.status,
                                   bool(k.get("step_passed") and k["step_passed"].value == 1),
                                   bool(k.get("step_skipped") and k["step_skipped"].value == 1),
                                   int(ref.value) if ref is not None and ref.value is not None else None, run.notes)
    return st


class Ledger:
    """Records the steps of one commissioning of ``rig`` (a RigConfig) in ``store`` (open)."""

    def __init__(self, store, rig, *, cid: int | None = None, operator: str = "", clock=time.time):
        self.store, self.rig, self.cid, self.operator, self.clock = store, rig, cid, operator, clock

    def _kw(self, started=None):
        return dict(rig=self.rig.rig, operator=self.operator, config_digest=self.rig.digest,
                    tolerances=self.rig.tolerances, clock=self.clock,
                    **({} if started is None else {"started": started}))

    def _write(self, step: str, measures: list, notes: str, artifacts=(), started=None) -> int:
        rec = Recorder(self.store, COMMISSION_STEP.name, notes=notes, **self._kw(started)).begin()
        if rec.run_id is None:
            raise StoreError(f"the commissioning step {step} could not be recorded: {rec.error}")
        if self.cid is None:
            self.cid = rec.run_id            # the first step's run names the commissioning
        ms = [Measure(step, "commission_id", float(self.cid), "", State.OK), *measures]
        stored = rec.finish(_Entry(COMMISSION_STEP.name, ms), artifacts=[str(a) for a in artifacts])
        if not stored.ok:
            raise StoreError(f"the commissioning step {step} was not stored ({stored.error}); "
                             f"its figures are in {stored.unsaved}")
        return stored.run_id

    def record(self, outcome) -> int:
        """The step's outcome: its own procedure's run first (when it is one), then its ledger run."""
        res, step = outcome.result, outcome.step
        passed = outcome.passed
        flag = State.OK if passed else (res.state if res.state != State.OK else State.TOLERANCE)
        notes = f"commissioning step {step}: " + ("passed" if passed else f"stopped: {outcome.advice}")
        if outcome.notes:
            notes += f" ({outcome.notes})"
        if res.procedure == COMMISSION_STEP.name:
            ms = [*res.measures, Measure(step, "step_passed", 1.0 if passed else 0.0, "", flag)]
            return self._write(step, ms, notes, outcome.artifacts, outcome.started)
        stored = record(self.store, res, notes=outcome.notes, artifacts=[str(a) for a in outcome.artifacts],
                        **self._kw(outcome.started))
        if not stored.ok:
            raise StoreError(f"the {res.procedure} run of commissioning step {step} was not stored "
                             f"({stored.error}); its figures are in {stored.unsaved}")
        ms = [Measure(step, "step_passed", 1.0 if passed else 0.0, "", flag),
              Measure(step, "step_run", float(stored.run_id), "", res.state)]
        return self._write(step, ms, notes)

    def skip(self, step: str, why: str) -> int:
        return self._write(step, [Measure(step, "step_passed", 0.0, "", State.TOLERANCE),
                                  Measure(step, "step_skipped", 1.0, "", State.TOLERANCE)],
                           f"commissioning step {step}: skipped: {why}")

    def failed(self, step: str, reason: str, started: float) -> None:
        """A step that raised: a run aborted with the reason (never counted as passed)."""
        try:
            rec = Recorder(self.store, COMMISSION_STEP.name, **self._kw(started),
                           notes=f"commissioning {self.cid or '(new)'} step {step}").begin()
            rec.abort(f"commissioning step {step} did not finish: {reason}")
        except Exception:   # noqa: BLE001 -- the step's own error is the one to say
            pass

    def finish_report(self, state: State, steps: dict[str, StepState], *, signed_by: str, artifacts, notes: str
                      ) -> int | None:
        """The commissioning's report as a run of ``commissioning`` (operator: who signed it off)."""
        ms = [Measure("commissioning", "commission_id", float(self.cid), "", State.OK),
              Measure("commissioning", "signed_off", 1.0 if signed_by else 0.0, "", State.OK)]
        for name, s in steps.items():
            st = State.TOLERANCE if s.skipped else State(s.status) if s.status in State.__members__ else State.ACTION
            ms.append(Measure(name, "step_run", float(s.step_run or s.run_id), "", st))
        entry = _Entry(COMMISSIONING.name, ms)
        kw = self._kw()
        kw["operator"] = signed_by
        stored = record(self.store, entry, notes=notes, artifacts=[str(a) for a in artifacts], **kw)
        if not stored.ok:
            raise StoreError(f"the commissioning report was written but not stored ({stored.error}); "
                             f"its record is in {stored.unsaved}")
        return stored.run_id


__all__ = ["Ledger", "CommissionState", "StepState", "load_state"]
