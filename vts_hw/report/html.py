"""The drift report as one self-contained HTML file.

Plots are inline PNG (``data:`` URIs), the CSS and the one small script are inline: the file
opens from a USB stick or an e-mail attachment with no network. The script counts the plots
that decoded (``naturalWidth > 0``) and sets ``document.body.dataset.plotsLoaded``; the body's
``data-plots-expected`` says how many there should be (the browser test compares the two).
"""

from __future__ import annotations

import base64
from html import escape

from vts_hw.figures import figure_png
from vts_hw.report.history_view import history_html
from vts_hw.report.model import AXES, WARMING_METRIC, CameraDrift, DriftReport, RunPoint
from vts_hw.report.plots import STATE_COLOURS, camera_figure
from vts_hw.report.steps import steps_html
from vts_hw.report.text import (
    camera_forecast_text,
    fmt_num,
    fmt_slope,
    forecast_detail,
    latest_text,
    led_text,
    period_text,
    trend_detail,
)
from vts_hw.report.times import fmt_date, fmt_datetime
from vts_hw.report.trend import CONTROL_RUNS, HORIZON_DAYS, MIN_TREND_DAYS, MIN_TREND_RUNS, SIGNIFICANCE
from vts_hw.tolerance import worst

# the page's CSS, its state colours filled in by %: str.format would need each of its braces doubled
_CSS_TEMPLATE = """
:root { --ok: %(OK)s; --tol: %(TOLERANCE)s; --act: %(ACTION)s; --ink: #1d2733; --muted: #5f6b7a;
        --line: #dfe3e8; --bg: #f5f7fa; }
* { box-sizing: border-box; }
body { margin: 0; background: var(--bg); color: var(--ink);
       font: 14px/1.45 "Segoe UI", "Helvetica Neue", Arial, "DejaVu Sans", sans-serif; }
main { max-width: 1120px; margin: 0 auto; padding: 24px 28px 40px; }
header h1 { margin: 0 0 4px; font-size: 24px; font-weight: 650; }
.meta { color: var(--muted); font-size: 13px; }
h2 { font-size: 18px; margin: 0 0 10px; }
h3 { font-size: 14px; margin: 16px 0 6px; color: var(--muted); text-transform: uppercase; letter-spacing: .04em; }
section.card { background: #fff; border: 1px solid var(--line); border-radius: 8px; padding: 18px 20px; margin: 18px 0; }
.banner { border-left: 8px solid var(--ok); }
.banner.TOLERANCE { border-left-color: var(--tol); } .banner.ACTION { border-left-color: var(--act); }
.banner .big { font-size: 20px; font-weight: 650; }
.banner ul { margin: 8px 0 0; padding-left: 20px; }
.banner p.quiet { margin: 8px 0 0; color: var(--muted); }
.badge { display: inline-block; padding: 1px 9px; border-radius: 10px; color: #fff; font-weight: 600;
         font-size: 12px; letter-spacing: .03em; vertical-align: middle; }
.badge.OK { background: var(--ok); } .badge.TOLERANCE { background: var(--tol); } .badge.ACTION { background: var(--act); }
.badge.none { background: #9aa3ad; }
table { border-collapse: collapse; width: 100%%; font-size: 13px; }
th, td { padding: 5px 7px; border-bottom: 1px solid var(--line); text-align: left; vertical-align: top; }
th { background: #eef1f5; font-weight: 600; }
.scroll { overflow-x: auto; }
td.num, th.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
td.s-TOLERANCE { background: #fff0d6; } td.s-ACTION { background: #fde4e4; font-weight: 600; }
.soon { color: var(--act); font-weight: 600; }
.ns { color: var(--muted); font-size: 11px; }
.muted { color: var(--muted); }
.cards { display: grid; grid-template-columns: repeat(auto-fit, minmax(160px, 1fr)); gap: 10px; margin: 6px 0 12px; }
.kpi { border: 1px solid var(--line); border-radius: 6px; padding: 8px 10px; background: #fbfcfd; }
.kpi .k { font-size: 11px; color: var(--muted); text-transform: uppercase; letter-spacing: .04em; }
.kpi .v { font-size: 16px; font-weight: 600; font-variant-numeric: tabular-nums; }
.kpi .u { font-size: 12px; color: var(--muted); }
img.plot { width: 100%%; height: auto; display: block; border: 1px solid var(--line); border-radius: 4px; }
details { margin-top: 10px; } summary { cursor: pointer; color: var(--muted); }
footer { color: var(--muted); font-size: 12px; margin-top: 24px; }
@media print { body { background: #fff; } section.card { break-inside: avoid; border: none; } details { display: none; } }
"""
CSS = _CSS_TEMPLATE % STATE_COLOURS

SCRIPT = """
window.addEventListener('load', function () {
  var n = 0;
  document.querySelectorAll('img.plot').forEach(function (img) {
    if (img.complete && img.naturalWidth > 0) { n += 1; }
  });
  document.body.dataset.plotsLoaded = String(n);
});
"""


def badge(state) -> str:
    """A state as a coloured badge (its words are its classes: ``NOT RUN`` is styled by ``.NOT``);
    no state: "no data"."""
    s = str(state) if state else "none"
    return f'<span class="badge {escape(s)}">{escape(s if state else "no data")}</span>'


_badge = badge


def table(head: list[str], rows: list[str], empty: str) -> str:
    """A report's table: ``head`` the column titles (text), ``rows`` whole ``<tr>`` rows (HTML);
    with no row, ``empty`` in muted words instead."""
    if not rows:
        return f'<p class="muted">{escape(empty)}</p>'
    th = "".join(f"<th>{escape(h)}</th>" for h in head)
    return f'<div class="scroll"><table><thead><tr>{th}</tr></thead><tbody>{"".join(rows)}</tbody></table></div>'


def _cell(text, status=None, num=True) -> str:
    cls = " ".join(c for c in ("num" if num else "", f"s-{status}" if status and status != "OK" else "") if c)
    return f'<td class="{cls}">{text}</td>' if cls else f"<td>{text}</td>"


def _drift_cell(cam: CameraDrift, p: RunPoint | None, axis: str) -> str:
    if p is None:
        return _cell("–")
    return _cell(escape(latest_text(cam, p, axis)), p.status.get(f"drift_{axis}_px"))


def _forecast_cell(cam: CameraDrift) -> str:
    text, soon = camera_forecast_text(cam)
    return _cell(f'<span class="{"soon" if soon else "muted"}">{escape(text)}</span>', num=False)


def _summary(report: DriftReport, prefix: str = "") -> str:
    rows = []
    for cam in report.cameras.values():
        p = cam.latest
        rows.append(
            "<tr>"
            f'<td><a href="#{escape(prefix)}cam-{escape(cam.name)}"><b>{escape(cam.name)}</b></a></td>'
            f"{_cell(fmt_date(p.t) if p else '–')}"
            f"{_drift_cell(cam, p, 'x')}{_drift_cell(cam, p, 'y')}"
            f"<td>{_badge(cam.state if p else None)}</td>"
            f"{_cell(fmt_slope(cam.axes['x'].trend, html=True))}{_cell(fmt_slope(cam.axes['y'].trend, html=True))}"
            f"{_forecast_cell(cam)}"
            f"{_cell(escape(led_text(cam)), 'ACTION' if cam.events('led_off_visible') else None, num=False)}"
            "</tr>"
        )
    if not rows:
        return '<p class="muted">No completed drift runs in this period.</p>'
    return (
        '<div class="scroll"><table><thead><tr><th>Camera</th><th class=num>Latest run</th>'
        "<th class=num>Drift x px (mm)</th><th class=num>Drift y px (mm)</th><th>State</th>"
        "<th class=num>Trend x px/30 d</th><th class=num>Trend y px/30 d</th>"
        "<th>Action level forecast</th><th>LED check</th></tr></thead><tbody>"
        + "".join(rows)
        + "</tbody></table></div>"
    )


def kpi(label, value, unit="") -> str:
    """One figure of a report's summary cards (``value`` is HTML already)."""
    return (
        f'<div class="kpi"><div class="k">{escape(label)}</div><div class="v">{value}'
        f' <span class="u">{escape(unit)}</span></div></div>'
    )


_kpi = kpi


def page(title: str, state: str, meta_html: str, body_html: str, plots_expected: int = 1) -> str:
    """A whole self-contained report page: the shared styles and script, a header with
    ``title`` and the ``meta_html`` line, then ``body_html`` (the cards). ``state`` goes into
    ``data-state`` (what the browser tests and a script read), ``plots_expected`` into
    ``data-plots-expected`` (the script flags a plot that did not load)."""
    return f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{escape(title)}</title>
<style>{CSS}</style>
</head>
<body data-plots-expected="{plots_expected}" data-state="{escape(state)}">
<main>
<header><h1>{escape(title)}</h1>
<div class="meta">{meta_html}</div>
</header>
{body_html}
</main>
<script>{SCRIPT}</script>
</body></html>
"""


def _axis_table(report: DriftReport, cam: CameraDrift) -> str:
    rows = []
    for a in AXES:
        s = cam.axes[a]
        c = s.control
        ctrl = (
            f"{c.mean:+.3f} ± {3 * c.sd:.3f} ({fmt_num(c.lower, '+.3f')} … {fmt_num(c.upper, '+.3f')})"
            if c.mean is not None and c.sd is not None
            else f"pending ({c.n}/{CONTROL_RUNS} runs)"
        )
        w = report.window_now(a)
        fit = trend_detail(s.trend)
        action = fmt_num(w.action_low, "+g") + " / " + fmt_num(w.action_high, "+g")
        soon = ' class="soon"' if s.forecast.within_year else ""
        rows.append(
            f"<tr><td><b>{a}</b></td>{_cell(escape(ctrl))}{_cell(fmt_slope(s.trend, html=True))}"
            f"<td>{escape(fit)}</td>{_cell(action)}<td{soon}>{escape(forecast_detail(s.forecast))}</td></tr>"
        )
    return (
        "<table><thead><tr><th>Axis</th><th class=num>Control limits px (mean ± 3 SD)</th>"
        "<th class=num>Trend px/30 d</th><th>Fit</th><th class=num>Action level now px</th>"
        "<th>Reaches action level</th></tr></thead><tbody>" + "".join(rows) + "</tbody></table>"
    )


def _checks(report: DriftReport, cam: CameraDrift) -> str:
    items = []
    for metric, what in (
        ("led_off_visible", "LED check failed (markers visible with the LED off)"),
        ("markers_missing", "baseline markers missing"),
        ("stray_blobs", "stray blobs"),
    ):
        ev = cam.events(metric)
        if ev:
            when = ", ".join(f"{fmt_date(p.t)} ({p.values[metric]:g})" for p in ev[-12:])
            more = f" and {len(ev) - 12} earlier" if len(ev) > 12 else ""
            items.append(f"<li><b>{escape(what)}</b>: {len(ev)} run(s) — {escape(when + more)}</li>")
    warm = cam.events(WARMING_METRIC)
    if warm:
        when = ", ".join(fmt_datetime(p.t) for p in warm[-12:]) + (
            f" and {len(warm) - 12} earlier" if len(warm) > 12 else ""
        )
        items.append(
            f"<li><b>camera warming up</b>: {len(warm)} run(s) taken less than its warm-up time after the "
            f"camera started; their drift may not have settled (marked in the runs below) — {escape(when)}</li>"
        )
    if not items:
        return '<p class="muted">LED, missing-marker and stray-blob checks passed on every run shown.</p>'
    return "<ul>" + "".join(items) + "</ul>"


_RUN_COLS = (
    ("drift_x_px", "x px", ".3f"),
    ("drift_y_px", "y px", ".3f"),
    ("drift_x_mm", "x mm", ".2f"),
    ("drift_y_mm", "y mm", ".2f"),
    ("drift_sd_px", "SD px", ".3f"),
    ("markers_missing", "missing", "g"),
    ("stray_blobs", "stray", "g"),
    ("led_off_visible", "LED off seen", "g"),
    ("clock_offset_s", "clock s", "+.2f"),
    ("params_changed", "params", "g"),
    ("camera_reachable", "answered", "g"),
    ("uptime_min", "up min", ".0f"),
)


WARMING_MARK = (
    ' <span class="meta" title="taken less than the camera\'s warm-up time after it started: its drift '
    'may not have settled">warming up</span>'
)


def _runs_table(cam: CameraDrift) -> str:
    cols = [c for c in _RUN_COLS if any(c[0] in p.values for p in cam.points)]
    head = "".join(f"<th class=num>{escape(label)}</th>" for _, label, _ in cols)
    rows = []
    for p in reversed(cam.points):
        cells = "".join(_cell(fmt_num(p.values.get(m), f), p.status.get(m)) for m, _, f in cols)
        rows.append(
            f"<tr><td>{fmt_datetime(p.t)}</td><td>{escape(p.procedure)}</td><td>{p.run_id}</td>"
            f"<td>{_badge(p.state)}{WARMING_MARK if p.warming_up else ''}</td>{cells}</tr>"
        )
    return (
        f"<details><summary>All {len(cam.points)} runs shown (newest first)</summary><div class=scroll><table><thead><tr>"
        f"<th>Started</th><th>Procedure</th><th>Run</th><th>State</th>{head}</tr></thead><tbody>"
        + "".join(rows)
        + "</tbody></table></div></details>"
    )


def _markers_table(cam: CameraDrift) -> str:
    if not cam.markers:
        return ""
    metrics = sorted({m for d in cam.markers.values() for m in d})
    head = "".join(f"<th class=num>{escape(m)}</th>" for m in metrics)
    rows = "".join(
        f"<tr><td>{escape(name)}</td>" + "".join(_cell(fmt_num(d.get(m), ".3f")) for m in metrics) + "</tr>"
        for name, d in cam.markers.items()
    )
    return (
        f"<details><summary>Per-marker values of the latest run ({len(cam.markers)} markers)</summary>"
        f"<table><thead><tr><th>Marker</th>{head}</tr></thead><tbody>{rows}</tbody></table></details>"
    )


def _camera_section(report: DriftReport, cam: CameraDrift, prefix: str = "") -> str:
    p = cam.points[-1]  # a camera with runs shown (the page's sections)
    png = base64.b64encode(figure_png(camera_figure(report, cam))).decode("ascii")
    kpis = "".join(
        (
            _kpi("latest drift x", escape(latest_text(cam, p, "x")), "px (mm)"),
            _kpi("latest drift y", escape(latest_text(cam, p, "y")), "px (mm)"),
            _kpi("trend x", fmt_slope(cam.axes["x"].trend, html=True), "px / 30 d"),
            _kpi("trend y", fmt_slope(cam.axes["y"].trend, html=True), "px / 30 d"),
            _kpi("action level", escape(camera_forecast_text(cam)[0])),
            _kpi("baseline", fmt_date(cam.baseline_t) if cam.baseline_t else "none recorded"),
        )
    )
    return (
        f'<section class="card" id="{escape(prefix)}cam-{escape(cam.name)}"><h2>{escape(cam.name)} {_badge(cam.state)}'
        f' <span class="meta">latest run {fmt_datetime(p.t)} · {len(cam.points)} runs shown</span></h2>'
        f'<div class="cards">{kpis}</div>'
        f'<img class="plot" alt="{escape(cam.name)}: drift in x and y over time with tolerance and action '
        f'bands, control limits, trend and forecast; LED and marker checks" src="data:image/png;base64,{png}">'
        f"<h3>Control limits, trend and forecast</h3>{_axis_table(report, cam)}"
        f"<h3>Checks</h3>{_checks(report, cam)}{_runs_table(cam)}{_markers_table(cam)}</section>"
    )


def _run_list(runs, empty: str) -> str:
    if not runs:
        return f'<p class="muted">{escape(empty)}</p>'
    rows = "".join(
        f"<tr><td>{fmt_datetime(r.started)}</td><td>{escape(r.procedure)}</td><td>{r.id}</td>"
        f"<td>{escape(r.status)}</td><td>{escape(r.operator)}</td><td>{escape(r.notes)}</td></tr>"
        for r in runs
    )
    return (
        "<table><thead><tr><th>Started</th><th>Procedure</th><th>Run</th><th>Status</th><th>Operator</th>"
        f"<th>Notes</th></tr></thead><tbody>{rows}</tbody></table>"
    )


def _windows_table(report: DriftReport) -> str:
    rows = []
    for a in AXES:
        for i, seg in enumerate(report.bands[a]):
            w = seg.window
            src = "built-in default" if seg.window_id is None else f"store window {seg.window_id}"
            start = "start of the period" if i == 0 else fmt_datetime(seg.start)
            rows.append(
                f"<tr><td>drift_{a}_px</td><td>{start}</td>"
                + "".join(
                    _cell(fmt_num(v, "+g")) for v in (w.action_low, w.tolerance_low, w.tolerance_high, w.action_high)
                )
                + f"<td>{src}</td></tr>"
            )
    return (
        "<table><thead><tr><th>Metric</th><th>In effect from</th><th class=num>Action low</th>"
        "<th class=num>Tolerance low</th><th class=num>Tolerance high</th><th class=num>Action high</th>"
        "<th>Source</th></tr></thead><tbody>" + "".join(rows) + "</tbody></table>"
    )


def _method(report: DriftReport) -> str:
    return (
        "<ul>"
        "<li><b>Drift</b>: mean displacement of the wall markers from the baseline, per camera and axis, "
        "from completed <code>drift</code> and <code>daily</code> runs; points coloured by the state the QA "
        "gave them.</li>"
        f"<li><b>Control limits</b>: {escape(report.control_method)} (pending until there are "
        f"{CONTROL_RUNS}). Points outside them show that the camera has moved since the baseline period "
        "even while inside tolerance.</li>"
        "<li><b>Trend</b>: least-squares line through every run since the camera's latest baseline "
        f"(also before the report period), once there are at least {MIN_TREND_RUNS} runs spanning "
        f"{MIN_TREND_DAYS:g} days (runs minutes apart say nothing about a drift over months); slope per "
        "30 days ± its standard error, with its 95 % confidence interval and p-value "
        f"(<span class=ns>n.s.</span>: not significant, p ≥ {SIGNIFICANCE:g}).</li>"
        "<li><b>Forecast</b>: only for a significant slope, the date the trend line reaches the action "
        "level in the direction of its slope, with the window in effect now; <i>not within a year</i> "
        f"when that is more than {HORIZON_DAYS:g} days ahead. Without a date the table says why.</li>"
        "<li><b>Bands</b>: the <code>drift_x_px</code>/<code>drift_y_px</code> windows recorded in the "
        "results store, as a step function of the date each took effect.</li>"
        "<li><b>Baselines</b> (dashed vertical lines) reset the drift to zero for the cameras they "
        "measured (all cameras when they hold no measurements).</li>"
        "</ul>"
    )


def render_drift_html(report: DriftReport) -> str:
    """The report as an HTML string."""
    state = report.state if report.cameras else None
    meta = f"{escape(period_text(report))} · generated {fmt_datetime(report.now)} · vts-hw {escape(report.software_version)}"
    return page(report.title, str(state or "none"), meta, report_body(report), plots_expected=report.plot_count)


def render_drift_html_every_rig(reports: list[DriftReport], title: str = "VTS camera drift — all rooms") -> str:
    """Several rigs' drift reports on one page: a list of the rooms, then each room's report
    (its own banner, cameras, step test and history: numbers never mixed between rooms)."""
    states = [r.state for r in reports if r.cameras]
    state = worst(states) if states else None
    links = "".join(
        f'<li><a href="#room-{i}">{escape(r.rig or "(no rig name)")}</a> {_badge(r.state if r.cameras else None)}</li>'
        for i, r in enumerate(reports)
    )
    body = (
        f'<section class="card"><h2>Rooms</h2><ul id="rooms">{links}</ul><p class="muted">Each room below is '
        "its own report: cam1 of one room is not cam1 of another.</p></section>"
        + "".join(
            f'<section class="card room-head" id="room-{i}"><h2>{escape(r.title)}</h2></section>'
            + report_body(r, prefix=f"room-{i}-")
            for i, r in enumerate(reports)
        )
    )
    meta = (
        f"{len(reports)} room(s) · {escape(period_text(reports[0]))} · generated {fmt_datetime(reports[0].now)} · "
        f"vts-hw {escape(reports[0].software_version)}"
        if reports
        else "no runs in the store"
    )
    return page(title, str(state or "none"), meta, body, plots_expected=sum(r.plot_count for r in reports))


def report_body(report: DriftReport, prefix: str = "") -> str:
    """The report's cards (``prefix`` makes the anchors unique when several share a page)."""
    state = report.state if report.cameras else None
    attention = report.attention()
    items = (
        f"<ul>{''.join(f'<li>{escape(a)}</li>' for a in attention)}</ul>"
        if attention
        else '<p class="quiet">Nothing needs attention.</p>'
    )
    cams = "".join(_camera_section(report, c, prefix) for c in report.cameras.values() if c.points)
    steps = steps_html(report.steps) if report.steps is not None else ""
    steps += history_html(report.history)
    return f"""<section class="card banner {escape(str(state or "OK"))}">
<div class="big">Overall {_badge(state)} <span class="meta">worst state of each camera's latest run</span></div>
{items}
</section>
<section class="card"><h2>Summary</h2>{_summary(report, prefix)}</section>
{cams}
{steps}
<section class="card"><h2>Runs that did not complete</h2>{_run_list(report.not_completed, "None in this period.")}</section>
<section class="card"><h2>Baselines</h2>{_run_list(report.baselines, "No baseline set in this period.")}</section>
<section class="card"><h2>Tolerance windows</h2>{_windows_table(report)}</section>
<section class="card"><h2>Method</h2>{_method(report)}</section>
<footer>All times UTC. Drift in pixels of the camera image; mm at the wall from the QA's own conversion.</footer>"""
