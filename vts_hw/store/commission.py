"""The state of a room's commissioning, kept in the results store (decisions 0069, 0084).

Every step of the sequence leaves a run of ``commission-step`` (vts_hw.catalog.COMMISSION_STEP).
It is written "running" when the step starts, its notes beginning ``commissioning CID step
NAME`` (``(new)`` for the first step of a new commissioning, whose own run id names it), so
that a commissioning killed in a step (SIGKILL, a power cut) leaves a row, which the next open
of the store marks aborted (vts_hw.store.liveness). A step that ends is finished with
measures that name the step (their subject): ``commission_id`` (which commissioning),
``step_passed`` (1 passed, 0 stopped), ``step_skipped`` (1, the reason in the notes), and
``step_run`` (the step's own run, for a step that is a procedure of its own: calibration,
mapping, step test, sync check, drift baseline, stored under their own names through the one
recorder). A step that raised (a device failed, an input missing, Ctrl-C, SIGTERM) is aborted
with the reason; an aborted run has no measures, its notes name the step. Nothing is ever
rewritten: a step run again is a newer run of the same step, and the NEWEST attempt of each
step is the commissioning's state, whatever it was (a failed or aborted redo undoes the pass
of the run before it); the older runs stay.

:class:`Ledger` writes (the procedure gets it as its ``ledger``); :func:`load_state` reads;
:meth:`CommissionState.standing` says where the room stands (OK, TOLERANCE, ACTION or
incomplete, with what was skipped and what did not pass).
"""

from __future__ import annotations

import re
import time
from collections import defaultdict
from dataclasses import dataclass, field

from vts_hw.catalog import COMMISSION_STEP, COMMISSION_STEPS, COMMISSIONING
from vts_hw.results import Measure, overall_state
from vts_hw.store.errors import StoreError
from vts_hw.store.recorder import ResultRecorder, record
from vts_hw.store.records import Measurement, Run
from vts_hw.tolerance import State

KEYS = ("commission_id", "step_passed", "step_run", "step_skipped")
LABELS = dict(COMMISSION_STEPS)
#: the first line of a step run's notes while it runs (kept when it is aborted)
_MARK = re.compile(r"^commissioning (\d+|\(new\)) step ([a-z]+)\b")


def _mark(cid: int | None, step: str) -> str:
    return f"commissioning {cid if cid is not None else '(new)'} step {step}"


def _aborted_reason(notes: str) -> str:
    """Why an aborted step run ended, from its notes (the lines after its mark)."""
    lines = [ln for ln in notes.splitlines()[1:] if ln.strip()]
    text = "; ".join(ln.removeprefix("aborted: ") for ln in lines)
    return text or "it did not finish"


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
    run_id: int  # the commission-step run
    started: float
    status: str  # the run's: OK / TOLERANCE / ACTION, or "aborted"
    passed: bool
    skipped: bool
    step_run: int | None  # the step's own run (a procedure's), else None: its figures are in run_id
    notes: str

    @property
    def aborted(self) -> bool:
        return self.status == "aborted"

    @property
    def label(self) -> str:
        return LABELS.get(self.step, self.step)

    def why(self) -> str:
        """Why this attempt did not pass: the reason it was aborted, or where it stopped."""
        if self.aborted:
            return _aborted_reason(self.notes)
        head = self.notes.split("stopped: ", 1)
        return head[1].strip() if len(head) == 2 else f"{self.status}"

    def outcome(self, why: bool = True) -> str:
        """This attempt in a few words: "passed", "skipped", "aborted (why)", "stopped (why)" (without
        the why when ``why`` is False)."""
        if self.skipped:
            return "skipped"
        if self.passed:
            return "passed"
        word = "aborted" if self.aborted else "stopped"
        return f"{word} ({self.why()})" if why else word


@dataclass
class Standing:
    """Where a room's commissioning stands: ``word`` is OK, TOLERANCE or ACTION (every step's newest
    attempt passed or was skipped, and the report was written after them: its state), or
    "incomplete"; ``skipped`` and ``not_passed`` (step names; a step never run is not passed)."""

    cid: int
    word: str
    skipped: list[str]
    not_passed: list[str]
    report: Run | None  # the report run that stands, else None
    last_report: Run | None  # the newest report run of this commissioning, standing or not
    attempts: dict[str, StepState] = field(default_factory=dict)  # the newest attempt of each step run

    def not_passed_text(self, why: bool = True) -> list[str]:
        """Each step not passed in a few words: "warm-up aborted (stopped by SIGTERM)" ("warm-up aborted"
        without the why), "sync check not run"."""
        return [
            f"{LABELS.get(n, n)} " + (self.attempts[n].outcome(why) if n in self.attempts else "not run")
            for n in self.not_passed
        ]

    @property
    def complete(self) -> bool:
        return self.word != "incomplete"


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

    def unfinished(self) -> list[StepState]:
        """The steps whose newest attempt was aborted (a step that raised, or whose process died)."""
        return [s for s in self.steps.values() if s.aborted]

    def standing(self, store) -> Standing | None:
        """Where this commissioning stands (None: there is none); ``store`` gives the report run."""
        if self.cid is None:
            return None
        names = [n for n, _ in COMMISSION_STEPS]
        skipped = [n for n in names if n in self.steps and self.steps[n].skipped]
        not_passed = [n for n in names if n not in self.steps or not (self.steps[n].passed or self.steps[n].skipped)]
        last = store.run(self.report_run) if self.report_run is not None else None
        newest_step = max((s.run_id for s in self.steps.values()), default=0)
        stands = last if last is not None and last.id > newest_step and not not_passed else None
        word = str(stands.status) if stands is not None and str(stands.status) in State.__members__ else "incomplete"
        return Standing(self.cid, word, skipped, not_passed, stands, last, dict(self.steps))


def load_state(store, rig: str) -> CommissionState:
    """The newest commissioning of ``rig`` in ``store`` (cid None when there is none): the newest
    attempt of each of its steps (passed, stopped, skipped or aborted) and its newest report."""
    names = (COMMISSION_STEP.name, COMMISSIONING.name)
    runs = {r.id: r for r in store.runs(procedure=names) if (r.rig or "") == rig and r.status != "running"}
    keyed: dict[int, dict[str, Measurement]] = defaultdict(dict)
    for m in store.measurements(procedure=names, metric=KEYS):
        if m.run_id in runs:
            keyed[m.run_id][m.metric] = m
    # (run id, commissioning, step) of every ledger run: by its measures, or an aborted one by its notes
    entries: list[tuple[int, int, str]] = []
    for rid in sorted(runs):
        k, run = keyed[rid], runs[rid]
        cid = k["commission_id"].value if "commission_id" in k else None  # always a number as the ledger writes it
        if cid is not None:
            entries.append((rid, int(cid), k["commission_id"].subject))
        elif run.procedure == COMMISSION_STEP.name and run.status == "aborted":
            m = _MARK.match(run.notes or "")
            if m:
                entries.append((rid, rid if m.group(1) == "(new)" else int(m.group(1)), m.group(2)))
    st = CommissionState(rig)
    if not entries:
        return st
    st.cid = entries[-1][1]
    for rid, cid, step in entries:
        if cid != st.cid:
            continue
        k, run = keyed[rid], runs[rid]
        if run.procedure == COMMISSIONING.name:
            st.report_run = rid
            continue
        ref = k.get("step_run")
        st.steps[step] = StepState(
            step,
            rid,
            run.started,
            run.status,
            bool(k.get("step_passed") and k["step_passed"].value == 1),
            bool(k.get("step_skipped") and k["step_skipped"].value == 1),
            int(ref.value) if ref is not None and ref.value is not None else None,
            run.notes,
        )
    return st


class Ledger:
    """Records the steps of one commissioning of ``rig`` (a RigConfig) in ``store`` (open)."""

    def __init__(self, store, rig, *, cid: int | None = None, operator: str = "", clock=time.time):
        self.store, self.rig, self.cid, self.operator, self.clock = store, rig, cid, operator, clock
        self._open: dict[str, ResultRecorder] = {}  # step -> its run, written "running" by begin()

    def _kw(self, started=None):
        return dict(
            rig=self.rig.rig,
            operator=self.operator,
            config_digest=self.rig.digest,
            tolerances=self.rig.tolerances,
            clock=self.clock,
            **({} if started is None else {"started": started}),
        )

    def begin(self, step: str, started: float | None = None) -> int:
        """The step's run, written "running" now (its notes name the commissioning and the step):
        a commissioning killed in the step leaves it, and the next open of the store marks it
        aborted. A store that cannot take it stops the step before it starts (exit 3)."""
        rec = ResultRecorder(self.store, COMMISSION_STEP.name, notes=_mark(self.cid, step), **self._kw(started)).begin()
        if rec.run_id is None:
            raise StoreError(f"the commissioning step {step} could not be recorded ({rec.error}); it was not started")
        if self.cid is None:
            self.cid = rec.run_id  # the first step's run names the commissioning
        self._open[step] = rec
        return rec.run_id

    def _known_cid(self) -> int:
        """The commissioning's id: its first step's run, set by begin()."""
        if self.cid is None:
            raise RuntimeError(f"no step of this commissioning of {self.rig.rig} has begun: it has no id yet")
        return self.cid

    def _write(self, step: str, measures: list, notes: str, artifacts=(), started=None) -> int:
        rec = self._open.pop(step, None)
        if rec is None:
            self.begin(step, started)
            rec = self._open.pop(step)
        ms = [Measure(step, "commission_id", float(self._known_cid()), "", State.OK), *measures]
        stored = rec.finish(_Entry(COMMISSION_STEP.name, ms), artifacts=[str(a) for a in artifacts], notes=notes)
        if stored.run_id is None:
            raise StoreError(
                f"the commissioning step {step} was not stored ({stored.error}); its figures are in {stored.unsaved}"
            )
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
        stored = record(
            self.store,
            res,
            notes=outcome.notes,
            artifacts=[str(a) for a in outcome.artifacts],
            **self._kw(outcome.started),
        )
        if stored.run_id is None:
            raise StoreError(
                f"the {res.procedure} run of commissioning step {step} was not stored "
                f"({stored.error}); its figures are in {stored.unsaved}"
            )
        ms = [
            Measure(step, "step_passed", 1.0 if passed else 0.0, "", flag),
            Measure(step, "step_run", float(stored.run_id), "", res.state),
        ]
        return self._write(step, ms, notes)

    def skip(self, step: str, why: str) -> int:
        return self._write(
            step,
            [
                Measure(step, "step_passed", 0.0, "", State.TOLERANCE),
                Measure(step, "step_skipped", 1.0, "", State.TOLERANCE),
            ],
            f"commissioning step {step}: skipped: {why}",
        )

    def failed(self, step: str, reason: str, started: float) -> None:
        """A step that raised: its run aborted with the reason (never counted as passed). When
        even that cannot be written, the run stays "running" and the next open marks it aborted."""
        try:
            rec = self._open.pop(step, None)
            if rec is None:
                rec = ResultRecorder(
                    self.store, COMMISSION_STEP.name, notes=_mark(self.cid, step), **self._kw(started)
                ).begin()
            rec.abort(reason)
        except Exception:  # noqa: BLE001 -- the step's own error is the one to say
            pass

    def finish_report(
        self, state: State, steps: dict[str, StepState], *, signed_by: str, artifacts, notes: str
    ) -> int | None:
        """The commissioning's report as a run of ``commissioning`` (operator: who signed it off)."""
        ms = [
            Measure("commissioning", "commission_id", float(self._known_cid()), "", State.OK),
            Measure("commissioning", "signed_off", 1.0 if signed_by else 0.0, "", State.OK),
        ]
        for name, s in steps.items():
            st = State.TOLERANCE if s.skipped else State(s.status) if s.status in State.__members__ else State.ACTION
            ms.append(Measure(name, "step_run", float(s.step_run or s.run_id), "", st))
        entry = _Entry(COMMISSIONING.name, ms)
        kw = self._kw()
        kw["operator"] = signed_by
        stored = record(self.store, entry, notes=notes, artifacts=[str(a) for a in artifacts], **kw)
        if stored.run_id is None:
            raise StoreError(
                f"the commissioning report was written but not stored ({stored.error}); "
                f"its record is in {stored.unsaved}"
            )
        return stored.run_id


__all__ = ["Ledger", "CommissionState", "StepState", "Standing", "load_state", "LABELS"]
