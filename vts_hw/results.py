"""One shape for every QA result, after pylinac: load → analyze(tolerances) → results(),
results_data(), plot(); each figure a :class:`Measure` judged by a tolerance window.

A procedure's result keeps this shape (:class:`Analysis`) and is stored one way
(:class:`vts_hw.store.recorder.ResultRecorder`): a run of its ``procedure`` with one measurement
per :class:`Measure`, the run's state the worst of them — or, when the store cannot take it,
a file that ``vts qa import`` stores later.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol, runtime_checkable

from vts_hw.tolerance import State, Window, worst


class Measure(NamedTuple):
    """One figure of a QA result: what was measured (``subject``: a camera, a marker, an event
    set), which ``metric`` (the tolerance table's name), its value and unit, and its state.
    (A named tuple: ``subject, metric, value, unit, state = m`` reads it too.)"""

    subject: str
    metric: str
    value: float | None
    unit: str
    state: State

    @classmethod
    def judged(cls, subject: str, metric: str, value: float | None, unit: str, window: Window | None) -> Measure:
        """A measure whose state its window gives (OK without a window; ACTION when unmeasured)."""
        if value is None:
            return cls(subject, metric, None, unit, State.ACTION)
        return cls(subject, metric, float(value), unit, window.state(value) if window else State.OK)

    def as_dict(self) -> dict:
        return {
            "subject": self.subject,
            "metric": self.metric,
            "value": self.value,
            "unit": self.unit,
            "state": str(self.state),
        }


def overall_state(measures) -> State:
    """The worst state of the measures (OK when there are none)."""
    return worst([m.state for m in measures]) if measures else State.OK


@runtime_checkable
class Analysis(Protocol):
    """What every analysed QA procedure offers (its ``analyze(tolerances)`` has run): its
    ``procedure`` name, its ``measures`` and their worst ``state``, a text summary, the data as
    JSON-ready dicts, and a plot."""

    procedure: str

    @property  # read only: a procedure may work its measures out when asked (BaselineSet)
    def measures(self) -> list[Measure]: ...

    @property
    def state(self) -> State: ...

    def results(self) -> str: ...

    def results_data(self) -> dict: ...

    def plot(self, path=None) -> bytes: ...
