"""The rooms page as a PDF (matplotlib, A4 landscape, as report/pdf.py): one block per room
with each camera's state word on its colour and a drift sparkline, the last step test,
calibration and mapping, the open ACTION items, and the name of the room's drift report file
(a link in the PDF); the rule for open items in the footnote."""

from __future__ import annotations

import math
import textwrap

import matplotlib
from matplotlib.figure import Figure

from vts_hw.report.pdf import A4_LANDSCAPE, MARGIN, pdf_bytes
from vts_hw.report.plots import FONT, STATE_COLOURS
from vts_hw.report.rooms import OPEN_RULE, RoomsReport, days_since
from vts_hw.report.rooms_html import X_COLOUR, Y_COLOUR
from vts_hw.report.times import fmt_date, fmt_datetime, utc

NONE_COLOUR = "#9aa3ad"
COLUMNS = (
    ("Room", 0.05),
    ("Cameras: latest daily QA, drift x/y", 0.14),
    ("Step test", 0.46),
    ("Calibration", 0.56),
    ("SPECT mapping", 0.66),
    ("Open ACTION items", 0.76),
)
CAM_ROW = 0.045
FLOOR = 0.13


def _word(fig, x, y, text, state) -> None:
    fig.text(
        x,
        y,
        f" {text} ",
        fontsize=7.5,
        fontweight="bold",
        color="white",
        va="center",
        bbox={"boxstyle": "round,pad=0.25", "fc": STATE_COLOURS.get(str(state), NONE_COLOUR), "ec": "none"},
    )


def _spark(fig, x, y, cam, tol, start, end) -> None:
    ax = fig.add_axes((x, y - 0.016, 0.09, 0.032))
    ts = [p.t for p in cam.points]
    for metric, colour in (("drift_x_px", X_COLOUR), ("drift_y_px", Y_COLOUR)):
        ax.plot(ts, [p.value(metric) for p in cam.points], color=colour, lw=0.8)
    vals = [abs(p.value(m)) for p in cam.points for m in ("drift_x_px", "drift_y_px") if math.isfinite(p.value(m))]
    top = max(vals + ([tol * 1.2] if tol else []) + [0.1])
    if tol:
        for lv in (tol, -tol):
            ax.axhline(lv, color=STATE_COLOURS["TOLERANCE"], lw=0.6, ls="--")
    ax.set_xlim(start, max(end, start + 1))
    ax.set_ylim(-top, top)
    ax.set_xticks([])
    ax.set_yticks([])
    for s in ax.spines.values():
        s.set_color("#dfe3e8")


def _last(fig, x, y, run, what, now) -> None:
    if run is None:
        fig.text(x, y, f"no {what}\nrecorded", fontsize=7, color="#5f6b7a", va="top")
        return
    fig.text(x, y, days_since(run.started, now), fontsize=7.5, va="top")
    _word(fig, x, y - 0.03, run.status, run.status)
    fig.text(x, y - 0.05, f"{fmt_date(run.started)} · run {run.id}", fontsize=6.5, color="#5f6b7a", va="top")


def _new_page(report: RoomsReport, pages: list, first: bool) -> tuple[Figure, float]:
    fig = Figure(figsize=A4_LANDSCAPE)
    pages.append(fig)
    fig.text(
        MARGIN, 0.94, report.title + ("" if first else " (continued)"), fontsize=17 if first else 13, fontweight="bold"
    )
    period = "all runs" if report.since is None else f"since {fmt_datetime(report.since)}"
    fig.text(
        MARGIN,
        0.905,
        f"{len(report.rooms)} room(s) · drift {period} · generated {fmt_datetime(report.now)}"
        f" · vts-hw {report.software_version}",
        fontsize=8.5,
        color="#5f6b7a",
    )
    fig.text(
        MARGIN,
        0.03,
        textwrap.fill(
            "Open ACTION items: " + OPEN_RULE + " A room without daily QA shows no "
            "state, never OK. Sparklines: drift x (blue) and y (orange) in px, dashed "
            "the ±tolerance level now. All times UTC.",
            190,
        ),
        fontsize=6.5,
        color="#5f6b7a",
        va="bottom",
    )
    y = 0.86
    if first:
        state = report.state
        _word(fig, MARGIN, y, f"Department {state or 'no daily QA yet'}", state)
        y -= 0.05
    for label, x in COLUMNS:
        fig.text(x, y, label, fontsize=8, fontweight="bold", va="top")
    fig.text(0.90, y, "Drift report", fontsize=8, fontweight="bold", va="top")
    return fig, y - 0.035


def render_department_pdf(report: RoomsReport) -> bytes:
    pages: list[Figure] = []
    with matplotlib.rc_context(FONT):
        fig, y = _new_page(report, pages, True)
        for room in report.rooms:
            cams = [c for c in room.drift.cameras.values() if c.points]
            lines = [textwrap.fill(i.text(), 34) for i in room.open_items]
            commissioned = textwrap.fill(room.commissioned_text(), 24)
            height = (
                max(
                    len(cams) * CAM_ROW,
                    0.08,
                    0.018 * sum(t.count("\n") + 1 for t in lines),
                    0.022 + 0.0125 * (commissioned.count("\n") + 1),
                )
                + 0.015
            )
            if y - height < FLOOR:
                fig, y = _new_page(report, pages, False)
            fig.add_artist(matplotlib.lines.Line2D([MARGIN, 1 - MARGIN], [y + 0.008] * 2, color="#dfe3e8", lw=0.6))
            fig.text(COLUMNS[0][1], y, room.label, fontsize=8.5, fontweight="bold", va="top")
            fig.text(COLUMNS[0][1], y - 0.022, commissioned, fontsize=6, va="top", color="#5f6b7a")
            if not cams:
                _word(fig, COLUMNS[1][1], y - 0.012, room.daily_missing_text(), None)
            tol = room.drift.window_now("x").tolerance_high
            start = min((c.points[0].t for c in cams), default=report.now)
            for k, c in enumerate(cams):
                cy = y - 0.012 - k * CAM_ROW
                fig.text(COLUMNS[1][1], cy, c.name, fontsize=7.5, va="center", fontweight="bold")
                _word(fig, COLUMNS[1][1] + 0.045, cy, c.state, c.state)
                _spark(fig, COLUMNS[1][1] + 0.12, cy, c, tol, start, report.now)
                fig.text(COLUMNS[1][1] + 0.22, cy, fmt_date(c.points[-1].t), fontsize=6.5, color="#5f6b7a", va="center")
            _last(fig, COLUMNS[2][1], y, room.last_steps, "step test", report.now)
            _last(fig, COLUMNS[3][1], y, room.last_calibration, "calibration", report.now)
            _last(fig, COLUMNS[4][1], y, room.last_mapping, "SPECT mapping", report.now)
            fig.text(
                COLUMNS[5][1],
                y,
                "\n".join(lines) or "none",
                fontsize=6.5,
                va="top",
                color=STATE_COLOURS["ACTION"] if lines else "#5f6b7a",
            )
            link = fig.text(
                0.90,
                y,
                "\n".join(textwrap.wrap(room.drift_file, 22, break_long_words=True)),
                fontsize=6,
                va="top",
                color="#1f5fa8",
            )
            link.set_url(room.drift_file)
            y -= height
        if not report.rooms:
            fig.text(MARGIN, y, "The store holds no runs yet.", fontsize=11, va="top")
    meta = {
        "Title": report.title,
        "Subject": "VTS rooms overview",
        "Creator": f"vts-hw {report.software_version}",
        "CreationDate": utc(report.now).replace(microsecond=0),
    }
    return pdf_bytes(pages, meta)


__all__ = ["render_department_pdf"]
