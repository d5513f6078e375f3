"""The rooms page as one self-contained HTML file: the drift report's styles (report/html.page),
one table row per room, drift sparklines as inline SVG (no images to load, no external
resources), each room's drift report linked relatively."""

from __future__ import annotations

import math
from html import escape
from urllib.parse import quote

from vts_hw.report.html import page
from vts_hw.report.model import CameraDrift
from vts_hw.report.plots import STATE_COLOURS
from vts_hw.report.rooms import OPEN_RULE, RoomsReport, RoomStatus, days_since
from vts_hw.report.times import fmt_date, fmt_datetime

EXTRA_CSS = """
.cam { white-space: nowrap; margin: 2px 0; }
.cam b { display: inline-block; min-width: 46px; }
svg.spark { vertical-align: middle; margin: 0 4px; background: #fbfcfd; border: 1px solid #dfe3e8; border-radius: 3px; }
tr.room > td:first-child { white-space: nowrap; }
tr.room > td { padding-top: 9px; padding-bottom: 9px; }
td.open ul { margin: 0; padding-left: 16px; } td.open li { color: #c62828; }
.banner.none { border-left-color: #9aa3ad; }
.legend-x { color: #1f5fa8; font-weight: 600; } .legend-y { color: #b35900; font-weight: 600; }
"""
SPARK_W, SPARK_H = 120, 30
X_COLOUR, Y_COLOUR = "#1f5fa8", "#b35900"


def _word(state) -> str:
    s = str(state) if state else "none"
    return f'<span class="badge {escape(s)}">{escape(s)}</span>'


def sparkline_svg(
    cam: CameraDrift, tolerance: float | None = None, start: float | None = None, end: float | None = None
) -> str:
    """The drift in x and y of the camera's runs shown as two lines in a tiny SVG, the ±tolerance
    level dashed, the latest point in the colour of its state."""
    pts = [(p.t, p.value("drift_x_px"), p.value("drift_y_px")) for p in cam.points]
    if not pts:
        return ""
    t0 = start if start is not None else pts[0][0]
    t1 = end if end is not None else pts[-1][0]
    span_t = max(t1 - t0, 1.0)
    vals = [abs(v) for _, x, y in pts for v in (x, y) if math.isfinite(v)]
    top = max(vals + ([tolerance * 1.2] if tolerance else []) + [0.1])
    pad = 2.0

    def xy(t, v):
        return (pad + (t - t0) / span_t * (SPARK_W - 2 * pad), SPARK_H / 2 - v / top * (SPARK_H / 2 - pad))

    def line(i, colour):
        coords = " ".join(f"{a:.1f},{b:.1f}" for a, b in (xy(p[0], p[i]) for p in pts if math.isfinite(p[i])))
        return f'<polyline fill="none" stroke="{colour}" stroke-width="1.2" points="{coords}"/>' if coords else ""

    parts = [
        f'<line x1="0" x2="{SPARK_W}" y1="{SPARK_H / 2:.1f}" y2="{SPARK_H / 2:.1f}" stroke="#c4cad1" stroke-width="0.6"/>'
    ]
    if tolerance:
        for lv in (tolerance, -tolerance):
            y = xy(t0, lv)[1]
            parts.append(
                f'<line x1="0" x2="{SPARK_W}" y1="{y:.1f}" y2="{y:.1f}" stroke="{STATE_COLOURS["TOLERANCE"]}" '
                'stroke-width="0.8" stroke-dasharray="3,2"/>'
            )
    parts += [line(1, X_COLOUR), line(2, Y_COLOUR)]
    last = cam.points[-1]
    for i in (1, 2):
        if math.isfinite(pts[-1][i]):
            a, b = xy(pts[-1][0], pts[-1][i])
            parts.append(
                f'<circle cx="{a:.1f}" cy="{b:.1f}" r="2" fill="{STATE_COLOURS.get(str(last.state), "#5f6b7a")}"/>'
            )
    if not last.drift_measured:  # the latest run could not measure the drift: a cross, no value
        a, b = xy(pts[-1][0], 0.0)
        colour = STATE_COLOURS.get(str(last.state), "#5f6b7a")
        parts.append(
            f'<path d="M{a - 2.5:.1f},{b - 2.5:.1f}L{a + 2.5:.1f},{b + 2.5:.1f}M{a - 2.5:.1f},{b + 2.5:.1f}'
            f'L{a + 2.5:.1f},{b - 2.5:.1f}" stroke="{colour}" stroke-width="1.5"/>'
        )
    latest = (
        f"latest x {pts[-1][1]:+.2f}, y {pts[-1][2]:+.2f} px"
        if last.drift_measured
        else f"latest run {fmt_date(last.t)}: drift not measured ({', '.join(last.not_ok())})"
    )
    title = f"{cam.name}: drift x/y px over {len(pts)} runs, {fmt_date(pts[0][0])} to {fmt_date(pts[-1][0])}; {latest}"
    return (
        f'<svg class="spark" width="{SPARK_W}" height="{SPARK_H}" viewBox="0 0 {SPARK_W} {SPARK_H}" '
        f'role="img" aria-label="{escape(title)}"><title>{escape(title)}</title>{"".join(parts)}</svg>'
    )


def _cameras_cell(room: RoomStatus) -> str:
    rep = room.drift
    cams = [c for c in rep.cameras.values() if c.points]
    if not cams:
        return f'<td><span class="badge none">{escape(room.daily_missing_text())}</span></td>'
    tol = rep.window_now("x").tolerance_high
    start = min(c.points[0].t for c in cams)  # the room's first run shown: one time axis for its cameras
    out = []
    for c in cams:
        out.append(
            f'<div class="cam" data-camera="{escape(c.name)}" data-state="{escape(str(c.state))}">'
            f"<b>{escape(c.name)}</b> {_word(c.state)}{sparkline_svg(c, tol, start, rep.now)}"
            f'<span class="muted">{fmt_date(c.points[-1].t)}</span></div>'
        )
    return "<td>" + "".join(out) + "</td>"


def _last_cell(run, what: str, now: float) -> str:
    if run is None:
        return f'<td class="muted" data-last="never">no {escape(what)} recorded</td>'
    return (
        f'<td data-last="{fmt_date(run.started)}">{escape(days_since(run.started, now))}'
        f' {_word(run.status)}<div class="muted">{fmt_date(run.started)} · run {run.id}</div></td>'
    )


def _open_cell(room: RoomStatus) -> str:
    if not room.open_items:
        return '<td class="open muted" data-open="0">none</td>'
    items = "".join(f"<li>{escape(i.text())}</li>" for i in room.open_items)
    return f'<td class="open" data-open="{len(room.open_items)}"><ul>{items}</ul></td>'


def _row(room: RoomStatus, now: float) -> str:
    state = str(room.state) if room.state else "none"
    return (
        f'<tr class="room" data-rig="{escape(room.rig)}" data-state="{escape(state)}">'
        f'<td><b>{escape(room.label)}</b><div class="muted commissioned">{escape(room.commissioned_text())}</div>'
        f"</td>{_cameras_cell(room)}"
        f"{_last_cell(room.last_steps, 'step test', now)}{_last_cell(room.last_calibration, 'calibration', now)}"
        f"{_last_cell(room.last_mapping, 'SPECT mapping', now)}{_open_cell(room)}"
        f'<td><a class="drift-link" href="{escape(quote(room.drift_file))}">drift report</a></td></tr>'
    )


def render_department_html(report: RoomsReport) -> str:
    state = report.state
    n_open = sum(len(r.open_items) for r in report.rooms)
    no_daily = [r.label for r in report.rooms if not r.has_daily]
    lines = []
    if n_open:
        lines.append(f"{n_open} open ACTION item(s) in {sum(1 for r in report.rooms if r.open_items)} room(s)")
    if no_daily:
        lines.append("no daily QA in the period: " + ", ".join(no_daily))
    items = "".join(f"<li>{escape(x)}</li>" for x in lines)
    period = "all runs" if report.since is None else f"since {fmt_datetime(report.since)}"
    meta = (
        f"{len(report.rooms)} room(s) · drift {period} · generated {fmt_datetime(report.now)} · "
        f"vts-hw {escape(report.software_version)}"
    )
    rows = "".join(_row(r, report.now) for r in report.rooms)
    table = (
        (
            '<div class="scroll"><table id="rooms"><thead><tr><th>Room</th><th>Cameras: latest daily QA, drift '
            '<span class="legend-x">x</span>/<span class="legend-y">y</span></th><th>Step test</th>'
            "<th>Calibration</th><th>SPECT mapping</th><th>Open ACTION items</th><th>Details</th></tr></thead>"
            f"<tbody>{rows}</tbody></table></div>"
        )
        if rows
        else '<p class="muted">The store holds no runs yet.</p>'
    )
    overall = _word(state) if state else '<span class="badge none">no daily QA yet</span>'
    banner = (
        f'<section class="card banner {escape(str(state or "none"))}"><div class="big">Department '
        f"{overall} "
        "<span class=\"meta\">worst of every room's latest results: each camera's latest daily QA, "
        "and the latest result of every other check</span></div>"
        + (f"<ul>{items}</ul>" if items else '<p class="quiet">No open ACTION items.</p>')
        + "</section>"
    )
    foot = (
        f"<footer><p><b>Open ACTION items.</b> {escape(OPEN_RULE)}</p>"
        "<p><b>State</b> of a room: the worst of its latest results, whatever the check (each camera's "
        "latest daily QA in the period; the latest result of every step test, calibration, mapping and sync "
        "check quantity). <b>Cameras</b>: the state of each camera's latest daily (or drift) QA run in the "
        "period, over every check of it (reachable, parameters, clock, LED, drift); a camera that run could "
        "not measure (it did not answer) is ACTION, its sparkline ends in a cross; "
        "the sparkline shows its drift in x (blue) and y (orange) in px since the start of the period, "
        "the dashed lines the ±tolerance level in effect now, the dot the latest run in its state's colour. "
        "A room without daily QA shows no state, never OK. <b>Step test, calibration, SPECT mapping</b>: "
        "the latest completed run of any date (calibration: stereo or N-camera) and its state. "
        "The drift report of each room is a separate file beside this page. All times UTC.</p></footer>"
    )
    return page(
        report.title,
        str(state or "none"),
        meta,
        f'<style>{EXTRA_CSS}</style>{banner}<section class="card"><h2>Rooms</h2>{table}</section>{foot}',
        plots_expected=0,
    )


__all__ = ["render_department_html", "sparkline_svg"]
