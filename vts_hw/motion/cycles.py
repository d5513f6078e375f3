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
**breaths seen whole**, each once (:func:`_breath_bounds`): in a chain of stretches joined across
gaps shorter than :data:`SPAN_K` of the shortest half breath seen (such a gap cannot hide a
breath: the crossings alternate, so every crossing is there, hidden or not), each breath's start
and end (the troughs before its inhalation and the next) are fitted by least squares to every
landmark of it that was seen -- its troughs (to :data:`TROUGH_S`), and its up and down crossings
of the middle, placed in the breath at the share at which they come in this scan's breaths seen
whole. A breath across a gap is so measured from what is seen on both sides of it; one whose
length is not known to :data:`KEEP_S`, or whose landmarks do not fit one breath (a pause, a deep
breath: :data:`OUTLIER_K`), or over :data:`DOUBLED` times the typical one, is left out. Its range:
the breaths' spread (at least :data:`SPREAD_MIN` of the rate) over the square root of their
number, shrunk by the share of the scan's breaths measured, and the breaths' own errors, at
:data:`Z_RANGE`, combined with :data:`RATE_FLOOR` (the scan's ends); ``unknown`` when fewer than
:data:`MIN_CYCLES` breaths were measured, ``measured`` when the range is within ±0.5 /min, else
``bounded`` (the range is then the figure). The amplitude is the median depth of the half breaths
(at least :data:`MIN_CYCLES` of them). The live trace's rate is this one, of its last seconds
(:mod:`vts_hw.tracking.live.breathing`). Why (and the figures on simulated scans):
docs/decisions/0059-breaths-across-short-gaps.md, 0089-one-rate-estimator.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.signal import find_peaks

from vts_hw.motion.signal import bandpass
from vts_hw.motion.timeline import seen_runs

__all__ = [
    "Cycle",
    "Breaths",
    "BreathingFigures",
    "find_breaths",
    "signal_noise",
    "breathing_figures",
    "EDGE_S",
    "MIN_CYCLES",
    "NOISE_K",
    "MIN_BREATH_MM",
]

EDGE_S = 0.3  # seen time needed on both sides of a peak or trough ...
CROSS_EDGE_S = 0.1  # ... and of a crossing of the middle (a steep, well-placed landmark)
MIN_CYCLES = 3  # breaths a rate (half breaths an amplitude) needs
NOISE_K = 6.0  # a breath must be this many times the signal's frame noise ...
MIN_BREATH_MM = 0.2  # ... and at least this deep
RATE_GOAL = 0.5  # /min: a rate whose 95 % range is wider is "bounded"
SPREAD_MIN = 0.10  # breath-to-breath spread of the rate assumed at least (a few breaths show less)
SPAN_K = 0.8  # a period may span gaps up to this share of the shortest half breath seen ...
MIN_HALVES = 3  # ... when at least this many half breaths were seen in one stretch (0059: 6; no chain
# through a body move: 0089)
DOUBLED = 1.6  # a period spanning a gap this many times the typical breath held two
RATE_FLOOR = 0.2  # /min: the scan's first and last breaths, counted by the truth, not always seen
Z_RANGE = 2.58  # the range is 99 % (1.96 left 7 % of 150 simulated 60-s scans at 20 % loss outside)


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
    ``span_s``: the longest gap a crossing-to-crossing period may span; ``breaths``
    [(t0, t1, sigma_s)]: each breath measured, start, end and the error of its length
    (:func:`_breath_bounds`)."""

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
    breaths: list = field(default_factory=list)


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
        return {
            "status": self.status,
            "why": self.why,
            "rate_per_min": self.rate_per_min,
            "rate_range_per_min": self.rate_range,
            "amplitude_mm": self.amplitude_mm,
            "whole_cycles": self.cycles,
            "periods_seen": self.periods,
            "half_breaths_seen": self.halves,
            "rate_rests_on_s": self.breaths_s,
            "share_of_scan": self.share,
            "noise_mm": self.noise_mm,
        }


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
            j -= 1  # back to the first row past the middle
        if j > 0 and ok[j - 1]:
            a, b = x[j - 1], x[j]
            out.append((sign, float(t[j - 1] + (t[j] - t[j - 1]) * (-a / (b - a))), j))
        else:
            out.append((sign, None, j))
    return out


def find_breaths(
    t, a, valid, period: float, min_period_s: float = 1.5, max_period_s: float = 12.0, moving=None
) -> Breaths:
    """Cycles, periods and half breaths of the signal ``a`` where ``valid`` (see the module).
    ``moving`` (F,): frames where the body moves. A breath seen whole (trough to trough in one
    stretch) stands then too, but no period or fitted breath is chained across a gap through
    them: the fitted signal takes up part of a move, and its crossings there are not the
    breath's (decision 0089)."""
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

    def seen(i, edge_s=EDGE_S):  # in a stretch (maybe on a hole of a frame or two)
        k, edge = seg[i], int(np.ceil(edge_s / period))
        return k >= 0 and i - edge >= bounds[k][0] and i + edge < bounds[k][1]

    # the chains across gaps: the stretches without the moving frames
    if moving is None or not np.any(moving):
        c_bounds, c_seg, c_seen = bounds, seg, seen
    else:
        c_bounds = seen_runs(ok & ~np.asarray(moving, bool), period)
        c_seg = np.full(F, -1)
        for k, (s0, s1) in enumerate(c_bounds):
            c_seg[s0:s1] = k

        def c_seen(i, edge_s=EDGE_S):
            k, edge = c_seg[i], int(np.ceil(edge_s / period))
            return k >= 0 and i - edge >= c_bounds[k][0] and i + edge < c_bounds[k][1]

    out.span_s = _span_s(cross, c_seen, c_seg)
    for (sign, t0, i0), (_, t1, i1) in zip(cross[:-2], cross[2:]):  # an up-crossing to the next
        if sign < 0 or t0 is None or t1 is None or not (c_seen(i0, CROSS_EDGE_S) and c_seen(i1, CROSS_EDGE_S)):
            continue
        if (
            min_period_s <= t1 - t0 <= max_period_s
            and _longest_gap_s(c_bounds, c_seg[i0], c_seg[i1], period) <= out.span_s
        ):
            out.periods.append((t0, t1))
    ext = sorted([(int(i), 1) for i in peaks] + [(int(i), -1) for i in troughs])
    for (i0, s0), (i1, s1) in zip(ext[:-1], ext[1:]):
        if s0 != s1 and seen(i0) and seen(i1) and seg[i0] == seg[i1]:
            out.halves.append(float(abs(x[i1] - x[i0])))
    for i0, i1 in zip(troughs[:-1], troughs[1:]):
        if not (seen(i0) and seen(i1) and seg[i0] == seg[i1]):
            continue  # not seen whole: it spans a gap, or a trough is a gap's edge
        per = t[i1] - t[i0]
        inside = peaks[(peaks > i0) & (peaks < i1)]
        if not (min_period_s <= per <= max_period_s) or inside.size == 0:
            continue
        j = inside[np.argmax(x[inside])]
        out.cycles.append(Cycle(float(t[i0]), float(t[j]), float(t[i1]), float(x[j] - 0.5 * (x[i0] + x[i1]))))
        phase[i0:i1] = (t[i0:i1] - t[i0]) / per
        rate[i0:i1] = 60.0 / per
    phase[~ok] = np.nan  # no pose, no phase (even inside a whole breath)
    rate[~ok] = np.nan
    out.bounds, out.n_rows = bounds, F
    out.breaths = _with_cycles(
        _breath_bounds(t, x, cross, troughs, c_seen, c_seg, c_bounds, out.span_s, period), out.cycles
    )
    return out


def _with_cycles(fitted: list, cycles: list) -> list:
    """The breaths fitted, checked against the cycles seen whole (trough to trough in one
    stretch, a peak between): a fitted breath overlapping a cycle without being it (a shallow
    breath that never crossed the middle merged into its neighbour) is left out, and every cycle
    no fitted breath is stands as a breath of its own."""
    whole = [(c.t_start, c.t_end, TROUGH_S * np.sqrt(2.0)) for c in cycles]

    def same(a, b):
        return abs(a[0] - b[0]) <= SAME_S and abs(a[1] - b[1]) <= SAME_S

    def clash(a, b):
        return min(a[1], b[1]) - max(a[0], b[0]) > SAME_S and not same(a, b)

    kept = [b for b in fitted if not any(clash(b, c) for c in whole)]
    kept += [c for c in whole if not any(same(c, b) for b in kept) and not any(clash(c, b) for b in kept)]
    return sorted(kept)


def _span_s(cross, seen, seg) -> float:
    """The longest gap a crossing-to-crossing period may span: :data:`SPAN_K` of the shortest
    half breath (a crossing of the middle to the next, the other way) seen in one stretch -- a
    gap shorter than any excursion past the middle cannot hide one, so the crossings on its two
    sides are one breath apart however many are hidden; 0 when fewer than :data:`MIN_HALVES`
    half breaths were seen (then no period spans a gap)."""
    halves = [
        t1 - t0
        for (_, t0, i0), (_, t1, i1) in zip(cross[:-1], cross[1:])
        if t0 is not None
        and t1 is not None
        and seg[i0] == seg[i1]
        and seen(i0, CROSS_EDGE_S)
        and seen(i1, CROSS_EDGE_S)
    ]
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


def _union_s(intervals) -> float:
    total, end = 0.0, -np.inf
    for a, b in sorted(intervals):
        if b > end:
            total += b - max(a, end)
            end = b
    return total


def breathing_figures(
    br: Breaths, period: float, duration_s: float, noise_mm: float, breathes: bool = True
) -> BreathingFigures:
    """The figures of the module's rules. ``breathes``: False when no marker moves at breathing
    rates at all (then ``none`` whatever the signal)."""
    noise = float(noise_mm) if np.isfinite(noise_mm) else None
    breaths = [(a, b) for a, b, _ in br.breaths]
    sig = np.array([s for *_, s in br.breaths])
    if breaths:  # a pause, or two breaths after all: not one breath
        typical = float(np.median([b - a for a, b in breaths]))
        keep = [k for k, (a, b) in enumerate(breaths) if b - a <= DOUBLED * typical]
        breaths, sig = [breaths[k] for k in keep], sig[keep]
    span_s = _union_s(breaths)
    n_ind = len(breaths)
    base: dict[str, Any] = dict(
        cycles=len(br.cycles),
        periods=n_ind,
        halves=len(br.halves),
        breaths_s=span_s,
        share=span_s / duration_s if duration_s > 0 else 0.0,
        noise_mm=noise,
    )
    floor = max(NOISE_K * (noise or 0.0), MIN_BREATH_MM)
    if not breathes:
        return BreathingFigures("none", "no marker moves at breathing rates: no breathing found", **base)
    depth = float(np.median(br.halves)) if br.halves else float(br.depth_mm)
    if depth < floor:
        return BreathingFigures(
            "none",
            f"no breathing above the noise (breaths of {depth:.2f} mm against "
            f"{floor:.2f} mm: {NOISE_K:g} x the {noise or 0:.3f} mm noise, at least "
            f"{MIN_BREATH_MM:g} mm)",
            **base,
        )
    amp = float(np.median(br.halves)) if len(br.halves) >= MIN_CYCLES else None
    if n_ind < MIN_CYCLES:
        longest = max(br.stretches_s, default=0.0)
        return BreathingFigures(
            "unknown",
            f"rate unknown: {n_ind} breath(s) seen whole, over {span_s:.1f} s of "
            f"{duration_s:.1f} s (the longest stretch seen {longest:.1f} s); a rate "
            f"needs {MIN_CYCLES}",
            amplitude_mm=amp,
            **base,
        )
    lengths = np.array([b - a for a, b in breaths])
    rates = 60.0 / lengths
    rate = float(np.median(rates))
    spread = max(1.4826 * float(np.median(np.abs(rates - rate))), SPREAD_MIN * rate)
    expected = duration_s * rate / 60.0 - 1.0  # whole breaths in the scan (its ends cut two)
    fpc = np.sqrt(max(0.0, 1.0 - n_ind / max(expected, 1.0)))
    meas = 1.2533 * float(np.sqrt(np.mean((60.0 * sig / lengths**2) ** 2))) / np.sqrt(n_ind)
    half = float(np.hypot(Z_RANGE * np.hypot(1.2533 * spread / np.sqrt(n_ind) * fpc, meas), RATE_FLOOR))
    rng = [round(rate - half, 2), round(rate + half, 2)]
    status = "measured" if half <= RATE_GOAL else "bounded"
    why = f"from {n_ind} breaths seen whole over {span_s:.1f} s ({100 * base['share']:.0f} % of the scan)" + (
        "" if status == "measured" else f": the rate is known only to {rng[0]:.1f}-{rng[1]:.1f} /min"
    )
    return BreathingFigures(status, why, rate, rng, amp, **base)


TROUGH_S = 0.06  # s: a trough's time (the flat end of an exhalation) is known to this, 1 sigma
CROSS_S = 0.03  # s: a crossing of the middle (steep) at least this
PRIOR_K = 0.35  # a breath with nothing seen of it: its length the typical one to this share, 1 sigma
OUTLIER_K = 4.0  # a landmark this many sigma off the breaths' fit is not of a normal breath
SAME_S = 0.4  # s: a fitted breath and a cycle seen whole whose ends are this close are one
KEEP_S = 0.30  # s: a breath whose length is known to worse than this (1 sigma) is not used


def _breath_bounds(t, x, cross, troughs, seen, seg, bounds, span_s: float, period: float) -> list:
    """Each breath in a chain of stretches (joined across gaps shorter than ``span_s``, which
    cannot hide a breath: its crossings are all there, hidden or not) as ``(t0, t1, sigma_s)``:
    its start and end (the troughs before its inhalation and the next) from every landmark of it
    seen -- the troughs, and its up and down crossings of the middle, placed in the breath by the
    share of it at which they come in the breaths seen whole -- by least squares; ``sigma_s``
    the 1-sigma error of its length. Breaths whose length is not known to ``KEEP_S``, or whose
    landmarks do not fit one breath (a pause, a deep breath), are left out."""
    if not cross:
        return []
    chain = np.full(len(bounds), -1)
    g = -1
    for k in range(len(bounds)):
        if k == 0 or (bounds[k][0] - bounds[k - 1][1]) * period > span_s:
            g += 1
        chain[k] = g
    lows = np.asarray(troughs, int)
    slots = []  # per chain: [[trough time|None, up time|None, down time|None], ...]
    for c in range(g + 1):
        cs = [(s, tt, j) for s, tt, j in cross if seg[j] >= 0 and chain[seg[j]] == c]
        if not cs:
            continue
        rows = [r for k in np.flatnonzero(chain == c) for r in range(*bounds[k])]
        lo_row, hi_row = rows[0], rows[-1]
        breaths = []  # one per up-crossing: [trough before it, up, down after it]
        prev_row = lo_row
        for s, tt, j in cs:
            if s > 0:
                tr = lows[(lows > prev_row) & (lows < j)]
                tr_t = None
                if tr.size:
                    r = int(tr[np.argmin(x[tr])])
                    tr_t = float(t[r]) if seen(r) else None
                up = tt if tt is not None and seen(j, CROSS_EDGE_S) else None
                breaths.append([tr_t, up, None])
            else:
                if breaths:
                    breaths[-1][2] = tt if tt is not None and seen(j, CROSS_EDGE_S) else None
            prev_row = j
        if cs[-1][0] < 0 and breaths:  # the trough after the last down-crossing
            tr = lows[(lows > prev_row) & (lows <= hi_row)]
            end_t = None
            if tr.size:
                r = int(tr[np.argmin(x[tr])])
                end_t = float(t[r]) if seen(r) else None
            breaths.append([end_t, None, None])
        slots.append(breaths)
    # the shares of a breath at which its crossings come, from the breaths seen whole
    typ, a_s, d_s = [], [], []
    for br in slots:
        for (t0, u, d), (t1, _, _) in zip(br[:-1], br[1:]):
            if t0 is not None and t1 is not None and t1 > t0:
                typ.append(t1 - t0)
                if u is not None and t0 < u < t1:
                    a_s.append((u - t0) / (t1 - t0))
                if d is not None and t0 < d < t1:
                    d_s.append((d - t0) / (t1 - t0))
    if not typ:
        return []
    L = float(np.median(typ))
    use_cross = min(len(a_s), len(d_s)) >= MIN_CYCLES
    if use_cross:
        fa, fd = float(np.median(a_s)), float(np.median(d_s))
        sa = max(1.4826 * float(np.median(np.abs(np.array(a_s) - fa))) * L, CROSS_S)
        sd = max(1.4826 * float(np.median(np.abs(np.array(d_s) - fd))) * L, CROSS_S)
    out = []
    for br in slots:
        n = len(br)  # boundaries B_0 .. B_{n-1}; breath i from B_i to B_{i+1}
        if n < 2:
            continue
        coefs: list[list[float]] = []
        values: list[float] = []
        weights: list[float] = []
        own: list = []

        def obs(
            coef,
            value,
            sigma,
            tag,  # one landmark: sum(coef[k] * B_k) = value, to sigma
            n=n,
            coefs=coefs,
            values=values,
            weights=weights,
            own=own,
        ):
            coefs.append([coef.get(k, 0.0) for k in range(n)])
            values.append(value)
            weights.append(1.0 / sigma)
            own.append(tag)

        for i, (tr_t, u, d) in enumerate(br):
            if tr_t is not None:
                obs({i: 1.0}, tr_t, TROUGH_S, ("b", i))
            if use_cross and i + 1 < n:
                if u is not None:
                    obs({i: 1.0 - fa, i + 1: fa}, u, sa, ("c", i))
                if d is not None:
                    obs({i: 1.0 - fd, i + 1: fd}, d, sd, ("c", i))
        if not coefs:
            continue
        for i in range(n - 1):  # a weak prior: a breath is about the typical length
            obs({i: -1.0, i + 1: 1.0}, L, PRIOR_K * L, None)
        # the chain's place, when only the prior speaks of a boundary: keeps the fit solvable
        obs({0: 1.0}, float(next(v for b in br for v in b if v is not None)), 1e6, None)
        A, y, w = np.array(coefs), np.array(values), np.array(weights)
        use = np.ones(len(y), bool)
        bad = set()
        for _ in range(len(y)):  # the landmark furthest off one breath's shape out, until all fit
            Aw = A[use] * w[use, None]
            cov = np.linalg.pinv(Aw.T @ Aw)
            B = cov @ (Aw.T @ (y[use] * w[use]))
            res = np.where(use, (y - A @ B) * w, 0.0)
            k = int(np.argmax(np.abs(res)))
            if abs(res[k]) <= OUTLIER_K:
                break
            use[k] = False
            bad.add(own[k])
        for i in range(n - 1):
            var = cov[i, i] + cov[i + 1, i + 1] - 2 * cov[i, i + 1]
            s = float(np.sqrt(max(var, 0.0)))
            if s > KEEP_S or {("b", i), ("b", i + 1), ("c", i)} & bad:
                continue
            out.append((float(B[i]), float(B[i + 1]), s))
    return out
