"""The motion analysis's figure: the respiratory trace (breaths seen whole marked); the body's
translations and rotations with events shaded (an event whose start is only bounded: its whole
bound) and motion-state boundaries marked; the body speed with its thresholds, the still frames
and the reference period (the still-period check). Time without a pose (no frames, fewer than 3
markers) is hatched red on every panel and the traces break there: nothing is drawn across it.
Times as in the results (SPECT list-mode s, or s from the first frame on the host clock)."""

from __future__ import annotations

import numpy as np

__all__ = ["motion_figure"]


def motion_figure(r, data):
    from matplotlib.figure import Figure

    t0 = data["time_origin"]
    t = r.pose.t - t0
    fig = Figure(figsize=(10, 9))
    axes = fig.subplots(4, 1, sharex=True, gridspec_kw={"height_ratios": [1.2, 1.4, 1.4, 1]})
    ax, tx, rx, sx = axes
    ax.plot(t, r.respiration.amplitude, lw=0.8, color="#1f5fa8")
    for c in r.respiration.cycles:
        ax.axvline(c.t_start - t0, color="#9fb6d6", lw=0.4)
    ax.set_ylabel("breathing mm")
    ax.set_title(
        f"patient motion: {data['session']} ({data['date']}, vts-hw {data['vts_hw_version']})\n"
        f"{data['summary']['time']}; breathing {data['breathing']['status']}",
        fontsize=9,
    )
    six = r.pose.six_dof()
    for k, (name, col) in enumerate(zip(("x", "y", "z"), ("#c62828", "#2e7d32", "#1565c0"))):
        tx.plot(t, six[:, k], lw=0.8, color=col, label=f"t{name}")
        rx.plot(t, six[:, 3 + k], lw=0.8, color=col, label=f"r{name}")
    tx.set_ylabel("translation mm")
    rx.set_ylabel("rotation deg")
    tx.legend(loc="upper left", fontsize=7, ncol=3)
    rx.legend(loc="upper left", fontsize=7, ncol=3)
    for e in r.events:
        for a in axes:
            a.axvspan(e.t_start - t0, e.t_end - t0, color="#f3c969", alpha=0.5, lw=0)
    for s in r.states[1:]:
        for a in (tx, rx):
            a.axvline(s.t_start - t0, color="#5b2a86", lw=0.8, ls="--")
    for a, b in r.gaps:
        for x in axes:
            x.axvspan(a - t0, b - t0, facecolor="#c62828", alpha=0.12, edgecolor="#c62828", hatch="//", lw=0)
    sx.plot(t, r.speed, lw=0.6, color="#444")
    sx.axhline(r.thresholds["hi_mm_s"], color="#c62828", lw=0.8, ls=":")
    sx.axhline(r.thresholds["lo_mm_s"], color="#e08a00", lw=0.8, ls=":")
    still = r.still.astype(float)
    top = float(np.nanmax(r.speed)) if np.isfinite(r.speed).any() else 1.0
    sx.fill_between(t, 0, still * top, color="#2e7d32", alpha=0.08, lw=0, step="mid")
    sx.axvspan(r.reference_period[0] - t0, r.reference_period[1] - t0, color="#2e7d32", alpha=0.25, lw=0)
    sx.set_yscale("symlog", linthresh=1.0)
    sx.set_ylabel("body speed mm/s")
    clock = "SPECT list-mode s" if r.series.clock == "spect" else "s from the first frame (host clock)"
    sx.set_xlabel(
        f"time, {clock}; events shaded, states dashed, reference and still frames green, "
        f"no pose (no frames / < 3 markers) hatched red"
    )
    fig.tight_layout()
    return fig
