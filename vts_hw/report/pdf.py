"""The drift report as a PDF: a title page with the summary, then one page per camera.

Written with matplotlib's ``PdfPages`` (A4 landscape); the camera pages use the same figure as
the HTML report with a text header of the key numbers.
"""

from __future__ import annotations

import datetime as _dt
import textwrap
from pathlib import Path

import matplotlib
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure

from .model import AXES, CameraDrift, DriftReport
from .plots import FONT, STATE_COLOURS, ZONE_COLOURS, camera_figure
from .text import camera_forecast_text, fmt_slope, forecast_text, latest_text, led_text, period_text
from .times import fmt_date, fmt_datetime, utc
from .trend import CONTROL_RUNS

A4_LANDSCAPE = (11.69, 8.27)


def _summary_rows(report: DriftReport):
    rows, colours = [], []
    for cam in report.cameras.values():
        p = cam.latest
        nf = cam.nearest_forecast()
        rows.append([cam.name, fmt_date(p.t) if p else "–", latest_text(cam, p, "x"), latest_text(cam, p, "y"),
                     str(cam.state) if p else "no data", fmt_slope(cam.axes["x"].trend),
                     fmt_slope(cam.axes["y"].trend),
                     camera_forecast_text(cam)[0], led_text(cam)])
        def bg(status):
            return ZONE_COLOURS.get(status, "white") if status and status != "OK" else "white"
        st = str(cam.state)
        colours.append(["white", "white", bg(p.status.get("drift_x_px")) if p else "white",
                        bg(p.status.get("drift_y_px")) if p else "white", STATE_COLOURS.get(st, "white"),
                        "white", "white", ZONE_COLOURS["ACTION"] if nf else "white",
                        ZONE_COLOURS["ACTION"] if cam.events("led_off_visible") else "white"])
    return rows, colours


def title_page(report: DriftReport) -> Figure:
    """Title, overall state, what needs attention, the summary table, runs that did not complete."""
    with matplotlib.rc_context(FONT):
        fig = Figure(figsize=A4_LANDSCAPE)
        state = str(report.state) if report.cameras else "no data"
        fig.text(0.05, 0.93, report.title, fontsize=20, fontweight="bold")
        fig.text(0.05, 0.895, f"{period_text(report)} · generated {fmt_datetime(report.now)} · "
                              f"vts-hw {report.software_version}", fontsize=9, color="#5f6b7a")
        fig.text(0.05, 0.84, " Overall " + state + " ", fontsize=13, fontweight="bold", color="white",
                 bbox={"boxstyle": "round,pad=0.35", "fc": STATE_COLOURS.get(state, "#9aa3ad"), "ec": "none"})
        lines = report.attention() or ["Nothing needs attention."]
        fig.text(0.05, 0.80, "\n".join("• " + a for a in lines[:8]), fontsize=9.5, va="top", linespacing=1.5)
        y_table = 0.80 - 0.03 * min(len(lines), 8) - 0.04
        rows, colours = _summary_rows(report)
        if rows:
            ax = fig.add_axes((0.05, max(y_table - 0.05 * (len(rows) + 1), 0.3), 0.9, 0.05 * (len(rows) + 1)))
            ax.axis("off")
            cols = ["Camera", "Latest run", "Drift x px (mm)", "Drift y px (mm)", "State",
                    "Trend x px/30 d", "Trend y px/30 d", "Action level forecast", "LED check"]
            widths = [0.06, 0.085, 0.1, 0.1, 0.085, 0.115, 0.115, 0.12, 0.22]
            tab = ax.table(cellText=rows, cellColours=colours, colLabels=cols, loc="upper left",
                           cellLoc="center", colColours=["#eef1f5"] * len(cols), colWidths=widths)
            tab.auto_set_font_size(False)
            tab.set_fontsize(8)
            tab.scale(1, 1.5)
            for (r, c), cell in tab.get_celld().items():
                cell.set_edgecolor("#dfe3e8")
                if r > 0 and c == 4:
                    cell.get_text().set_color("white")
                    cell.get_text().set_fontweight("bold")
            y_next = max(y_table - 0.05 * (len(rows) + 1), 0.3) - 0.05
        else:
            fig.text(0.05, y_table, "No completed drift runs in this period.", fontsize=11)
            y_next = y_table - 0.06
        nc = report.not_completed
        text = ("Runs that did not complete: " + ("none" if not nc else "") + "\n"
                + "\n".join(f"  {fmt_datetime(r.started)}  {r.procedure:<15} run {r.id:<5} {r.status:<9} "
                            f"{textwrap.shorten(r.notes.replace(chr(10), ' '), 70)}"
                            for r in nc[:8]) + (f"\n  … and {len(nc) - 8} more" if len(nc) > 8 else ""))
        bl = report.baselines
        text += "\nBaselines set in the period: " + (", ".join(fmt_date(r.started) for r in bl) or "none")
        fig.text(0.05, y_next, text, fontsize=8.5, va="top", family="monospace", linespacing=1.4)
        method = (f"Control limits: {report.control_method} (pending until {CONTROL_RUNS} runs). Trend: least "
                  "squares since each camera's latest baseline; forecast: the date the line reaches the action "
                  "level now in effect, 'not within a year' beyond 365 days or when the trend runs away from the "
                  "limit. n.s.: slope smaller than twice its standard error. All times UTC.")
        fig.text(0.05, 0.04, textwrap.fill(method, 160), fontsize=7.5, color="#5f6b7a", va="bottom")
    return fig


def _camera_header(report: DriftReport, cam: CameraDrift) -> list[str]:
    p = cam.latest
    lines = [f"{cam.name} — {cam.state}",
             f"latest run {fmt_datetime(p.t)} · {len(cam.points)} runs shown · baseline "
             f"{fmt_date(cam.baseline_t) if cam.baseline_t else 'none recorded'}"]
    for a in AXES:
        s = cam.axes[a]
        c = s.control
        ctrl = (f"control {c.mean:+.3f} ± {3 * c.sd:.3f}" if not c.pending else f"control pending ({c.n}/{CONTROL_RUNS})")
        lines.append(f"{a}: latest {latest_text(cam, p, a):<15} px (mm)   trend {fmt_slope(s.trend):<20} px/30 d   "
                     f"{ctrl:<24}   action level: {forecast_text(s.forecast)}")
    lines.append(f"LED check: {led_text(cam)}   markers missing on {len(cam.events('markers_missing'))} run(s)   "
                 f"stray blobs on {len(cam.events('stray_blobs'))} run(s)")
    return lines


def write_pdf(report: DriftReport, out: Path) -> None:
    """Write the title page and one page per camera with runs."""
    meta = {"Title": report.title, "Subject": "VTS camera drift trend", "Creator": f"vts-hw {report.software_version}",
            "CreationDate": utc(report.now).replace(microsecond=0) if report.now else _dt.datetime.now(_dt.timezone.utc)}
    with PdfPages(out, metadata=meta) as pdf:
        pdf.savefig(title_page(report))
        for cam in report.cameras.values():
            if cam.points:
                pdf.savefig(camera_figure(report, cam, figsize=A4_LANDSCAPE, header=_camera_header(report, cam)))
        if report.steps is not None:
            from .steps import steps_figure
            pdf.savefig(steps_figure(report.steps, figsize=A4_LANDSCAPE))
