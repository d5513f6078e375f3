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

from vts_hw.procedures.drift import DriftAnalysis
from vts_hw.vision.wall_baseline import Baseline

__all__ = ["RateFit", "fit_rate", "Sample", "Watch", "settle_wait_min"]


@dataclass(frozen=True)
class RateFit:
    """The fitted rate over a window: ``rate_px_min`` (None: fewer than 3 samples with markers),
    its standard error, the window's length (min), and, when the rate slows measurably, the time
    constant of its settling (``tau_min``) and the rate at the window's end."""

    rate_px_min: float | None
    se_px_min: float | None = None
    window_min: float = 0.0
    n: int = 0
    tau_min: float | None = None
    rate_end_px_min: float | None = None

    def minutes_to(self, limit: float) -> float | None:
        """Minutes from the window's end until the rate is below ``limit``; None when the fit
        cannot tell (it does not slow measurably)."""
        if self.rate_px_min is None:
            return None
        if self.rate_px_min <= limit:
            return 0.0
        if self.tau_min is None or not self.rate_end_px_min:
            return None
        return max(0.0, self.tau_min * math.log(self.rate_end_px_min / limit))


def fit_rate(times_s, positions) -> RateFit:
    """The rate (px/min) of positions (n x 2, px) taken at ``times_s`` (epoch s): a straight line
    per axis (with 4 samples or more, a parabola too: the slowing along the motion, significant
    at 3 standard errors, gives the time constant of an exponential settling)."""
    t = np.asarray(times_s, float) / 60.0
    p = np.asarray(positions, float).reshape(-1, 2)
    ok = np.isfinite(p).all(axis=1) & np.isfinite(t)
    t, p = t[ok], p[ok]
    n = len(t)
    if n < 3 or np.ptp(t) <= 0:
        return RateFit(None, n=n, window_min=float(np.ptp(t)) if n else 0.0)
    tc = t - t.mean()
    sxx = float((tc ** 2).sum())
    v = (tc[:, None] * (p - p.mean(axis=0))).sum(axis=0) / sxx
    res = p - p.mean(axis=0) - tc[:, None] * v
    s2 = float((res ** 2).sum()) / (2 * (n - 2))            # both axes share one noise
    rate = float(np.hypot(*v))
    se = math.sqrt(s2 / sxx)
    fit = RateFit(rate, se, float(np.ptp(t)), n)
    if n < 4 or rate == 0.0:
        return fit
    X = np.column_stack([np.ones(n), tc, 0.5 * tc ** 2])
    coef, *_ = np.linalg.lstsq(X, p, rcond=None)
    res2 = p - X @ coef
    q2 = float((res2 ** 2).sum()) / (2 * max(1, n - 3))
    cov = q2 * np.linalg.inv(X.T @ X)
    u = v / rate
    slowing = -float(coef[2] @ u)                           # the acceleration against the motion
    se_acc = math.sqrt(max(cov[2, 2], 0.0))
    if slowing <= 0 or slowing < 3 * se_acc:
        return fit
    tau = rate / slowing
    end = rate * math.exp(-float(tc.max()) / tau)
    return RateFit(rate, se, float(np.ptp(t)), n, tau, end)


def settle_wait_min(fit: RateFit, limit: float, uptime_min: float | None,
                    warmup_min: float) -> tuple[float | None, str, bool]:
    """(minutes to wait, why, at least) for one camera: the longer of the rest of its warm-up
    time and the time its rate takes to fall below ``limit``. When the rate is above the limit
    and does not measurably slow, that time is not known: the rest of the warm-up time is then
    a lower bound (``at least`` True), and with none left the minutes are None (never guessed)."""
    by_uptime = None if uptime_min is None else max(0.0, warmup_min - uptime_min)
    by_rate = fit.minutes_to(limit)
    parts = []
    if by_uptime:
        parts.append(f"{by_uptime:.0f} min more of its {warmup_min:g} min warm-up time")
    unknown = fit.rate_px_min is not None and fit.rate_px_min > limit and by_rate is None
    if fit.rate_px_min is not None and fit.rate_px_min > limit:
        parts.append(f"the rate slowing with a time constant of {fit.tau_min:.0f} min: {by_rate:.0f} min to "
                     f"{limit:g} px/min" if by_rate is not None
                     else f"the rate not slowing measurably over {fit.window_min:.1f} min: how long is not known")
    if unknown:
        return (by_uptime or None), "; ".join(parts), True
    return max(by_uptime or 0.0, by_rate or 0.0), "; ".join(parts), False


@dataclass
class Sample:
    t: float                      # the picture's time (camera clock; host receive time without one)
    dx: float
    dy: float
    markers: int


@dataclass
class Watch:
    """The samples of one camera (opened by the caller); the first one is the reference."""

    cam: object
    frames: int = 3
    reference: Baseline | None = None
    samples: list[Sample] = field(default_factory=list)

    def sample(self) -> Sample:
        snaps = [self.cam.snapshot() for _ in range(self.frames)]
        t = float(np.mean([f.camera_time if f.camera_time is not None else f.host_time for f in snaps]))
        jpegs = [f.jpeg for f in snaps]
        if self.reference is None or not self.reference.markers:
            self.reference = Baseline.from_frames(self.cam.name, jpegs, t)
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
