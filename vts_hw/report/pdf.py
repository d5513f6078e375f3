"""The drift report as a PDF: a title page with the summary, then one page per camera.

Rendered in memory with matplotlib's ``PdfPages`` (A4 landscape) and written whole by the
caller; the camera pages use the same figure as the HTML report with a text header of the key
numbers. The summary table is laid out from measured text: long cells wrap, and the font
shrinks until every column fits the page.
"""

from __future__ import annotations

import datetime as _dt
import io
import textwrap

import matplotlib
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from vts_hw.report.history_view import history_figure
from vts_hw.report.model import AXES, WARMING_METRIC, CameraDrift, DriftReport
from vts_hw.report.plots import FONT, STATE_COLOURS, ZONE_COLOURS, camera_figure
from vts_hw.report.steps import steps_figure
from vts_hw.report.text import (
    camera_forecast_text,
    fmt_slope,
    forecast_detail,
    latest_text,
    led_text,
    period_text,
    trend_detail,
)
from vts_hw.report.times import fmt_date, fmt_datetime, utc
from vts_hw.report.trend import CONTROL_RUNS, TREND_RULE

A4_LANDSCAPE = (11.69, 8.27)
MARGIN = 0.05  # left and right, as a fraction of the page width
TABLE_FONTS = (8.0, 7.5, 7.0, 6.5, 6.0, 5.5)
TABLE_WRAPS = (22, 16, 11)  # characters per line a cell is wrapped at, tried in turn
CELL_PAD_PT = 4.0
HEADER_WIDTH_CHARS = 150  # monospace lines of a camera page's header
SUMMARY_COLUMNS = [
    "Camera",
    "Latest run",
    "Drift x px (mm)",
    "Drift y px (mm)",
    "State",
    "Trend x px/30 d",
    "Trend y px/30 d",
    "Action level forecast",
    "LED check",
]


def _summary_rows(report: DriftReport):
    rows, colours = [], []
    for cam in report.cameras.values():
        p = cam.latest
        nf = cam.nearest_forecast()
        rows.append(
            [
                cam.name,
                fmt_date(p.t) if p else "–",
                latest_text(cam, p, "x"),
                latest_text(cam, p, "y"),
                str(cam.state) if p else "no data",
                fmt_slope(cam.axes["x"].trend),
                fmt_slope(cam.axes["y"].trend),
                camera_forecast_text(cam)[0],
                led_text(cam),
            ]
        )

        def bg(status):
            return ZONE_COLOURS.get(status, "white") if status and status != "OK" else "white"

        st = str(cam.state)
        colours.append(
            [
                "white",
                "white",
                bg(p.status.get("drift_x_px")) if p else "white",
                bg(p.status.get("drift_y_px")) if p else "white",
                STATE_COLOURS.get(st, "white"),
                "white",
                "white",
                ZONE_COLOURS["ACTION"] if nf else "white",
                ZONE_COLOURS["ACTION"] if cam.events("led_off_visible") else "white",
            ]
        )
    return rows, colours


def _wrap(text: str, width: int) -> str:
    return "\n".join(textwrap.wrap(text, width, break_long_words=True, break_on_hyphens=False)) or text


def _text_size(fig, renderer, text: str, fontsize: float, weight="normal") -> tuple[float, float]:
    """Width and height of ``text`` in figure fractions."""
    t = fig.text(0, 0, text, fontsize=fontsize, fontweight=weight)
    bb = t.get_window_extent(renderer)
    t.remove()
    return bb.width / fig.bbox.width, bb.height / fig.bbox.height


def _layout_table(fig, renderer, header, rows, width, height):
    """Wrapped cells, font size, column widths and row heights (figure fractions).

    The largest font (and widest wrap) at which the table is at most ``width`` wide and, if
    possible, ``height`` tall; a table too tall at any font goes on over more pages."""
    pad_x = CELL_PAD_PT / 72 / fig.get_figwidth()
    pad_y = CELL_PAD_PT / 72 / fig.get_figheight()
    fitting = None
    for wrap in TABLE_WRAPS:
        cells = [[_wrap(h, min(wrap, 12)) for h in header]] + [[_wrap(c, wrap) for c in r] for r in rows]
        for fs in TABLE_FONTS:
            sizes = [
                [_text_size(fig, renderer, c, fs, "bold" if i == 0 else "normal") for c in row]
                for i, row in enumerate(cells)
            ]
            col_w = [max(sz[j][0] for sz in sizes) + 2 * pad_x for j in range(len(header))]
            row_h = [max(w_h[1] for w_h in sz) + 2 * pad_y for sz in sizes]
            layout = (cells, fs, col_w, row_h)
            if sum(col_w) <= width:
                if sum(row_h) <= height:
                    return layout
                fitting = fitting or layout
        if fitting:
            return fitting
    return layout


def _draw_rows(fig, top, cells, fs, col_w, row_h, colours, left=MARGIN) -> float:
    """Draw the header row and ``cells`` (rows), top at ``top``; returns the bottom."""
    y = top
    for i, (row, h) in enumerate(zip(cells, row_h)):
        x = left
        y -= h
        for j, (text, w) in enumerate(zip(row, col_w)):
            fc = "#eef1f5" if i == 0 else colours[i - 1][j]
            fig.add_artist(Rectangle((x, y), w, h, transform=fig.transFigure, fc=fc, ec="#dfe3e8", lw=0.6))
            bold = i == 0 or j == 4
            colour = "white" if (i > 0 and j == 4 and fc != "white") else "#1d2733"
            fig.text(
                x + w / 2,
                y + h / 2,
                text,
                fontsize=fs,
                ha="center",
                va="center",
                ma="center",
                fontweight="bold" if bold else "normal",
                color=colour,
            )
            x += w
    return y


def _page(report: DriftReport, continued: bool = False):
    """A new summary page: its figure, a renderer to measure text, and the footer's top."""
    fig = Figure(figsize=A4_LANDSCAPE)
    renderer = FigureCanvasAgg(fig).get_renderer()
    if continued:
        fig.text(MARGIN, 0.93, f"{report.title} — summary (continued)", fontsize=14, fontweight="bold")
    method = (
        f"Control limits: {report.control_method} (pending until {CONTROL_RUNS} runs). Trend: least "
        f"squares since each camera's latest baseline, ± its standard error; {TREND_RULE}. "
        "Forecast: the date the line reaches the action level now in effect. "
        "n.s.: not significant. All times UTC."
    )
    foot = fig.text(MARGIN, 0.04, textwrap.fill(method, 170), fontsize=7.5, color="#5f6b7a", va="bottom")
    return fig, renderer, _top(fig, renderer, foot)


def _top(fig, renderer, text) -> float:
    return text.get_window_extent(renderer).y1 / fig.bbox.height


def _bottom(fig, renderer, text) -> float:
    return text.get_window_extent(renderer).y0 / fig.bbox.height


def _closing_text(report: DriftReport) -> str:
    nc = report.not_completed
    listed = [
        f"  {fmt_datetime(r.started)}  {r.procedure:<15} run {r.id:<5} {r.status:<9} "
        f"{textwrap.shorten(r.notes.replace(chr(10), ' '), 90)}"
        for r in nc[:8]
    ]
    if len(nc) > 8:
        listed.append(f"  … and {len(nc) - 8} more")
    body = "Runs that did not complete: " + ("none" if not nc else "") + "".join("\n" + x for x in listed)
    bl = report.baselines
    return body + "\nBaselines set in the period: " + (", ".join(fmt_date(r.started) for r in bl) or "none")


def title_pages(report: DriftReport) -> list[Figure]:
    """Title, overall state, what needs attention, the summary table (over more pages when it
    is too long for one), the runs that did not complete and the baselines."""
    gap = 0.025
    with matplotlib.rc_context(FONT):
        fig, renderer, floor = _page(report)
        pages = [fig]
        state = str(report.state) if report.cameras else "no data"
        fig.text(MARGIN, 0.93, report.title, fontsize=20, fontweight="bold")
        fig.text(
            MARGIN,
            0.895,
            f"{period_text(report)} · generated {fmt_datetime(report.now)} · vts-hw {report.software_version}",
            fontsize=9,
            color="#5f6b7a",
        )
        fig.text(
            MARGIN,
            0.84,
            " Overall " + state + " ",
            fontsize=13,
            fontweight="bold",
            color="white",
            bbox={"boxstyle": "round,pad=0.35", "fc": STATE_COLOURS.get(state, "#9aa3ad"), "ec": "none"},
        )
        lines = report.attention()
        shown = ["• " + textwrap.fill(a, 140, subsequent_indent="  ") for a in lines[:8]]
        if len(lines) > 8:
            shown.append(f"  … and {len(lines) - 8} more (see the camera pages)")
        text = fig.text(
            MARGIN,
            0.80,
            "\n".join(shown) or "Nothing needs attention.",
            fontsize=9.5,
            va="top",
            linespacing=1.5,
            color="#1d2733" if shown else "#5f6b7a",
        )
        y = _bottom(fig, renderer, text) - gap
        closing = fig.text(
            MARGIN, 0, _closing_text(report), fontsize=8.5, va="bottom", family="monospace", linespacing=1.4
        )
        closing_h = _top(fig, renderer, closing)
        closing.remove()
        rows, colours = _summary_rows(report)
        if not rows:
            fig.text(MARGIN, y, "No completed drift runs in this period.", fontsize=11, va="top")
            y -= 0.05
        else:
            cells, fs, col_w, row_h = _layout_table(
                fig, renderer, SUMMARY_COLUMNS, rows, 1 - 2 * MARGIN, y - floor - 2 * gap - closing_h
            )
            col_w = [w + max(0.0, (1 - 2 * MARGIN - sum(col_w)) / len(col_w)) for w in col_w]
            head, body, body_h, todo = cells[0], cells[1:], row_h[1:], list(range(len(rows)))
            while todo:
                room = y - floor - gap - row_h[0]
                last = sum(body_h[i] for i in todo) <= room - gap - closing_h
                n = (
                    len(todo)
                    if last
                    else max(
                        1, next((k for k in range(len(todo), 0, -1) if sum(body_h[i] for i in todo[:k]) <= room), 1)
                    )
                )
                take, todo = todo[:n], todo[n:]
                y = (
                    _draw_rows(
                        fig,
                        y,
                        [head] + [body[i] for i in take],
                        fs,
                        col_w,
                        [row_h[0]] + [body_h[i] for i in take],
                        [colours[i] for i in take],
                    )
                    - gap
                )
                if todo:
                    fig, renderer, floor = _page(report, continued=True)
                    pages.append(fig)
                    y = 0.89
        if y - gap - closing_h < floor:
            fig, renderer, floor = _page(report, continued=True)
            pages.append(fig)
            y = 0.89
        fig.text(MARGIN, y - gap, _closing_text(report), fontsize=8.5, va="top", family="monospace", linespacing=1.4)
    return pages


def _camera_header(report: DriftReport, cam: CameraDrift) -> list[str]:
    p = cam.points[-1]  # a camera with runs shown (report_pages)
    base = fmt_date(cam.baseline_t) if cam.baseline_t else "none recorded (the trend uses every run)"
    lines = [
        f"{cam.name} — {cam.state}",
        f"latest run {fmt_datetime(p.t)} · {len(cam.points)} runs shown · baseline {base}",
    ]
    for a in AXES:
        s = cam.axes[a]
        c = s.control
        ctrl = (
            f"control {c.mean:+.3f} ± {3 * c.sd:.3f}"
            if c.mean is not None and c.sd is not None
            else f"control pending ({c.n}/{CONTROL_RUNS})"
        )
        trend = (
            f"trend {fmt_slope(s.trend)} px/30 d ({trend_detail(s.trend)})"
            if s.trend.ok
            else f"no trend yet: {trend_detail(s.trend)}"
        )
        line = (
            f"{a}: latest {latest_text(cam, p, a)} px (mm) · {ctrl} · {trend} · "
            f"action level: {forecast_detail(s.forecast)}"
        )
        lines.append(textwrap.fill(line, HEADER_WIDTH_CHARS, subsequent_indent="   "))
    lines.append(
        f"LED check: {led_text(cam)} · markers missing on {len(cam.events('markers_missing'))} run(s) · "
        f"stray blobs on {len(cam.events('stray_blobs'))} run(s)"
    )
    warm = cam.events(WARMING_METRIC)
    if warm:
        lines.append(
            textwrap.fill(
                f"Warming up: {len(warm)} run(s) taken less than the camera's warm-up time after it "
                f"started (drift may not have settled): " + ", ".join(fmt_datetime(p.t) for p in warm[-6:]),
                HEADER_WIDTH_CHARS,
                subsequent_indent="   ",
            )
        )
    return lines


def pdf_bytes(figures, metadata: dict | None = None) -> bytes:
    """Figures as the pages of one PDF, in memory."""
    buf = io.BytesIO()
    # TrueType fonts embedded (not Type 3): text that viewers and pdftotext measure truly
    with matplotlib.rc_context({"pdf.fonttype": 42}), PdfPages(buf, metadata=metadata) as pdf:
        for fig in figures:
            pdf.savefig(fig)
    return buf.getvalue()


def render_drift_pdf(report: DriftReport) -> bytes:
    """The title page and one page per camera with runs (and the step test), as PDF bytes."""
    return pdf_bytes(report_pages(report), _meta(report))


def render_drift_pdf_every_rig(reports: list[DriftReport]) -> bytes:
    """Several rigs' drift reports in one PDF, one after the other (each with its title page)."""
    first = reports[0] if reports else None
    meta = _meta(first) if first else {}
    meta["Title"] = "VTS camera drift — all rooms"
    if not reports:
        fig = Figure(figsize=A4_LANDSCAPE)
        fig.text(MARGIN, 0.9, "VTS camera drift — all rooms: the store holds no runs yet.", fontsize=14)
        return pdf_bytes([fig], meta)
    return pdf_bytes((p for r in reports for p in report_pages(r)), meta)


def _meta(report: DriftReport) -> dict:
    return {
        "Title": report.title,
        "Subject": "VTS camera drift trend",
        "Creator": f"vts-hw {report.software_version}",
        "CreationDate": utc(report.now).replace(microsecond=0) if report.now else _dt.datetime.now(_dt.UTC),
    }


def report_pages(report: DriftReport):
    """The report's pages (figures), one by one."""
    yield from title_pages(report)
    for cam in report.cameras.values():
        if cam.points:
            yield camera_figure(report, cam, figsize=A4_LANDSCAPE, header=_camera_header(report, cam))
    if report.steps is not None:
        yield steps_figure(report.steps, figsize=A4_LANDSCAPE)
    if report.history:
        yield history_figure(report.history, figsize=A4_LANDSCAPE)
