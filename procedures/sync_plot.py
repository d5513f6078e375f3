"""The sync check's figure: the VTS and SPECT traces on one clock, and dt per event.

:func:`sync_figure` draws an analysed :class:`~.sync.SyncAnalysis` (``SyncAnalysis.figure()``
and ``plot()`` call it): both traces on one time axis (s since the trigger's first edge, host
clock), SPECT dead time shaded, gaps of the VTS hatched, motion events marked; below, VTS − SPECT
per event (ms) and the median offset.
"""

from __future__ import annotations

import numpy as np

__all__ = ["sync_figure"]


def sync_figure(an):
    """A matplotlib Figure of the analysed sync check ``an`` (see the module)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(10, 5.6))
    ax, bx = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    for t0, t1 in an._rel(an.dead_host):
        for x in (ax, bx):
            x.axvspan(t0, t1, color="#d0d4da", alpha=0.6, lw=0)
    for t0, t1 in an._rel(np.array(an.vts_gaps).reshape(-1, 2)):
        ax.axvspan(t0, t1, facecolor="none", edgecolor="#c62828", hatch="//", lw=0)
    ax.plot(
        an._rel(an.spect_t),
        an.spect_z,
        color="#e08a00",
        lw=1.0,
        label=f"SPECT: axial centre of mass ({an.spect_bin_s * 1e3:.0f} ms bins)",
    )
    ax.plot(
        an._rel(an.vts_t),
        an.vts_z,
        ".",
        ms=2.0,
        color="#1f5fa8",
        label=f"VTS: marker {'+'.join(str(m) for m in an.marker_ids)} "
        f"{'SPECT Z' if an.vts_axial else '(main direction)'}",
    )
    for k, e in enumerate(an.events, 1):
        x = float(an._rel(e.t))
        ax.axvline(x, color="#5b2a86", lw=0.8, ls="--")
        ax.annotate(
            str(k), (x, 1.0), xycoords=("data", "axes fraction"), ha="center", va="bottom", fontsize=8, color="#5b2a86"
        )
        if e.dt_s is not None:
            bx.plot([x], [e.dt_s * 1e3], "o", color="#2e7d32", ms=5)
        else:
            bx.plot([x], [0.0], "x", color="#c62828", ms=6)
    off = an.offset_s
    if off is not None:
        bx.axhline(off * 1e3, color="#2e7d32", lw=0.8, ls=":")
    bx.axhline(0, color="#888", lw=0.5)
    ax.set_ylabel("axial position (mm)")
    bx.set_ylabel("VTS − SPECT\n(ms)")
    bx.set_xlabel("time since the trigger's first edge (s, host clock)")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(
        "VTS and SPECT on one clock: grey = SPECT dead time, hatched = VTS gap, dashed = motion events",
        fontsize=9,
        pad=14,
    )
    fig.tight_layout()
    return fig
