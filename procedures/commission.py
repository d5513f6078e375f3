"""Commissioning a room (issue 24 §3): the guided sequence from cameras in boxes to a room ready
for patients, each step a stored run, resumable where it stopped.

The steps, in order (:data:`STEPS`): the cameras found and set up, the trigger box asked its
version, aim and focus, the warm-up, calibration, the VTS → SPECT mapping, the step test, the
sync check, the drift baseline. Each step calls the function its own command calls
(:mod:`vts_hw.procedures.commission_steps`); nothing of a procedure is done again here.

A procedure never holds a store: :func:`run_sequence` is handed a ``ledger`` (the caller's:
vts_hw.store.commission.Ledger) that records each step's outcome and is asked nothing else.
A step ends in one of:

* passed -- the sequence goes on (a figure in TOLERANCE passes, and is reported);
* stopped -- a figure in ACTION, a camera to adjust, a camera still warming up with ``no_wait``:
  recorded (not passed), the sequence stops with what to do;
* an error -- a device that failed (exit 4), an input missing (exit 2): recorded as a step that
  did not pass, with the reason, then raised for the caller's exit code; Ctrl-C likewise.

docs/decisions/0069-commissioning.md.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from vts_hw.catalog import COMMISSION_STEP
from vts_hw.errors import UsageError
from vts_hw.results import Measure, overall_state
from vts_hw.tolerance import State


@dataclass(frozen=True)
class Step:
    name: str
    label: str
    command: str        # the command that runs it on its own
    needs: str = ""     # what the operator must give for it (an option), "" when nothing


STEPS: tuple[Step, ...] = (
    Step("cameras", "discover and set up the cameras", "vts discover; vts camera setup --all"),
    Step("trigger", "trigger box", "vts trigger status"),
    Step("aim", "aim and focus", "vts camera aim NAME"),
    Step("warmup", "warm-up", "vts qa daily (its uptime check and drift detection)"),
    Step("calibration", "calibration", "vts calibrate cameras IMAGES", "--checkerboards"),
    Step("mapping", "VTS → SPECT mapping", "vts calibrate spect --from-cameras --volume FILE", "--phantom-volume"),
    Step("steps", "step test", "vts qa steps --volumes DIR", "--step-volumes"),
    Step("sync", "sync check", "vts sync analyze SESSION --listmode FILE", "--sync-session, --listmode"),
    Step("baseline", "drift baseline", "vts qa drift --set-baseline"),
)
NAMES = tuple(s.name for s in STEPS)


def step(name: str) -> Step:
    for s in STEPS:
        if s.name == name:
            return s
    raise UsageError(f"no commissioning step {name!r}: the steps are {', '.join(NAMES)}")


@dataclass
class StepCheck:
    """The result of a step that is no procedure of its own (cameras, trigger, aim, warm-up):
    the one QA result shape, stored as a run of ``commission-step``."""

    step: str
    measures: list[Measure]
    lines: list[str] = field(default_factory=list)
    data: dict = field(default_factory=dict)
    procedure: str = COMMISSION_STEP.name

    @property
    def state(self) -> State:
        return overall_state(self.measures)

    def results(self) -> str:
        return "\n".join(self.lines)

    def results_data(self) -> dict:
        return {"procedure": self.procedure, "step": self.step, "state": str(self.state), **self.data}

    def plot(self, path=None) -> bytes:
        raise NotImplementedError("a commissioning step has no plot")


@dataclass
class Outcome:
    """How a step ended: its result (stored as its procedure's run), whether the sequence goes
    on, what to do when it does not, the files it wrote (artifacts), when it started."""

    step: str
    result: object
    passed: bool
    advice: str = ""
    artifacts: list[Path] = field(default_factory=list)
    started: float = 0.0
    notes: str = ""
    error: Exception | None = None   # recorded as not passed, then raised (rig.yaml not written: exit 3)

    @property
    def state(self) -> State:
        return self.result.state


@dataclass
class Inputs:
    """What the operator gives: the files the measuring steps need, and their settings."""

    out: Path
    checkerboards: tuple[str, ...] = ()
    pattern: tuple[int, int] = (9, 6)
    square_mm: float = 30.0
    phantom_volume: str | None = None
    step_volumes: str | None = None
    vertical: int = 10
    axial: int = 10
    sync_session: str | None = None
    listmode: tuple[str, ...] = ()
    frames: int = 10
    listen_s: float = 3.0
    interfaces: tuple[str, ...] = ()
    wait: bool = True

    @property
    def calibration_file(self) -> Path:
        return self.out / "calibration.json"

    @property
    def mapping_file(self) -> Path:
        return self.out / "spect_mapping.json"


@dataclass
class Context:
    """One commissioning's rig (read again after a step changes rig.yaml), inputs and hooks."""

    rig: object
    inputs: Inputs
    say: Callable[[str], None] = lambda m: None
    ask: Callable[[str], object] = input
    clock: Callable[[], float] = time.time
    sleep: Callable[[float], None] = time.sleep
    reload: Callable[[], object] | None = None    # the rig config read again (after rig.yaml changed)

    def refresh(self) -> None:
        if self.reload is not None:
            self.rig = self.reload()


@dataclass
class SequenceEnd:
    """Where the sequence ended: the outcomes of the steps run now, the step that stopped it
    (None: every step passed or was skipped)."""

    outcomes: list[Outcome]
    stopped: Outcome | None = None

    @property
    def done(self) -> bool:
        return self.stopped is None


def plan(start: str | None, done: dict[str, bool]) -> list[str]:
    """The steps to run: from ``start`` (every later one too), else from the first step that has
    not passed or been skipped (``done``: step -> passed or skipped, in the current commissioning)."""
    if start is not None:
        step(start)
        return list(NAMES[NAMES.index(start):])
    for i, name in enumerate(NAMES):
        if not done.get(name):
            return list(NAMES[i:])
    return []


def run_sequence(ctx: Context, todo: list[str], ledger, skips: dict[str, str] | None = None) -> SequenceEnd:
    """Run ``todo`` in order through ``ledger`` (``record(outcome) -> run id``, ``skip(step, why)``,
    ``failed(step, reason)``); a step in ``skips`` is recorded skipped with its reason."""
    from vts_hw.procedures import commission_steps as run

    skips = dict(skips or {})
    outcomes: list[Outcome] = []
    for name in todo:
        s = step(name)
        if name in skips:
            ledger.skip(name, skips[name])
            ctx.say(f"== {s.label}: SKIPPED ({skips[name]})")
            continue
        ctx.say(f"== {s.label} ({s.command})")
        started = ctx.clock()
        try:
            out = getattr(run, name)(ctx)
        except BaseException as exc:      # a device that failed, an input missing, Ctrl-C: said and kept
            reason = "interrupted" if isinstance(exc, KeyboardInterrupt) else (str(exc) or type(exc).__name__)
            ledger.failed(name, reason, started)
            raise
        out.started = out.started or started
        if isinstance(out.result, StepCheck):      # a procedure's result said itself already
            ctx.say(out.result.results())
        ledger.record(out)
        outcomes.append(out)
        if out.error is not None:          # its figures stored, then the error said (exit code) and resumable
            raise out.error
        if not out.passed:
            return SequenceEnd(outcomes, out)
    return SequenceEnd(outcomes)


__all__ = ["STEPS", "NAMES", "Step", "StepCheck", "Outcome", "Inputs", "Context", "SequenceEnd", "plan",
           "run_sequence", "step"]
