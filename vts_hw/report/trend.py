"""The numbers behind the drift report: control limits, linear trend and action-level forecast.

Pure functions of arrays (times in UTC epoch seconds, drift in pixels); no store, no plotting.

- Control limits: mean ± 3 SD (sample SD) of the first ``CONTROL_RUNS`` runs after the latest
  baseline. Until that many runs exist the limits are *pending* (a few runs give an SD too
  unreliable to judge anything by).
- Trend: ordinary least squares of drift on time over every run since the latest baseline; the
  slope is given per 30 days with its standard error.
- Forecast: where the fitted line meets the action level that lies in the direction of the
  slope. More than ``HORIZON_DAYS`` ahead, or a slope away from the limit, is "not within a year".
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

DAY = 86400.0
CONTROL_RUNS = 10
CONTROL_K = 3.0
HORIZON_DAYS = 365.0
SLOPE_PERIOD_DAYS = 30.0
MIN_FIT_RUNS = 3

CONTROL_METHOD = (f"mean ± {CONTROL_K:g} SD of the first {CONTROL_RUNS} completed runs after the "
                  f"latest baseline, per axis")


@dataclass(frozen=True)
class ControlLimits:
    """Control limits of one axis. ``mean``/``lower``/``upper`` are None while pending."""
    n: int                      # runs used (at most CONTROL_RUNS)
    start: float | None         # time of the first and last run used
    end: float | None
    mean: float | None = None
    sd: float | None = None
    lower: float | None = None
    upper: float | None = None

    @property
    def pending(self) -> bool:
        return self.mean is None

    def as_dict(self) -> dict:
        return {**asdict(self), "pending": self.pending}


@dataclass(frozen=True)
class Forecast:
    """When the fitted line reaches the action level.

    ``status`` is one of: ``date`` (``t`` is the crossing, within the horizon), ``reached`` (the
    fitted line is already beyond the level: ``t`` is when it crossed), ``beyond horizon``,
    ``away`` (slope away from the limit or zero), ``no limit`` (no action level that way),
    ``no fit``.
    """
    status: str
    t: float | None = None
    level: float | None = None  # the action level aimed at (px)

    @property
    def within_year(self) -> bool:
        return self.status in ("date", "reached")

    def label(self, fmt_date) -> str:
        """Short text for a table: a date, or why there is none."""
        if self.status == "date":
            return fmt_date(self.t)
        if self.status == "reached":
            return f"reached {fmt_date(self.t)} (fit)"
        if self.status in ("beyond horizon", "away"):
            return "not within a year"
        if self.status == "no limit":
            return "no action level"
        return "too few runs"

    def as_dict(self) -> dict:
        return {**asdict(self), "within_year": self.within_year}


@dataclass(frozen=True)
class Trend:
    """A least-squares line ``drift = intercept + slope * (t - t0) / DAY`` (px, px/day)."""
    n: int
    t0: float | None = None
    t_end: float | None = None
    intercept: float | None = None
    slope_per_day: float | None = None
    slope_se_per_day: float | None = None
    residual_sd: float | None = None

    @property
    def ok(self) -> bool:
        return self.slope_per_day is not None

    @property
    def slope_per_30d(self) -> float | None:
        return None if self.slope_per_day is None else self.slope_per_day * SLOPE_PERIOD_DAYS

    @property
    def slope_se_per_30d(self) -> float | None:
        return None if self.slope_se_per_day is None else self.slope_se_per_day * SLOPE_PERIOD_DAYS

    @property
    def significant(self) -> bool:
        """Slope at least twice its standard error (about 95 %)."""
        return self.ok and abs(self.slope_per_day) >= 2 * self.slope_se_per_day

    def at(self, t):
        """Fitted drift at time(s) ``t`` (epoch seconds)."""
        return self.intercept + self.slope_per_day * (np.asarray(t, dtype=float) - self.t0) / DAY

    def as_dict(self) -> dict:
        return {**asdict(self), "slope_per_30d": self.slope_per_30d,
                "slope_se_per_30d": self.slope_se_per_30d, "significant": self.significant}


def _finite(t, v):
    t = np.asarray(t, dtype=float)
    v = np.asarray(v, dtype=float)
    keep = np.isfinite(t) & np.isfinite(v)
    return t[keep], v[keep]


def control_limits(t, v, n_runs: int = CONTROL_RUNS, k: float = CONTROL_K) -> ControlLimits:
    """Mean ± k SD of the first ``n_runs`` values (by time); pending with fewer values."""
    t, v = _finite(t, v)
    order = np.argsort(t, kind="stable")
    t, v = t[order][:n_runs], v[order][:n_runs]
    if len(v) == 0:
        return ControlLimits(n=0, start=None, end=None)
    start, end = float(t[0]), float(t[-1])
    if len(v) < n_runs:
        return ControlLimits(n=len(v), start=start, end=end)
    mean = float(np.mean(v))
    sd = float(np.std(v, ddof=1))
    return ControlLimits(n=len(v), start=start, end=end, mean=mean, sd=sd,
                         lower=mean - k * sd, upper=mean + k * sd)


def fit_trend(t, v) -> Trend:
    """Least-squares line through (t, v) with the slope's standard error.

    Needs ``MIN_FIT_RUNS`` points spread over time; otherwise ``Trend.ok`` is False.
    """
    t, v = _finite(t, v)
    n = len(v)
    if n < MIN_FIT_RUNS or np.ptp(t) <= 0:
        return Trend(n=n)
    t0 = float(t.min())
    d = (t - t0) / DAY
    dm = d.mean()
    sxx = float(np.sum((d - dm) ** 2))
    slope = float(np.sum((d - dm) * (v - v.mean())) / sxx)
    intercept = float(v.mean() - slope * dm)
    resid = v - (intercept + slope * d)
    s2 = float(np.sum(resid ** 2) / (n - 2))
    return Trend(n=n, t0=t0, t_end=float(t.max()), intercept=intercept, slope_per_day=slope,
                 slope_se_per_day=math.sqrt(s2 / sxx), residual_sd=math.sqrt(s2))


def forecast(trend: Trend, action_low: float | None, action_high: float | None, now: float,
             horizon_days: float = HORIZON_DAYS) -> Forecast:
    """When the fitted line meets the action level in the direction of its slope."""
    if not trend.ok:
        return Forecast("no fit")
    b = trend.slope_per_day
    if b == 0:
        return Forecast("away")
    level = action_high if b > 0 else action_low
    if level is None:
        return Forecast("no limit")
    t_cross = trend.t0 + (level - trend.intercept) / b * DAY
    if t_cross <= now:
        # moving towards this level, the line has met it already (possibly before the fit began)
        return Forecast("reached", t=float(t_cross), level=level)
    if t_cross - now > horizon_days * DAY:
        return Forecast("beyond horizon", t=float(t_cross), level=level)
    return Forecast("date", t=float(t_cross), level=level)
