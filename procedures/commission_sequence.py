"""Running the steps of commissioning in order (procedures/commission.py names them,
procedures/commission_steps.py runs each) through the caller's ledger: each step's run begun
before it starts, its outcome recorded, a step that raised recorded aborted with the reason and
raised again. docs/decisions/0069-commissioning.md, 0084-commissioning-honest-state.md."""

from __future__ import annotations

from dataclasses import dataclass

from vts_hw.procedures import commission_steps as run
from vts_hw.procedures.commission import Context, Outcome, StepCheck, step


@dataclass
class SequenceEnd:
    """Where the sequence ended: the outcomes of the steps run now, the step that stopped it
    (None: every step passed or was skipped)."""

    outcomes: list[Outcome]
    stopped: Outcome | None = None

    @property
    def done(self) -> bool:
        return self.stopped is None


def failure_reason(exc: BaseException) -> str:
    """What a step that raised is recorded with: the error's sentence; for Ctrl-C "interrupted
    (Ctrl-C)", for a signal made an interrupt (SIGTERM) what it says ("stopped by SIGTERM")."""
    if isinstance(exc, KeyboardInterrupt):
        return str(exc) or "interrupted (Ctrl-C)"
    return str(exc) or type(exc).__name__


def run_sequence(ctx: Context, todo: list[str], ledger, skips: dict[str, str] | None = None) -> SequenceEnd:
    """Run ``todo`` in order through ``ledger`` (``begin(step, started)``: the step's run written
    "running" before it starts; ``record(outcome) -> run id``, ``skip(step, why)``,
    ``failed(step, reason, started)``); a step in ``skips`` is recorded skipped with its reason."""
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
        ledger.begin(name, started)
        try:
            out = getattr(run, name)(ctx)
        except BaseException as exc:  # a device that failed, an input missing, Ctrl-C, SIGTERM: said and kept
            ledger.failed(name, failure_reason(exc), started)
            raise
        out.started = out.started or started
        if isinstance(out.result, StepCheck):  # a procedure's result said itself already
            ctx.say(out.result.results())
        ledger.record(out)
        outcomes.append(out)
        if out.error is not None:  # its figures stored, then the error said (exit code) and resumable
            raise out.error
        if not out.passed:
            return SequenceEnd(outcomes, out)
    return SequenceEnd(outcomes)


__all__ = ["SequenceEnd", "failure_reason", "run_sequence"]
