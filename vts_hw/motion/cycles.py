"""Breaths seen whole, and the breathing figures that rest on what was seen (issue 20; the
rules and their reasons: docs/decisions/0046-time-without-frames.md).

The respiratory signal is band-passed 0.05-1.2 Hz; its **landmarks** are the troughs (end of
exhalation) and peaks found by prominence (30 % of the 5-95 % range), and its up and down
crossings of the middle (with a hysteresis of 15 % of the range). A landmark is *seen* when it
lies in a stretch of time with a pose (holes of up to :data:`~.timeline.MAX_HOLE_S` allowed: a
breath cannot begin and end inside one) with :data:`EDGE_S` of it on either side, so that a
trough is not the edge of a gap. Two breaths with the peak between them lost must never read as
one slow breath: only a period of crossings may span a gap, and only one too short to hide a
breath (below).

* **Cycles** (:func:`find_breaths`): trough to trough, both seen in one stretch, a peak between
  them. Phase (0-1, linear in time) and the per-frame rate exist only inside them.
* **Periods**: from an up-crossing of the middle to the next, also across gaps too short to
  hide a breath (the breaths with no whole cycle are measured so).
* **Half breaths**: a trough and the peak next to it in one stretch (the breath's depth).

:func:`breathing_figures`: ``none`` when the breaths are not above the signal's noise (no
respiratory signal is then kept and no respiratory subsets made). The rate is the median of the
**breaths seen whole**, each once (:func:`_single_breaths`): the trough-to-trough cycles, and for a
breath with no cycle its up-crossing to the next -- which may span gaps shorter than
:data:`SPAN_K` of the shortest half breath seen (such a gap cannot hide a breath: the crossings
alternate, so the two on its sides are one breath apart); a period over :data:`DOUBLED` times
the typical one (a pause, or a breath hidden after all) is left out. Peak-to-peak and
down-to-down periods mix two breaths and are not used for the rate. Each breath is weighted by
the inverse of the time in which a breath of its length can be seen whole (loss in bursts
favours short ones). Its range: the breaths' spread (at least :data:`SPREAD_MIN` of the rate)
over the square root of their number, shrunk by the share of the scan's breaths seen, at
:data:`Z_RANGE`, combined with :data:`RATE_FLOOR` (the breaths' landmarks and the scan's ends);
``unknown`` when fewer than :data:`MIN_CYCLES` breaths were seen, ``measured`` when the range
is within ±0.5 /min, else ``bounded`` (the range is then the figure). The amplitude is the
median depth of the half breaths (at least :data:`MIN_CYCLES` of them). Why (and the figures on
simulated scans): docs/decisions/0059-breaths-across-short-gaps.md.
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
SPAN_K = 0.8            # a period may span gaps up to this share of the shortest half breath seen ...
MIN_HALVES = 6          # ... when at least this many half breaths were seen in one stretch
DOUBLED = 1.6           # a period spanning a gap this many times the typical breath held two
RATE_FLOOR = 0.3        # /min: the median of the breaths seen whole is off the breaths' own by this much
Z_RANGE = 2.58          # the range is 99 % (1.96 left 7 % of 150 simulated 60-s scans at 20 % loss outside)


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
    """What :func:`find_breaths` saw: whole ``cycles``; ``periods`` [(t0, t1)] from an
    up-crossing of the middle to the next (across gaps up to ``span_s``); ``halves`` depths (mm) of trough-peak pairs;
    ``phase``/``rate`` per frame inside whole cycles; ``depth_mm``: the signal's 5-95 % range;
    ``stretches_s``: the lengths of the stretches seen (``bounds`` their rows of ``n_rows``);
    ``span_s``: the longest gap a crossing-to-crossing period may span."""

    cycles: list
    periods: list
    halves: list
    phase: np.ndarray
    rate: np.ndarray
    depth_mm: float = 0.0
    stretches_s: list = field(default_factory=list)
    span_s: float = 0.0
    bounds: list = field(default_factory=list)
    n_rows: int = 0


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
    """Every crossing of the middle with hysteresis ``h``, in order: ``[(sign, time, row)]``,
    ``sign`` +1 up / -1 down; ``time`` interpolated between the two rows around it, or None when
    the row before it has no pose (it happened in a gap: its kind is known, not its time). The
    crossings alternate: none is missed unless a gap hides a whole excursion past the middle."""
    events = []
    state = 0
    for k in np.flatnonzero(ok):
        v = x[k]
        sign = -1 if v < -h else (1 if v > h else 0)
        if sign == 0:
            continue
        if state == -sign:
            events.append((sign, k))
        state = sign
    out = []
    for sign, k in events:
        j = k
        while j > 0 and ok[j - 1] and sign * x[j - 1] > 0:
            j -= 1                      # back to the first row past the middle
        if j > 0 and ok[j - 1]:
            a, b = x[j - 1], x[j]
            out.append((sign, float(t[j - 1] + (t[j] - t[j - 1]) * (-a / (b - a))), j))
        else:
            out.append((sign, None, j))
    return out


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
    cross = _crossings(t, x, ok, 0.15 * amp)
    seg = np.full(F, -1)
    for k, (s0, s1) in enumerate(bounds):
        seg[s0:s1] = k
    def seen(i, edge_s=EDGE_S):                 # in a stretch (maybe on a hole of a frame or two)
        k, edge = seg[i], int(np.ceil(edge_s / period))
        return k >= 0 and i - edge >= bounds[k][0] and i + edge < bounds[k][1]

    out.span_s = _span_s(cross, seen, seg)
    for (sign, t0, i0), (_, t1, i1) in zip(cross[:-2], cross[2:]):  # an up-crossing to the next
        if sign < 0 or t0 is None or t1 is None or not (seen(i0, CROSS_EDGE_S) and seen(i1, CROSS_EDGE_S)):
            continue
        if min_period_s <= t1 - t0 <= max_period_s and _longest_gap_s(bounds, seg[i0], seg[i1], period) <= out.span_s:
            out.periods.append((t0, t1))
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
    out.bounds, out.n_rows = bounds, F
    return out


def _span_s(cross, seen, seg) -> float:
    """The longest gap a crossing-to-crossing period may span: :data:`SPAN_K` of the shortest
    half breath (a crossing of the middle to the next, the other way) seen in one stretch -- a
    gap shorter than any excursion past the middle cannot hide one, so the crossings on its two
    sides are one breath apart however many are hidden; 0 when fewer than :data:`MIN_HALVES`
    half breaths were seen (then no period spans a gap)."""
    halves = [t1 - t0 for (_, t0, i0), (_, t1, i1) in zip(cross[:-1], cross[1:])
              if t0 is not None and t1 is not None and seg[i0] == seg[i1]
              and seen(i0, CROSS_EDGE_S) and seen(i1, CROSS_EDGE_S)]
    return SPAN_K * min(halves) if len(halves) >= MIN_HALVES else 0.0


def _longest_gap_s(bounds, k0: int, k1: int, period: float) -> float:
    """The longest time without a pose between stretch ``k0`` and stretch ``k1`` (0 if one)."""
    return max(((bounds[k + 1][0] - bounds[k][1]) * period for k in range(k0, k1)), default=0.0)


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


def _fit_lengths(lengths_s, br: Breaths, period: float) -> np.ndarray:
    """Per period length, the time in which a period of it can start and still be measured as an
    up-crossing period is: both ends seen (:data:`CROSS_EDGE_S` of pose on either side) with no
    gap longer than ``br.span_s`` between them."""
    edge = int(np.ceil(CROSS_EDGE_S / period))
    seen = np.zeros(br.n_rows, bool)
    joined = np.full(br.n_rows, -1)
    group = -1
    for j, (a, b) in enumerate(br.bounds):
        seen[a + edge:max(a + edge, b - edge)] = True
        if j == 0 or (a - br.bounds[j - 1][1]) * period > br.span_s:
            group += 1
        joined[a:b] = group
    out = []
    for p in lengths_s:
        k = int(round(p / period))
        ok = 0 < k < br.n_rows
        out.append(float((seen[:-k] & seen[k:] & (joined[:-k] == joined[k:])).sum()) * period if ok else 0.0)
    return np.array(out)


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


def _single_breaths(br: Breaths) -> list:
    """Each breath seen whole once: ``[(t0, t1)]``, the trough-to-trough cycles,
    and for a breath with no cycle its up-crossing to the next (the crossing comes a fifth of the
    way into the inhalation: that period is the breath's own to within a fifth of the next's
    difference; peak-to-peak and down-to-down periods mix two breaths half and half and are not
    used for the rate -- they shrink its spread and move the median off the breaths')."""
    out = [(c.t_start, c.t_end) for c in br.cycles]
    out += [(t0, t1) for t0, t1 in br.periods if not any(c.t_start <= t0 < c.t_end for c in br.cycles)]
    if out:                 # a pause, or a gap that hid a shallow breath's crossings: not one breath
        typical = float(np.median([b - a for a, b in out]))
        out = [(a, b) for a, b in out if b - a <= DOUBLED * typical]
    return sorted(out)


def breathing_figures(br: Breaths, period: float, duration_s: float, noise_mm: float,
                      breathes: bool = True) -> BreathingFigures:
    """The figures of the module's rules. ``breathes``: False when no marker moves at breathing
    rates at all (then ``none`` whatever the signal)."""
    noise = float(noise_mm) if np.isfinite(noise_mm) else None
    breaths = _single_breaths(br)
    span_s = _union_s(breaths)
    n_ind = len(breaths)
    base = dict(cycles=len(br.cycles), periods=n_ind, halves=len(br.halves), breaths_s=span_s,
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
    if n_ind < MIN_CYCLES:
        longest = max(br.stretches_s, default=0.0)
        return BreathingFigures("unknown", f"rate unknown: {n_ind} breath(s) seen whole, over {span_s:.1f} s of "
                                           f"{duration_s:.1f} s (the longest stretch seen {longest:.1f} s); a rate "
                                           f"needs {MIN_CYCLES}", amplitude_mm=amp, **base)
    lengths = np.array([b - a for a, b in breaths])
    rates = 60.0 / lengths
    # a breath is kept when seen either way, nearly always when its up-crossings are: the chance
    # of that (a long breath's ends are less often both seen) weighs it
    w = 1.0 / np.maximum(_fit_lengths(lengths, br, period), period)
    rate = _weighted_median(rates, w)
    spread = max(1.4826 * float(np.median(np.abs(rates - np.median(rates)))), SPREAD_MIN * rate)
    n_eff = min(float(w.sum() ** 2 / (w ** 2).sum()), n_ind)
    expected = duration_s * rate / 60.0 - 1.0               # whole breaths in the scan (its ends cut two)
    fpc = np.sqrt(max(0.0, 1.0 - n_ind / max(expected, 1.0)))
    half = float(np.hypot(Z_RANGE * 1.2533 * spread / np.sqrt(n_eff) * fpc, RATE_FLOOR))
    rng = [round(rate - half, 2), round(rate + half, 2)]
    status = "measured" if half <= RATE_GOAL else "bounded"
    why = (f"from {n_ind} breaths seen whole over {span_s:.1f} s ({100 * base['share']:.0f} % of the scan)"
           + ("" if status == "measured" else f": the rate is known only to {rng[0]:.1f}-{rng[1]:.1f} /min"))
    return BreathingFigures(status, why, rate, rng, amp, **base)
