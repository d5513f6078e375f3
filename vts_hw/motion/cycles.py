"""Breaths seen whole, and the breathing figures that rest on what was seen (issue 20; the
rules and their reasons: docs/decisions/0046-time-without-frames.md).

The respiratory signal is band-passed 0.05-1.2 Hz; its **landmarks** are the troughs (end of
exhalation) and peaks found by prominence (30 % of the 5-95 % range), and its up and down
crossings of the middle (with a hysteresis of 15 % of the range). A landmark is *seen* when it
lies in a stretch of time with a pose (holes of up to :data:`~.timeline.MAX_HOLE_S` allowed: a
breath cannot begin and end inside one) with :data:`EDGE_S` of it on either side, so that a
trough is not the edge of a gap. Nothing spanning a gap counts: two breaths with the peak
between them lost would read as one slow breath.

* **Cycles** (:func:`find_breaths`): trough to trough, both seen in one stretch, a peak between
  them. Phase (0-1, linear in time) and the per-frame rate exist only inside them.
* **Periods**: from a landmark to the next of its kind (trough-trough, peak-peak, up-up,
  down-down) in one stretch: every way a whole breath can be seen between two gaps, so that a
  stretch a little longer than a breath gives one whichever phase it starts at.
* **Half breaths**: a trough and the peak next to it in one stretch (the breath's depth).

:func:`breathing_figures`: ``none`` when the breaths are not above the signal's noise (no
respiratory signal is then kept and no respiratory subsets made); the rate from the periods --
their weighted median, each weighted by the inverse of the time in which a period of its length
fits whole into the stretches seen (short breaths fit into short stretches more often: unweighted,
loss in bursts would favour them) and by one over the ways its breath was seen (periods from
different landmarks of one breath count as one breath), with a 95 % range from the breaths'
spread (at least :data:`SPREAD_MIN` of the rate: a few breaths understate it), shrunk by the
share of the scan's breaths seen; ``unknown`` when fewer than :data:`MIN_CYCLES` breaths were,
``measured`` when the range is within ±0.5 /min, else ``bounded`` (the range is then the figure).
The amplitude is the median depth of the half breaths (at least :data:`MIN_CYCLES` of them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.signal import find_peaks

from vts_hw.motion.signal import bandpass
from vts_hw.motion.timeline import seen_runs

__all__ = ["Cycle", "Breaths", "BreathingFigures", "find_breaths", "signal_noise", "breathing_figures",
           "EDGE_S", "MIN_CYCLES", "NOISE_K", "MIN_BREATH_MM"]

EDGE_S = 0.3            # seen time needed on both sides of a peak or trough ...
CROSS_EDGE_S = 0.1      # ... and of a crossing of the middle (a steep, well-placed landmark)
MIN_CYCLES = 3          # breaths a rate (half breaths an amplitude) needs
NOISE_K = 6.0           # a breath must be this many times the signal's frame noise ...
MIN_BREATH_MM = 0.2     # ... and at least this deep
RATE_GOAL = 0.5         # /min: a rate whose 95 % range is wider is "bounded"
SPREAD_MIN = 0.10       # breath-to-breath spread of the rate assumed at least (a few breaths show less)


@dataclass
class Cycle:
    t_start: float
    t_peak: float
    t_end: float
    amplitude: float

    @property
    def period_s(self) -> float:
        return self.t_end - self.t_start

    @property
    def rate_per_min(self) -> float:
        return 60.0 / self.period_s


@dataclass
class Breaths:
    """What :func:`find_breaths` saw: whole ``cycles``; ``periods`` [(t0, t1, edge_s)] landmark
    to landmark of one kind (and the seen time its landmarks needed on either side); ``halves`` depths (mm) of trough-peak pairs; ``phase``/``rate`` per
    frame inside whole cycles; ``depth_mm``: the signal's 5-95 % range; ``stretches_s``: the
    lengths of the stretches seen."""

    cycles: list
    periods: list
    halves: list
    phase: np.ndarray
    rate: np.ndarray
    depth_mm: float = 0.0
    stretches_s: list = field(default_factory=list)


@dataclass
class BreathingFigures:
    """``status`` of the rate: ``measured``, ``bounded`` (known within ``rate_range`` only),
    ``unknown`` (too little seen whole) or ``none`` (no breathing above the noise); ``why`` in
    a sentence; ``cycles``: whole breaths, ``periods``/``breaths_s``: the periods measured and
    the time they span (``share`` of the scan); ``amplitude_mm`` (None when unknown) from
    ``halves`` half breaths; ``noise_mm``: the signal's frame noise."""

    status: str
    why: str
    rate_per_min: float | None = None
    rate_range: list | None = None
    amplitude_mm: float | None = None
    cycles: int = 0
    periods: int = 0
    halves: int = 0
    breaths_s: float = 0.0
    share: float = 0.0
    noise_mm: float | None = None

    def to_json(self) -> dict:
        return {"status": self.status, "why": self.why, "rate_per_min": self.rate_per_min,
                "rate_range_per_min": self.rate_range, "amplitude_mm": self.amplitude_mm,
                "whole_cycles": self.cycles, "periods_seen": self.periods, "half_breaths_seen": self.halves,
                "rate_rests_on_s": self.breaths_s, "share_of_scan": self.share, "noise_mm": self.noise_mm}


def _crossings(t, x, ok, h):
    """(up, down): interpolated times and row indices of the middle crossings with hysteresis."""
    up, down = [], []
    state = 0
    for k in np.flatnonzero(ok):
        v = x[k]
        if v < -h:
            if state == 1:
                down.append(k)
            state = -1
        elif v > h:
            if state == -1:
                up.append(k)
            state = 1

    def when(ks, sign):
        out = []
        for k in ks:
            j = k
            while j > 0 and ok[j - 1] and sign * x[j - 1] > 0:
                j -= 1                      # back to the first row past the middle
            if j > 0 and ok[j - 1]:
                a, b = x[j - 1], x[j]
                out.append((float(t[j - 1] + (t[j] - t[j - 1]) * (-a / (b - a))), j))
        return out
    return when(up, 1), when(down, -1)


def find_breaths(t, a, valid, period: float, min_period_s: float = 1.5, max_period_s: float = 12.0) -> Breaths:
    """Cycles, periods and half breaths of the signal ``a`` where ``valid`` (see the module)."""
    t = np.asarray(t, float)
    F = len(t)
    phase = np.full(F, np.nan)
    rate = np.full(F, np.nan)
    ok = np.asarray(valid, bool) & np.isfinite(a)
    bounds = seen_runs(ok, period)
    out = Breaths([], [], [], phase, rate, 0.0, [(b - a_) * period for a_, b in bounds])
    if ok.sum() < 20:
        return out
    x = bandpass(t, np.where(ok, a, np.nan)[:, None], 0.05, 1.2)[:, 0]
    amp = float(np.percentile(x[ok], 95) - np.percentile(x[ok], 5))
    out.depth_mm = amp
    dist = max(1, int(min_period_s / period * 0.6))
    troughs, _ = find_peaks(-x, prominence=0.3 * amp, distance=dist)
    peaks, _ = find_peaks(x, prominence=0.3 * amp, distance=dist)
    ups, downs = _crossings(t, x, ok, 0.15 * amp)
    seg = np.full(F, -1)
    for k, (s0, s1) in enumerate(bounds):
        seg[s0:s1] = k
    def seen(i, edge_s=EDGE_S):                 # in a stretch (maybe on a hole of a frame or two)
        k, edge = seg[i], int(np.ceil(edge_s / period))
        return k >= 0 and i - edge >= bounds[k][0] and i + edge < bounds[k][1]

    marks = {"trough": [(float(t[i]), int(i)) for i in troughs], "peak": [(float(t[i]), int(i)) for i in peaks],
             "up": ups, "down": downs}
    for kind, lst in marks.items():
        e = EDGE_S if kind in ("trough", "peak") else CROSS_EDGE_S
        for (t0, i0), (t1, i1) in zip(lst[:-1], lst[1:]):
            if seen(i0, e) and seen(i1, e) and seg[i0] == seg[i1] and min_period_s <= t1 - t0 <= max_period_s:
                out.periods.append((t0, t1, e))
    ext = sorted([(int(i), 1) for i in peaks] + [(int(i), -1) for i in troughs])
    for (i0, s0), (i1, s1) in zip(ext[:-1], ext[1:]):
        if s0 != s1 and seen(i0) and seen(i1) and seg[i0] == seg[i1]:
            out.halves.append(float(abs(x[i1] - x[i0])))
    for i0, i1 in zip(troughs[:-1], troughs[1:]):
        if not (seen(i0) and seen(i1) and seg[i0] == seg[i1]):
            continue            # not seen whole: it spans a gap, or a trough is a gap's edge
        per = t[i1] - t[i0]
        inside = peaks[(peaks > i0) & (peaks < i1)]
        if not (min_period_s <= per <= max_period_s) or inside.size == 0:
            continue
        j = inside[np.argmax(x[inside])]
        out.cycles.append(Cycle(float(t[i0]), float(t[j]), float(t[i1]), float(x[j] - 0.5 * (x[i0] + x[i1]))))
        phase[i0:i1] = (t[i0:i1] - t[i0]) / per
        rate[i0:i1] = 60.0 / per
    phase[~ok] = np.nan                         # no pose, no phase (even inside a whole breath)
    rate[~ok] = np.nan
    return out


def signal_noise(a, valid) -> float:
    """The frame-to-frame noise (mm, 1 sigma) of ``a`` over consecutive ``valid`` rows: the
    robust spread of second differences over sqrt(6) (a breath's own curvature is far below it
    at 25 frames/s)."""
    a = np.where(np.asarray(valid, bool), a, np.nan)
    d2 = a[2:] - 2 * a[1:-1] + a[:-2]
    d2 = d2[np.isfinite(d2)]
    if d2.size < 10:
        return float("nan")
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def _fit_length(p: float, stretches_s, edge_s: float) -> float:
    """The time in which a period of ``p`` s can start and still be seen whole."""
    return float(sum(max(0.0, s - p - 2 * edge_s) for s in stretches_s))


def _weighted_median(x, w) -> float:
    o = np.argsort(x)
    x, w = np.asarray(x)[o], np.asarray(w)[o]
    c = np.cumsum(w)
    return float(x[np.searchsorted(c, 0.5 * c[-1])])


def _union_s(intervals) -> float:
    total, end = 0.0, -np.inf
    for a, b in sorted(intervals):
        if b > end:
            total += b - max(a, end)
            end = b
    return total


def _breath_groups(periods) -> np.ndarray:
    """(n,) which breath each period is: periods whose middles lie within half a (median)
    period of each other measure one breath (from different landmarks)."""
    if not periods:
        return np.zeros(0, int)
    mid = np.array([(a + b) / 2 for a, b, _ in periods])
    p = float(np.median([b - a for a, b, _ in periods]))
    order = np.argsort(mid)
    group = np.zeros(len(mid), int)
    g, start = 0, mid[order[0]]
    for k in order:
        if mid[k] - start > 0.5 * p:
            g, start = g + 1, mid[k]
        group[k] = g
    return group


def breathing_figures(br: Breaths, period: float, duration_s: float, noise_mm: float,
                      breathes: bool = True) -> BreathingFigures:
    """The figures of the module's rules. ``breathes``: False when no marker moves at breathing
    rates at all (then ``none`` whatever the signal)."""
    noise = float(noise_mm) if np.isfinite(noise_mm) else None
    span_s = _union_s([(a, b) for a, b, _ in br.periods])
    base = dict(cycles=len(br.cycles), periods=len(br.periods), halves=len(br.halves), breaths_s=span_s,
                share=span_s / duration_s if duration_s > 0 else 0.0, noise_mm=noise)
    floor = max(NOISE_K * (noise or 0.0), MIN_BREATH_MM)
    if not breathes:
        return BreathingFigures("none", "no marker moves at breathing rates: no breathing found", **base)
    depth = float(np.median(br.halves)) if br.halves else float(br.depth_mm)
    if depth < floor:
        return BreathingFigures("none", f"no breathing above the noise (breaths of {depth:.2f} mm against "
                                        f"{floor:.2f} mm: {NOISE_K:g} x the {noise or 0:.3f} mm noise, at least "
                                        f"{MIN_BREATH_MM:g} mm)", **base)
    amp = float(np.median(br.halves)) if len(br.halves) >= MIN_CYCLES else None
    periods = np.array([b - a for a, b, _ in br.periods])
    edges = [e for _, _, e in br.periods]
    group = _breath_groups(br.periods)                  # one breath seen in several ways counts once
    n_ind = int(group.max()) + 1 if group.size else 0
    if n_ind < MIN_CYCLES:
        longest = max(br.stretches_s, default=0.0)
        return BreathingFigures("unknown", f"rate unknown: {n_ind} breath(s) seen whole, over {span_s:.1f} s of "
                                           f"{duration_s:.1f} s (the longest stretch seen {longest:.1f} s); a rate "
                                           f"needs {MIN_CYCLES}", amplitude_mm=amp, **base)
    rates = 60.0 / periods
    size = np.bincount(group)[group]
    w = np.array([1.0 / max(_fit_length(p, br.stretches_s, e), period) for p, e in zip(periods, edges)]) / size
    rate = _weighted_median(rates, w)
    per_breath = np.array([np.mean(rates[group == g]) for g in range(n_ind)])
    spread = max(1.4826 * float(np.median(np.abs(per_breath - np.median(per_breath)))), SPREAD_MIN * rate)
    wb = np.bincount(group, weights=w)
    n_eff = min(float(wb.sum() ** 2 / (wb ** 2).sum()), n_ind)
    expected = duration_s * rate / 60.0 - 1.0               # whole breaths in the scan (its ends cut two)
    fpc = np.sqrt(max(0.0, 1.0 - n_ind / max(expected, 1.0)))
    half = max(1.96 * 1.2533 * spread / np.sqrt(n_eff) * fpc, 0.1)
    rng = [round(rate - half, 2), round(rate + half, 2)]
    status = "measured" if half <= RATE_GOAL else "bounded"
    why = (f"from breaths seen whole over {span_s:.1f} s ({100 * base['share']:.0f} % of the scan)"
           + ("" if status == "measured" else f": the rate is known only to {rng[0]:.1f}-{rng[1]:.1f} /min"))
    return BreathingFigures(status, why, rate, rng, amp, **base)
