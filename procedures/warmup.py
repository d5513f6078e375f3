"""Has a camera's picture settled after it started? The commissioning's warm-up (issue 24 §3).

A fixed camera's picture drifts for minutes after it starts (it warms). Before calibration the
room must wait until it stops. For each camera, with the LED on:

1. a sample: ``frames`` snapshots, the wall markers found and matched as the daily drift QA
   does it (vision/detect.py, procedures/drift.py): the first sample is the reference (there is
   no drift baseline yet), every later one gives the markers' mean displacement from it;
2. every ``interval_s`` another sample; over the last ``samples`` ones the rate (px/min) is
   fitted (a straight line per image axis: the rate is the length of its slope vector);
3. a camera has settled when its rate is inside the ``warmup_rate_px_min`` window (default
   OK ≤ 0.05 px/min) *and* it has run at least its ``warmup_min`` (whatever its rate);
4. how long to wait: the rest of its ``warmup_min``, and, when the rate measurably slows in the
   window, the time until it is below the limit (an exponential settling: the slowing over the
   window gives its time constant). When it does not measurably slow, that time is not known
   (said, never guessed).

:func:`fit_rate` is the fit; :class:`Watch` takes the samples; the step (commission_steps.py)
waits or stops. docs/decisions/0072-warm-up-settling.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vts_hw.camera import Camera
from vts_hw.procedures.drift import DriftAnalysis
from vts_hw.vision.wall_baseline import Baseline
from vts_hw.vision.wall_markers import baseline_from_frames

__all__ = ["RateFit", "fit_rate", "Sample", "Watch", "settle_wait_min"]


@dataclass(frozen=True)
class RateFit:
    """The fitted rate over a window: ``rate`` (None: too few samples to fit it), its standard
    error ``se``, the window's length (min), and, when the rate slows measurably, the time
    constant of its settling (``tau_min``) and the rate at the window's end. The unit is the
    caller's: px/min for a picture, ppm/min for the change of a clock's rate (procedures/warmup_clock.py)."""

    rate: float | None
    se: float | None = None
    window_min: float = 0.0
    n: int = 0
    tau_min: float | None = None
    rate_end: float | None = None
    signed: float | None = None  # one axis: the rate with its sign

    def minutes_to(self, limit: float) -> float | None:
        """Minutes from the window's end until the rate is below ``limit``; None when the fit
        cannot tell (it does not slow measurably)."""
        if self.rate is None:
            return None
        if self.rate <= limit:
            return 0.0
        if self.tau_min is None or not self.rate_end:
            return None
        return max(0.0, self.tau_min * math.log(self.rate_end / limit))


def fit_rate(times_s, positions, order: int = 1, scale: float = 1.0, sigma: float = 0.0) -> RateFit:
    """The rate of positions (n x k) taken at ``times_s`` (epoch s), per minute: the ``order``-th
    time derivative of a polynomial of that degree per axis (order 1, a straight line: a picture's
    px/min; order 2, a parabola: how fast a clock's rate changes), times ``scale``, the length of
    its vector. With ``order + 3`` samples or more, a polynomial one degree higher too: the
    slowing along the rate (the next derivative against it), significant at 3 standard errors,
    gives the time constant of an exponential settling. ``sigma``: each position's own standard
    uncertainty (its units, before ``scale``), the least noise the fit assumes: a few readings of
    a coarse resolution can fit a polynomial exactly, and their residuals alone would then claim
    no uncertainty at all."""
    t = np.asarray(times_s, float) / 60.0
    p = np.asarray(positions, float)
    p = p.reshape(len(t), -1) if p.size else p.reshape(0, 1)
    ok = np.isfinite(p).all(axis=1) & np.isfinite(t)
    t, p = t[ok], p[ok] * scale
    n, k = len(t), p.shape[1]
    if n < order + 2 or np.ptp(t) <= 0:
        return RateFit(None, n=n, window_min=float(np.ptp(t)) if n else 0.0)
    tc = t - t.mean()

    def poly(deg):
        X = np.column_stack([tc**j / math.factorial(j) for j in range(deg + 1)])
        coef, *_ = np.linalg.lstsq(X, p, rcond=None)
        res = p - X @ coef
        s2 = float((res**2).sum()) / (k * max(1, n - deg - 1))  # every axis shares one noise
        s2 = max(s2, (sigma * scale) ** 2)
        return coef, s2 * np.linalg.inv(X.T @ X)

    coef, cov = poly(order)
    v = coef[order]
    rate = float(np.linalg.norm(v))
    se = math.sqrt(max(cov[order, order], 0.0))
    signed = float(v[0]) if k == 1 else None
    fit = RateFit(rate, se, float(np.ptp(t)), n, signed=signed)
    if n < order + 3 or rate == 0.0:
        return fit
    coef2, cov2 = poly(order + 1)
    slowing = -float(coef2[order + 1] @ (v / rate))  # the next derivative against the rate
    se_next = math.sqrt(max(cov2[order + 1, order + 1], 0.0))
    if slowing <= 0 or slowing < 3 * se_next:
        return fit
    tau = rate / slowing
    end = rate * math.exp(-float(tc.max()) / tau)
    return RateFit(rate, se, float(np.ptp(t)), n, tau, end, signed)


def settle_wait_min(
    fit: RateFit,
    limit: float,
    uptime_min: float | None,
    warmup_min: float,
    unit: str = "px/min",
    what: str = "the rate",
) -> tuple[float | None, str, bool]:
    """(minutes to wait, why, at least) for one camera: the longer of the rest of its warm-up
    time and the time its rate takes to fall below ``limit``. When the rate is above the limit
    and does not measurably slow, that time is not known: the rest of the warm-up time is then
    a lower bound (``at least`` True), and with none left the minutes are None (never guessed)."""
    by_uptime = None if uptime_min is None else max(0.0, warmup_min - uptime_min)
    by_rate = fit.minutes_to(limit)
    parts = []
    if by_uptime:
        parts.append(f"{by_uptime:.0f} min more of its {warmup_min:g} min warm-up time")
    unknown = fit.rate is not None and fit.rate > limit and by_rate is None
    if fit.rate is not None and fit.rate > limit:
        parts.append(
            f"{what} slowing with a time constant of {fit.tau_min:.0f} min: {by_rate:.0f} min to {limit:g} {unit}"
            if by_rate is not None
            else f"{what} not slowing measurably over {fit.window_min:.1f} min: how long is not known"
        )
    if unknown:
        return (by_uptime or None), "; ".join(parts), True
    return max(by_uptime or 0.0, by_rate or 0.0), "; ".join(parts), False


@dataclass
class Sample:
    t: float  # the picture's time (camera clock; host receive time without one)
    dx: float
    dy: float
    markers: int


@dataclass
class Watch:
    """The samples of one camera (opened by the caller); the first one is the reference."""

    cam: Camera
    frames: int = 3
    reference: Baseline | None = None
    samples: list[Sample] = field(default_factory=list)

    def sample(self) -> Sample:
        snaps = [self.cam.snapshot() for _ in range(self.frames)]
        t = float(np.mean([f.camera_time if f.camera_time is not None else f.host_time for f in snaps]))
        jpegs = [f.jpeg for f in snaps]
        if self.reference is None or not self.reference.markers:
            self.reference = baseline_from_frames(self.cam.name, jpegs, t)
        if not self.reference.markers:
            s = Sample(t, math.nan, math.nan, 0)
        else:
            a = DriftAnalysis.from_frames(self.cam.name, self.reference, jpegs, None).analyze()
            s = Sample(t, *a.drift_px, len(self.reference.markers) - len(a.missing))
        self.samples.append(s)
        return s

    def fit(self, last: int) -> RateFit:
        got = self.samples[-last:]
        return fit_rate([s.t for s in got], [(s.dx, s.dy) for s in got])
