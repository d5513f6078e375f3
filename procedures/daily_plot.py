"""The daily QA at a glance: per camera, today's wall-marker drift inside its tolerance and
action windows, and the state of every other check (``QAResult.plot``)."""

from __future__ import annotations

import math

from vts_hw import __version__
from vts_hw.figures import figure_png
from vts_hw.files import write_atomic
from vts_hw.tolerance import State, worst

STATE_COLOURS = {State.OK: "#2e7d32", State.TOLERANCE: "#ef6c00", State.ACTION: "#c62828"}


def _box(ax, lo, hi, style, label):
    """The window [lo, hi] on both axes as a dashed square (open sides skipped)."""
    if lo is None or hi is None:
        return
    ax.plot([lo, hi, hi, lo, lo], [lo, lo, hi, hi, lo], style, color="0.45", lw=1, label=label)


def daily_figure(result, windows: dict):
    """A matplotlib Figure: one panel per camera (drift y against drift x, px, the windows
    ``drift_x_px`` as squares) and the camera's other checks listed under it."""
    from matplotlib.figure import Figure

    cams = result.cameras
    fig = Figure(figsize=(3.2 * max(1, len(cams)), 4.4))
    wx = windows.get("drift_x_px")
    reach = 2.5 if wx is None or wx.action_high is None else 1.25 * wx.action_high
    for i, c in enumerate(cams):
        ax = fig.add_subplot(1, max(1, len(cams)), i + 1)
        if wx is not None:
            _box(ax, wx.tolerance_low, wx.tolerance_high, "--", "tolerance")
            _box(ax, wx.action_low, wx.action_high, ":", "action")
        colour = STATE_COLOURS.get(c.state, "k")
        own = [(m, v, u, st) for s, m, v, u, st in c.measures if "/" not in s]  # per marker rows skipped
        values = {m: v for m, v, _, _ in own}
        dx, dy = values.get("drift_x_px"), values.get("drift_y_px")
        if dx is not None and dy is not None and not (math.isnan(dx) or math.isnan(dy)):
            drift = STATE_COLOURS.get(worst(st for m, _, _, st in own if m in ("drift_x_px", "drift_y_px")), "k")
            ax.plot([0, dx], [0, dy], "-", color=drift, lw=1)
            ax.plot(dx, dy, "o", color=drift, ms=7)
            reach = max(reach, 1.15 * max(abs(dx), abs(dy)))
        else:
            ax.text(0, 0, "no drift\nmeasured", ha="center", va="center", fontsize=8, color=colour)
        ax.set_xlim(-reach, reach)
        ax.set_ylim(reach, -reach)  # image rows grow downwards
        ax.set_aspect("equal")
        ax.axhline(0, color="0.85", lw=0.6, zorder=0)
        ax.axvline(0, color="0.85", lw=0.6, zorder=0)
        ax.set_xlabel("drift x (px)")
        if i == 0:
            ax.set_ylabel("drift y (px)")
            ax.legend(fontsize=7, loc="lower left", frameon=False)
        ax.set_title(f"{c.camera}: {c.state}", color=colour, fontsize=10)
        checks = [
            f"{m} {_value(v)} {u}".rstrip() + ("" if st == State.OK else f"  {st}")
            for m, v, u, st in own
            if not m.startswith("drift_")
        ]
        checks += [f"! {p}" for p in c.problems]
        ax.text(0.0, -0.22, "\n".join(checks[:8]), transform=ax.transAxes, va="top", fontsize=7, family="monospace")
    fig.suptitle(
        f"{result.procedure} QA: {result.state}"
        + (f" (run {result.run_id})" if result.run_id else "")
        + f", vts-hw {__version__}",
        fontsize=10,
    )
    fig.subplots_adjust(bottom=0.36, top=0.86, wspace=0.35)
    return fig


def _value(v) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float) and not v.is_integer():
        return f"{v:+.3f}"
    return f"{v:g}"


def daily_png(result, windows: dict, path=None) -> bytes:
    png = figure_png(daily_figure(result, windows))
    if path is not None:
        write_atomic(path, png)
    return png
