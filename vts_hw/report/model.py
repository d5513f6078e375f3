"""The data of a drift report: per camera the runs, bands, control limits, trend and forecast.

These classes hold numbers only; ``drift.py`` fills them from the results store and
``html.py`` / ``pdf.py`` / ``plots.py`` render them.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from vts_hw.report.times import fmt_date
from vts_hw.report.trend import TREND_RULE, ControlLimits, Forecast, Trend
from vts_hw.tolerance import State, Window, worst

if TYPE_CHECKING:
    from vts_hw.report.steps import StepsSummary

AXES = ("x", "y")
# camera-level metrics the drift QA writes (subject = camera name)
CAMERA_METRICS = (
    "drift_x_px",
    "drift_y_px",
    "drift_x_mm",
    "drift_y_mm",
    "drift_sd_px",
    "markers_missing",
    "stray_blobs",
    "led_off_visible",
)
# the metrics that say whether the camera itself is healthy, beside the drift
CHECK_METRICS = ("led_off_visible", "markers_missing", "stray_blobs")
# the daily QA's warm-up check: 1 when the camera had run less than its warm-up time (drift unsettled)
WARMING_METRIC = "warming_up"
STATES = ("OK", "TOLERANCE", "ACTION")


# "NoBaseline: ...", "ValueError: ...", "vts_hw.errors.DataError: ..." at the start of a note or
# after "aborted: ": a Python exception's name, which says nothing to a physicist
_EXC_NAME = re.compile(
    r"(^|:\s+)(?:[a-z_][\w]*\.)*"
    r"((?=[A-Za-z0-9]*[a-z])(?=[A-Z][A-Za-z0-9]*[A-Z])[A-Z][A-Za-z0-9]*"
    r"|[A-Z][A-Za-z0-9]*(?:Error|Exception|Warning|Interrupt|Exit))(?::\s*|$)"
)
_ERRNO = re.compile(r"\[Errno -?\d+\]\s*")
_EXC_ALONE = {
    "TimeoutError": "timed out",
    "KeyboardInterrupt": "interrupted (Ctrl-C)",
    "SystemExit": "the program exited",
    "MemoryError": "out of memory",
}


def readable_note(text: str | None) -> str:
    """A run's stored note without Python exception names.

    ``aborted: NoBaseline: camera cam1 has no ...`` reads ``aborted: camera cam1 has no ...``;
    a bare name (``aborted: KeyboardInterrupt``) becomes words. The store keeps the note as
    written (history is never rewritten); only what the report shows is cleaned.
    """
    text = (text or "").strip()

    def sub(m: re.Match) -> str:
        name = m.group(2)
        rest_empty = m.end() == len(text)
        if rest_empty:
            return m.group(1) + _EXC_ALONE.get(name, "failed (" + re.sub(r"(?<!^)(?=[A-Z])", " ", name).lower() + ")")
        return m.group(1)

    return _ERRNO.sub("", _EXC_NAME.sub(sub, text))


def _clean(v):
    """A JSON-safe number: NaN/inf become None, numpy scalars plain floats."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


@dataclass
class RunPoint:
    """One completed drift (or daily) run as seen by one camera."""

    run_id: int
    t: float
    procedure: str
    values: dict[str, float | None]
    status: dict[str, str]  # metric -> OK / TOLERANCE / ACTION

    def value(self, metric: str) -> float:
        v = self.values.get(metric)
        return math.nan if v is None else float(v)

    @property
    def warming_up(self) -> bool:
        """The camera had run less than its warm-up time: its drift may not have settled."""
        return (self.values.get(WARMING_METRIC) or 0) > 0

    @property
    def drift_measured(self) -> bool:
        """The run measured this camera's drift (a finite x or y)."""
        return any(math.isfinite(self.value(f"drift_{a}_px")) for a in AXES)

    @property
    def state(self) -> State:
        """Worst state of this camera's measurements in this run, whatever the check (drift,
        LED, reachable, parameters, clock). A run that could not measure the camera's drift (it
        did not answer) is never OK: ACTION, as the daily QA judges a value it could not get."""
        st = worst(State(s) for s in self.status.values() if s in STATES)
        return st if self.drift_measured else State.ACTION

    def not_ok(self) -> list[str]:
        """The metrics of this run that were not OK (``drift not measured`` when it was not)."""
        bad = sorted(m for m, s in self.status.items() if s != "OK")
        return bad if self.drift_measured else bad + ["drift not measured"]

    def as_dict(self) -> dict:
        return {
            "run_id": self.run_id,
            "t": self.t,
            "date": fmt_date(self.t),
            "procedure": self.procedure,
            "state": str(self.state),
            "values": {k: _clean(v) for k, v in self.values.items()},
            "status": dict(self.status),
        }


@dataclass(frozen=True)
class BandSegment:
    """A tolerance window in effect from ``start`` to ``end`` (``window_id`` None: the default)."""

    start: float
    end: float
    window_id: int | None
    window: Window

    def as_dict(self) -> dict:
        return {
            "start": self.start,
            "end": self.end,
            "window_id": self.window_id,
            "window": self.window.as_dict(),
            "default": self.window_id is None,
        }


@dataclass
class AxisSummary:
    """Control limits, trend and forecast of one axis of one camera."""

    control: ControlLimits
    trend: Trend
    forecast: Forecast

    def as_dict(self) -> dict:
        return {"control": self.control.as_dict(), "trend": self.trend.as_dict(), "forecast": self.forecast.as_dict()}


@dataclass
class CameraDrift:
    """Everything the report says about one camera."""

    name: str
    points: list[RunPoint]  # runs shown (in the report period), oldest first
    baselines: list[float]  # baseline times shown
    baseline_t: float | None  # the latest baseline (may be before the period)
    axes: dict[str, AxisSummary]  # "x", "y"
    mm_per_px: dict[str, float | None]  # from the stored px and mm values, per axis
    markers: dict[str, dict[str, float | None]] = field(default_factory=dict)  # latest run, per marker

    @property
    def latest(self) -> RunPoint | None:
        return self.points[-1] if self.points else None

    @property
    def state(self) -> State:
        """The state of the camera in its latest run (OK when it has none)."""
        return self.latest.state if self.latest else State.OK

    def times(self) -> np.ndarray:
        return np.array([p.t for p in self.points], dtype=float)

    def series(self, metric: str) -> np.ndarray:
        return np.array([p.value(metric) for p in self.points], dtype=float)

    def events(self, metric: str) -> list[RunPoint]:
        """Runs in which a check metric (LED, missing markers, stray blobs) was not zero."""
        return [p for p in self.points if (p.values.get(metric) or 0) > 0]

    def nearest_forecast(self) -> tuple[str, Forecast] | None:
        """The axis whose forecast comes first, among those within a year."""
        hits = [
            (s.forecast.t, a, s.forecast)
            for a, s in self.axes.items()
            if s.forecast.within_year and s.forecast.t is not None
        ]  # a date or reached: t is set
        if not hits:
            return None
        _, axis, first = min(hits, key=lambda h: h[0])
        return axis, first

    def as_dict(self) -> dict:
        return {
            "name": self.name,
            "state": str(self.state),
            "latest": self.latest.as_dict() if self.latest else None,
            "baseline_t": self.baseline_t,
            "baselines": list(self.baselines),
            "mm_per_px": {a: _clean(v) for a, v in self.mm_per_px.items()},
            "axes": {a: s.as_dict() for a, s in self.axes.items()},
            "series": [p.as_dict() for p in self.points],
            "markers": {m: {k: _clean(v) for k, v in d.items()} for m, d in self.markers.items()},
        }


@dataclass(frozen=True)
class RunInfo:
    """A run listed as such (a baseline, or a run that did not complete)."""

    id: int
    procedure: str
    started: float
    status: str
    rig: str = ""
    operator: str = ""
    notes: str = ""  # as the report shows it (readable_note)
    stored_notes: str = ""  # as the store holds it

    @classmethod
    def of(cls, run) -> RunInfo:
        return cls(
            id=run.id,
            procedure=run.procedure,
            started=run.started,
            status=str(run.status or "unfinished"),
            rig=run.rig or "",
            operator=run.operator or "",
            notes=readable_note(run.notes),
            stored_notes=run.notes or "",
        )

    def as_dict(self) -> dict:
        return {**self.__dict__, "date": fmt_date(self.started)}


@dataclass
class DriftReport:
    """A drift trend report: what ``build_drift_report`` computed and where it wrote it."""

    title: str
    rig: str | None
    since: float | None
    now: float
    period_start: float | None  # first run shown (or since)
    cameras: dict[str, CameraDrift]
    bands: dict[str, list[BandSegment]]  # "x", "y": windows of drift_x_px / drift_y_px
    baselines: list[RunInfo]  # baseline runs in the period
    not_completed: list[RunInfo]  # aborted / error / unfinished runs in the period
    software_version: str
    control_method: str
    out: Path | None = None
    steps: StepsSummary | None = None  # the 7-sphere step tests of the period
    has_baseline: bool = True  # the store holds a completed baseline (any time up to now)
    history: list = field(default_factory=list)  # report.history.ProcedureHistory per procedure with runs

    @property
    def state(self) -> State:
        return worst(c.state for c in self.cameras.values())

    @property
    def plot_count(self) -> int:
        """Plots the report holds: one per camera with runs, and the step test's."""
        steps = 1 if self.steps is not None and self.steps.plot_png is not None else 0
        history = sum(1 for h in self.history if h.has_plot)
        return sum(1 for c in self.cameras.values() if c.points) + steps + history

    def window_now(self, axis: str) -> Window:
        return self.bands[axis][-1].window

    def attention(self) -> list[str]:
        """One line per thing a physicist should look at, worst first."""
        out = []
        for c in self.cameras.values():
            if c.latest and c.state != State.OK:
                out.append((c.state.rank, f"{c.name}: {c.state} in the latest run ({', '.join(c.latest.not_ok())})"))
            nf = c.nearest_forecast()
            if nf:
                axis, f = nf
                when = "has reached" if f.status == "reached" else "reaches"
                on = "" if f.status == "reached" else f" on {fmt_date(f.t)}"
                out.append((1, f"{c.name}: the drift trend in {axis} {when} the action level ({f.level:+g} px){on}"))
            led = c.events("led_off_visible")
            if led:
                out.append((1, f"{c.name}: LED check failed on {len(led)} run(s), last {fmt_date(led[-1].t)}"))
        steps = self.steps
        if steps is not None and steps.latest is not None and steps.state not in (None, State.OK):
            bad = sorted({f"{m.metric} ({m.subject})" for m in steps.measures if str(m.status) != "OK"})
            step_state = State(steps.latest.status)
            out.append(
                (step_state.rank, f"7-sphere step test: {step_state} in run {steps.latest.id} ({', '.join(bad)})")
            )
        out += [a for a in (h.attention() for h in self.history) if a is not None]
        if not self.has_baseline:  # an empty store too: the first thing to do
            out.append((1, "no drift baseline is recorded: set one with `vts qa drift --set-baseline`"))
        if self.not_completed:
            out.append((0, f"{len(self.not_completed)} run(s) did not complete (listed below)"))
        return [text for _, text in sorted(out, key=lambda x: -x[0])]

    def results_data(self) -> dict:
        """Everything computed, as a JSON-ready dict (no NaN: missing numbers are None)."""
        return {
            "report": "drift",
            "title": self.title,
            "rig": self.rig,
            "since": self.since,
            "now": self.now,
            "period_start": self.period_start,
            "state": str(self.state),
            "software_version": self.software_version,
            "control_method": self.control_method,
            "out": str(self.out) if self.out else None,
            "bands": {a: [s.as_dict() for s in segs] for a, segs in self.bands.items()},
            "cameras": {n: c.as_dict() for n, c in self.cameras.items()},
            "baselines": [r.as_dict() for r in self.baselines],
            "not_completed": [r.as_dict() for r in self.not_completed],
            "has_baseline": self.has_baseline,
            "trend_rule": TREND_RULE,
            "attention": self.attention(),
            "steps": None if self.steps is None else self.steps.results_data(),
            "history": [h.results_data() for h in self.history],
        }
