"""Matplotlib figures of the drift report: one figure per camera.

Each figure has three panels on one time axis: drift in x, drift in y (px on the left, mm at
the wall on the right), and a strip of the checks (LED, missing markers, stray blobs, runs that
did not complete). The drift panels show the tolerance/action bands as a step function of the
window in effect, the control limits, the baselines and the trend line extended to the
forecast. Figures are built on ``matplotlib.figure.Figure`` (no pyplot: no global state, safe
in a server or a test run).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib import dates as mdates
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.typing import RcKeyType

from vts_hw.report.model import CameraDrift, DriftReport
from vts_hw.report.times import fmt_date, utc
from vts_hw.report.trend import CONTROL_K, CONTROL_RUNS, DAY, MIN_TREND_DAYS, MIN_TREND_RUNS

MIN_SPAN_S = 3600.0  # the narrowest time axis: an hour

STATE_COLOURS = {"OK": "#2e7d32", "TOLERANCE": "#e08a00", "ACTION": "#c62828"}
ZONE_COLOURS = {"OK": "#e6f4e7", "TOLERANCE": "#fff0d6", "ACTION": "#fde4e4"}
CONTROL_COLOUR = "#1f5fa8"
TREND_COLOUR = "#5b2a86"
BASELINE_COLOUR = "#6b6b6b"
FONT: dict[RcKeyType, Any] = {
    "font.size": 9,
    "axes.titlesize": 10,
    "axes.labelsize": 9,
    "legend.fontsize": 8,
    "xtick.labelsize": 8,
    "ytick.labelsize": 8,
}


def _d(t):
    """Epoch seconds (scalar or array) to matplotlib date numbers."""
    return mdates.date2num(utc(t)) if np.isscalar(t) else np.array([mdates.date2num(utc(x)) for x in t])


def time_range(report: DriftReport, cam: CameraDrift) -> tuple[float, float]:
    """The plotted time range: the runs, baselines and incomplete runs shown, up to the report
    date, plus room on the right for a forecast date that is near.

    Scaled to the data, not to the period asked for: three runs of this morning in a 60-day
    period are drawn over hours, not squeezed into one pixel column.
    """
    ts = [float(x) for x in cam.times()] + list(cam.baselines)
    ts += [r.started for r in report.not_completed]
    start = min(ts) if ts else (report.period_start if report.period_start is not None else report.now - DAY)
    end = max([report.now, *ts])
    span = max(end - start, MIN_SPAN_S)
    ext = 0.03 * span
    nf = cam.nearest_forecast()
    crossing = nf[1].t if nf and nf[1].status == "date" else None
    if crossing is not None and crossing - end <= max(span, 60 * DAY):
        ext = max(ext, crossing - end + 0.05 * span)
    return start - 0.03 * span, end + ext


def _ylim(report, cam, axis, t0, t1):
    """The drift axis: the runs, the tolerance and action levels in effect over the plotted
    time, and the control limits, with a margin; never a trend line's extrapolation."""
    vals = [v for v in cam.series(f"drift_{axis}_px") if np.isfinite(v)]
    for seg in report.bands[axis]:
        if seg.end < t0 or seg.start > t1:
            continue
        w = seg.window
        vals += [v for v in (w.action_low, w.action_high, w.tolerance_low, w.tolerance_high) if v is not None]
    s = cam.axes[axis]
    if not s.control.pending:
        vals += [s.control.lower, s.control.upper]
    lo, hi = (min(vals), max(vals)) if vals else (-1.0, 1.0)
    pad = 0.08 * max(hi - lo, 0.5)
    return lo - pad, hi + pad


def _bands(ax, report, axis, t1, ylo, yhi):
    """Shade OK/TOLERANCE/ACTION zones and draw the limits, one step per window in effect."""
    segs = report.bands[axis]
    for i, seg in enumerate(segs):
        a = seg.start
        b = t1 if i == len(segs) - 1 else seg.end
        if b <= a:
            continue
        w = seg.window
        alo = ylo if w.action_low is None else w.action_low
        ahi = yhi if w.action_high is None else w.action_high
        tlo = alo if w.tolerance_low is None else w.tolerance_low
        thi = ahi if w.tolerance_high is None else w.tolerance_high
        x = [_d(a), _d(b)]
        for lo, hi, zone in (
            (ylo, alo, "ACTION"),
            (alo, tlo, "TOLERANCE"),
            (tlo, thi, "OK"),
            (thi, ahi, "TOLERANCE"),
            (ahi, yhi, "ACTION"),
        ):
            if hi > lo:
                ax.fill_between(x, lo, hi, color=ZONE_COLOURS[zone], lw=0, zorder=0)
    xs = [_d(s.start) for s in segs] + [_d(t1)]
    for attr, colour, style in (
        ("tolerance_low", STATE_COLOURS["TOLERANCE"], (0, (4, 2))),
        ("tolerance_high", STATE_COLOURS["TOLERANCE"], (0, (4, 2))),
        ("action_low", STATE_COLOURS["ACTION"], "-"),
        ("action_high", STATE_COLOURS["ACTION"], "-"),
    ):
        ys = [getattr(s.window, attr) for s in segs]
        ys = [np.nan if y is None else y for y in ys]
        ax.step(xs, ys + [ys[-1]], where="post", color=colour, lw=1.1, ls=style, zorder=1)


def _drift_panel(ax, report, cam, axis, t0, t1):
    ylo, yhi = _ylim(report, cam, axis, t0, t1)
    _bands(ax, report, axis, t1, ylo, yhi)
    s = cam.axes[axis]
    # control limits, from the start of the control period to the right edge
    if not s.control.pending:
        xc = [_d(max(s.control.start, t0)), _d(t1)]
        for y, style in ((s.control.mean, "--"), (s.control.lower, ":"), (s.control.upper, ":")):
            ax.plot(xc, [y, y], color=CONTROL_COLOUR, ls=style, lw=1.1, zorder=2)
    # trend: solid over the fitted runs; dashed into the future only towards a forecast date
    f = s.forecast
    if s.trend.ok:
        a = max(s.trend.t0, t0)
        style = {"color": TREND_COLOUR, "lw": 1.6, "zorder": 3}
        if not s.trend.significant:
            style.update(lw=1.1, alpha=0.6)
        ax.plot([_d(a), _d(s.trend.t_end)], s.trend.at([a, s.trend.t_end]), **style)
        if f.status == "date":
            b = min(f.t, t1)
            if b > s.trend.t_end:
                ax.plot([_d(s.trend.t_end), _d(b)], s.trend.at([s.trend.t_end, b]), ls=(0, (5, 3)), **style)
            if f.t <= t1:
                ax.plot([_d(f.t)], [f.level], marker="D", ms=6, color=STATE_COLOURS["ACTION"], mec="white", zorder=5)
                ax.annotate(
                    f"action level\n{fmt_date(f.t)}",
                    (_d(f.t), f.level),
                    xytext=(-8, 0),
                    textcoords="offset points",
                    ha="right",
                    va="bottom" if f.level > 0 else "top",
                    fontsize=8,
                    color=STATE_COLOURS["ACTION"],
                    fontweight="bold",
                )
            else:
                ax.text(
                    0.99,
                    0.04 if f.level < 0 else 0.96,
                    f"action level {fmt_date(f.t)} →",
                    transform=ax.transAxes,
                    ha="right",
                    va="bottom" if f.level < 0 else "top",
                    fontsize=8,
                    color=TREND_COLOUR,
                )
    # the runs, coloured by the state the QA gave them
    t = cam.times()
    v = cam.series(f"drift_{axis}_px")
    ok = np.isfinite(v)
    ax.plot(_d(t[ok]), v[ok], color="#555555", lw=0.7, zorder=4)
    colours = [
        STATE_COLOURS.get(p.status.get(f"drift_{axis}_px", "OK"), "#555555") for p, good in zip(cam.points, ok) if good
    ]
    ax.scatter(_d(t[ok]), v[ok], s=16, c=colours, edgecolors="white", linewidths=0.5, zorder=6)
    for b in cam.baselines:
        ax.axvline(_d(b), color=BASELINE_COLOUR, ls="--", lw=1.0, zorder=2)
    ax.axvline(_d(report.now), color="#999999", lw=0.8, ls="-.", zorder=1)
    ax.set_ylim(ylo, yhi)
    ax.set_ylabel(f"drift {axis} (px)")
    ax.grid(True, color="#d9d9d9", lw=0.5, zorder=0)
    ax.set_axisbelow(True)
    k = cam.mm_per_px.get(axis)
    if k:
        sec = ax.secondary_yaxis("right", functions=(lambda px, k=k: px * k, lambda mm, k=k: mm / k))
        sec.set_ylabel("mm at the wall")
    pend = "" if not s.control.pending else f"control limits pending ({s.control.n}/{CONTROL_RUNS} runs)"
    if s.trend.ok:
        slope = f"trend {s.trend.slope_per_30d:+.3f} ± {s.trend.slope_se_per_30d:.3f} px / 30 d"
        slope += "" if s.trend.significant else f" (not significant, p = {s.trend.p_value:.2f})"
    else:
        slope = f"no trend yet ({s.trend.short_reason}; needs {MIN_TREND_RUNS} runs / {MIN_TREND_DAYS:g} d)"
    ax.set_title("   ".join(x for x in (f"{cam.name} — drift {axis}", slope, pend) if x), loc="left")


_STRIP = (
    ("led_off_visible", "LED off: markers seen"),
    ("markers_missing", "markers missing"),
    ("stray_blobs", "stray blobs"),
)


def _strip_panel(ax, report, cam):
    n = len(_STRIP)
    for row, (metric, _) in enumerate(_STRIP):
        y = n - row
        ok_t = [p.t for p in cam.points if metric in p.values and not (p.values[metric] or 0) > 0]
        bad = [p for p in cam.points if (p.values.get(metric) or 0) > 0]
        if ok_t:
            ax.scatter(_d(np.array(ok_t)), [y] * len(ok_t), s=9, color=STATE_COLOURS["OK"], alpha=0.55, lw=0)
        for p in bad:
            colour = STATE_COLOURS.get(p.status.get(metric, "ACTION"), STATE_COLOURS["ACTION"])
            ax.scatter([_d(p.t)], [y], s=46, marker="X", color=colour, lw=0.4, edgecolors="white", zorder=3)
            ax.annotate(
                f"{p.values[metric]:g}",
                (_d(p.t), y),
                xytext=(0, 6),
                textcoords="offset points",
                ha="center",
                fontsize=7,
                color=colour,
            )
    nc = [r.started for r in report.not_completed]
    if nc:
        ax.scatter(_d(np.array(nc)), [0] * len(nc), s=40, marker="x", color="#444444", lw=1.4)
    for b in cam.baselines:
        ax.axvline(_d(b), color=BASELINE_COLOUR, ls="--", lw=1.0)
    ax.set_yticks(list(range(n, -1, -1)), [label for _, label in _STRIP] + ["run not completed"])
    ax.set_ylim(-0.7, n + 0.8)
    ax.grid(True, axis="x", color="#d9d9d9", lw=0.5)
    ax.set_axisbelow(True)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)


def _legend_handles():
    return [
        Patch(color=ZONE_COLOURS["OK"], label="OK"),
        Patch(color=ZONE_COLOURS["TOLERANCE"], label="tolerance"),
        Patch(color=ZONE_COLOURS["ACTION"], label="action"),
        Line2D([], [], color=CONTROL_COLOUR, ls=":", label=f"control limits (mean ± {CONTROL_K:g} SD)"),
        Line2D([], [], color=TREND_COLOUR, lw=1.6, label="linear trend (dashed: to the forecast)"),
        Line2D([], [], color=BASELINE_COLOUR, ls="--", label="baseline"),
        Line2D([], [], color="#999999", ls="-.", label="report date"),
    ]


HEADER_TITLE_PT = 15.0
HEADER_LINE_PT = 8.5
HEADER_LINESPACING = 1.35


def header_height_in(header: list[str]) -> float:
    """Inches the text header of a PDF camera page takes: the title, then one line each."""
    lines = sum(h.count("\n") + 1 for h in header[1:])
    return (HEADER_TITLE_PT * 1.6 + lines * HEADER_LINE_PT * HEADER_LINESPACING + 10) / 72


def camera_figure(
    report: DriftReport, cam: CameraDrift, figsize=(10.0, 7.6), header: list[str] | None = None
) -> Figure:
    """The figure of one camera; ``header`` lines (PDF pages) go in a text block on top, as
    tall as its lines (the plots take the rest of the page)."""
    import matplotlib

    with matplotlib.rc_context(FONT):
        fig = Figure(figsize=figsize, layout="constrained")
        body = fig
        if header:
            hh = header_height_in(header)
            top, body = fig.subfigures(2, 1, squeeze=False, height_ratios=[hh, figsize[1] - hh])[:, 0]
            top.text(0.035, 1 - 6 / 72 / hh, header[0], fontsize=HEADER_TITLE_PT, fontweight="bold", va="top")
            top.text(
                0.035,
                1 - (6 + HEADER_TITLE_PT * 1.6) / 72 / hh,
                "\n".join(header[1:]),
                fontsize=HEADER_LINE_PT,
                va="top",
                family="monospace",
                linespacing=HEADER_LINESPACING,
            )
        ax_x, ax_y, ax_s = body.subplots(3, 1, gridspec_kw={"height_ratios": [3, 3, 1.45]})
        t0, t1 = time_range(report, cam)
        _drift_panel(ax_x, report, cam, "x", t0, t1)
        _drift_panel(ax_y, report, cam, "y", t0, t1)
        _strip_panel(ax_s, report, cam)
        locator = mdates.AutoDateLocator(minticks=5, maxticks=12)
        for ax in (ax_x, ax_y, ax_s):
            ax.set_xlim(_d(t0), _d(t1))
            ax.xaxis.set_major_locator(locator)
            ax.xaxis.set_major_formatter(mdates.ConciseDateFormatter(locator))
        ax_x.sharex(ax_s)
        ax_y.sharex(ax_s)
        ax_x.tick_params(labelbottom=False)
        ax_y.tick_params(labelbottom=False)
        body.legend(
            handles=_legend_handles(),
            loc="outside lower center",
            ncol=7,
            frameon=False,
            handlelength=1.8,
            columnspacing=1.2,
        )
    return fig
