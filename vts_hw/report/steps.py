"""The 7-sphere step test in the QA report: the latest run's figures and plot, and the history.

:func:`collect_steps` reads the ``sphere-steps`` runs of the period from the results store;
the HTML section and the PDF page show the latest run's measurements with their states, the
plot the run saved (checked against the sha256 the store kept), and one line per earlier run.
"""

from __future__ import annotations

import base64
import hashlib
from dataclasses import dataclass, field
from html import escape
from pathlib import Path

from vts_hw import catalog
from vts_hw.report.times import fmt_datetime
from vts_hw.tolerance import State

PROCEDURE = catalog.STEPS.name

# metric -> (label, format) in the order the report lists them (the catalog's figures)
ROWS = {f.metric: (f.label, f.fmt) for f in catalog.STEPS.figures}


@dataclass
class StepRun:
    id: int
    started: float
    status: str
    operator: str = ""


@dataclass
class StepsSummary:
    runs: list[StepRun]  # in the period, oldest first
    measures: list = field(default_factory=list)  # the latest completed run's Measurements
    plot_png: bytes | None = None  # its plot, when the file is still there and intact
    plot_problem: str = ""

    @property
    def latest(self) -> StepRun | None:
        done = [r for r in self.runs if r.status in ("OK", "TOLERANCE", "ACTION")]
        return done[-1] if done else None

    @property
    def state(self) -> State | None:
        return None if self.latest is None else State(self.latest.status)

    def rows(self) -> list[tuple[str, str, str, str]]:
        """(quantity, subject, value, state) of the latest run, in report order."""
        order = {m: i for i, m in enumerate(ROWS)}
        out = []
        for m in sorted(self.measures, key=lambda m: (order.get(m.metric, 99), m.subject)):
            label, spec = ROWS.get(m.metric, (m.metric, ".3f"))
            value = "n/a" if m.value is None else format(m.value, spec)
            out.append((label, m.subject, value, str(m.status)))
        return out

    def results_data(self) -> dict:
        latest = self.latest
        return {
            "runs": [r.__dict__ for r in self.runs],
            "latest": None
            if latest is None
            else {
                **latest.__dict__,
                "measurements": [
                    {"subject": m.subject, "metric": m.metric, "value": m.value, "unit": m.unit, "state": str(m.status)}
                    for m in self.measures
                ],
            },
            "plot": self.plot_png is not None,
            "plot_problem": self.plot_problem,
        }


def collect_steps(store, since: float | None, now: float, rig: str | None) -> StepsSummary | None:
    """The step-test runs of the period (None when there are none)."""
    runs = [
        r
        for r in store.runs(procedure=catalog.STEPS.stored_as, since=since)
        if r.started <= now and (rig is None or (r.rig or "") == rig)
    ]
    if not runs:
        return None
    out = StepsSummary([StepRun(r.id, r.started, str(r.status), r.operator or "") for r in runs])
    latest = out.latest
    if latest is None:
        return out
    out.measures = store.measurements(run_id=latest.id)
    for a in store.artifacts(latest.id):
        if not a.path.endswith(".png"):
            continue
        p = Path(a.path)
        try:
            data = p.read_bytes()
        except OSError:
            out.plot_problem = f"the plot {p} is no longer there"
            continue
        if hashlib.sha256(data).hexdigest() != a.sha256:
            out.plot_problem = f"the plot {p} was changed after the run (sha256 differs); not shown"
            continue
        out.plot_png = data
    return out


def steps_html(s: StepsSummary) -> str:
    """The report's section on the step test."""
    latest = s.latest
    if latest is None:
        return (
            '<section class="card"><h2>7-sphere step test</h2><p class="muted">No completed '
            "step test in this period.</p></section>"
        )
    rows = "".join(
        f'<tr><td>{escape(q)}</td><td>{escape(sub)}</td><td class="num s-{escape(st)}">'
        f'{escape(v)}</td><td><span class="badge {escape(st)}">{escape(st)}</span></td></tr>'
        for q, sub, v, st in s.rows()
    )
    img = ""
    if s.plot_png is not None:
        b64 = base64.b64encode(s.plot_png).decode("ascii")
        img = f'<img class="plot" alt="7-sphere step test, run {latest.id}" src="data:image/png;base64,{b64}">'
    elif s.plot_problem:
        img = f'<p class="muted">{escape(s.plot_problem)}</p>'
    history = "".join(
        f"<li>{fmt_datetime(r.started)} · run {r.id} · "
        f'<span class="badge {escape(r.status)}">{escape(r.status)}</span></li>'
        for r in s.runs
    )
    return (
        f'<section class="card"><h2>7-sphere step test</h2>'
        f'<div class="meta">latest: run {latest.id}, {fmt_datetime(latest.started)}'
        f"{', ' + escape(latest.operator) if latest.operator else ''} · "
        f'<span class="badge {escape(latest.status)}">{escape(latest.status)}</span></div>'
        f'{img}<div class="scroll"><table><tr><th>quantity</th><th>axis</th>'
        f'<th class="num">value</th><th>state</th></tr>{rows}</table></div>'
        f"<h3>Step tests in the period</h3><ul>{history}</ul></section>"
    )


def steps_figure(s: StepsSummary, figsize=(11.69, 8.27)):
    """A PDF page: the latest run's plot above its table of figures."""
    import io

    import matplotlib.image as mpimg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize)
    latest = s.latest
    fig.text(0.05, 0.94, "7-sphere step test", fontsize=16, fontweight="bold")
    if latest is None:
        fig.text(0.05, 0.88, "No completed step test in this period.", fontsize=11)
        return fig
    fig.text(
        0.05,
        0.905,
        f"latest: run {latest.id}, {fmt_datetime(latest.started)} · {latest.status} · "
        f"{len(s.runs)} step test(s) in the period",
        fontsize=9,
        color="#5f6b7a",
    )
    if s.plot_png is not None:
        ax = fig.add_axes((0.03, 0.52, 0.94, 0.36))
        ax.imshow(mpimg.imread(io.BytesIO(s.plot_png), format="png"))
        ax.axis("off")
    rows = s.rows()
    if rows:
        ax = fig.add_axes((0.05, 0.04, 0.9, 0.44))
        ax.axis("off")
        colours = {"OK": "#e8f5ec", "TOLERANCE": "#fff0d6", "ACTION": "#fde4e4"}
        tab = ax.table(
            cellText=[list(r) for r in rows],
            colLabels=["quantity", "axis", "value", "state"],
            cellColours=[["white", "white", colours.get(r[3], "white"), colours.get(r[3], "white")] for r in rows],
            colWidths=[0.55, 0.15, 0.15, 0.15],
            loc="upper left",
            cellLoc="left",
        )
        tab.auto_set_font_size(False)
        tab.set_fontsize(8)
    return fig


__all__ = ["StepsSummary", "collect_steps", "steps_html", "steps_figure"]
