"""Commissioning a room (issue 24 §3): the guided sequence from cameras in boxes to a room ready
for patients, each step a stored run, resumable where it stopped.

The steps, in order (:data:`STEPS`): the cameras found and set up, the trigger box asked its
version, aim and focus, the warm-up, calibration, the VTS → SPECT mapping, the step test, the
sync check, the drift baseline. Each step calls the function its own command calls
(:mod:`vts_hw.procedures.commission_steps`); nothing of a procedure is done again here.

A procedure never holds a store: the sequence (procedures/commission_sequence.py) is handed a
``ledger`` (the caller's: vts_hw.store.commission.Ledger) that records each step's outcome and is
asked nothing else.
A step ends in one of:

* passed -- the sequence goes on (a figure in TOLERANCE passes, and is reported);
* stopped -- a figure in ACTION, a camera to adjust, a camera still warming up with ``no_wait``:
  recorded (not passed), the sequence stops with what to do;
* an error -- a device that failed (exit 4), an input missing (exit 2), a question no one can
  answer (no terminal): recorded as a step that did not pass, with the reason, then raised for
  the caller's exit code; Ctrl-C and SIGTERM likewise.

Each step's run is begun ("running") before the step starts, so that a commissioning killed in
it (SIGKILL) leaves a row that the store marks aborted at its next open: the newest attempt of
each step, aborted ones included, is the commissioning's state.

docs/decisions/0069-commissioning.md, 0084-commissioning-honest-state.md.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vts_hw.catalog import COMMISSION_STEP, COMMISSION_STEPS
from vts_hw.config import RigConfig
from vts_hw.errors import UsageError
from vts_hw.results import Analysis, Measure, overall_state
from vts_hw.tolerance import State


@dataclass(frozen=True)
class Step:
    name: str
    label: str
    command: str  # the command that runs it on its own
    needs: str = ""  # what the operator must give for it (an option), "" when nothing


#: how each step of the catalog's COMMISSION_STEPS runs on its own, and what it needs
_HOW = {
    "cameras": ("vts discover; vts camera setup --all", ""),
    "trigger": ("vts trigger status", ""),
    "aim": ("vts camera aim NAME", ""),
    "warmup": ("vts qa daily (its uptime check and drift detection)", ""),
    "calibration": ("vts calibrate cameras IMAGES", "--checkerboards"),
    "mapping": ("vts calibrate spect --from-cameras --volume FILE", "--phantom-volume"),
    "steps": ("vts qa steps --volumes DIR", "--step-volumes"),
    "sync": ("vts sync analyze SESSION --listmode FILE", "--sync-session, --listmode"),
    "baseline": ("vts qa drift --set-baseline", ""),
}
STEPS: tuple[Step, ...] = tuple(Step(name, label, *_HOW[name]) for name, label in COMMISSION_STEPS)
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
    result: Analysis
    passed: bool
    advice: str = ""
    artifacts: list[Path] = field(default_factory=list)
    started: float = 0.0
    notes: str = ""
    error: Exception | None = None  # recorded as not passed, then raised (rig.yaml not written: exit 3)

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
    room_clear: bool = False  # the drift baseline's "clear the room" answered beforehand (no terminal needed)

    @property
    def calibration_file(self) -> Path:
        return self.out / "calibration.json"

    @property
    def mapping_file(self) -> Path:
        return self.out / "spect_mapping.json"


@dataclass
class Context:
    """One commissioning's rig (read again after a step changes rig.yaml), inputs and hooks."""

    rig: RigConfig
    inputs: Inputs
    say: Callable[[str], None] = lambda m: None
    ask: Callable[[str], object] = input
    clock: Callable[[], float] = time.time
    sleep: Callable[[float], None] = time.sleep
    reload: Callable[[], RigConfig] | None = None  # the rig config read again (after rig.yaml changed)
    # the room's parts, given by the application that opened it (`vts commission`: the room's
    # camera(cfg) and trigger(), which the room closes); None: a step opens and closes its own
    camera: Callable[[Any], Any] | None = None
    trigger: Callable[[], Any] | None = None

    def refresh(self) -> None:
        if self.reload is not None:
            self.rig = self.reload()


def plan(start: str | None, done: dict[str, bool]) -> list[str]:
    """The steps to run: from ``start`` (every later one too), else from the first step that has
    not passed or been skipped (``done``: step -> passed or skipped, in the current commissioning)."""
    if start is not None:
        step(start)
        return list(NAMES[NAMES.index(start) :])
    for i, name in enumerate(NAMES):
        if not done.get(name):
            return list(NAMES[i:])
    return []


__all__ = ["STEPS", "NAMES", "Step", "StepCheck", "Outcome", "Inputs", "Context", "plan", "step"]
