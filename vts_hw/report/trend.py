"""The numbers behind the drift report: control limits, linear trend and action-level forecast.

Pure functions of arrays (times in UTC epoch seconds, drift in pixels); no store, no plotting.

- Control limits: mean ± 3 SD (sample SD) of the first ``CONTROL_RUNS`` runs after the latest
  baseline. Until that many runs exist the limits are *pending* (a few runs give an SD too
  unreliable to judge anything by).
- Trend: ordinary least squares of drift on time (``scipy.stats.linregress``) over every run
  since the latest baseline, only once there are at least ``MIN_TREND_RUNS`` runs spanning at
  least ``MIN_TREND_DAYS`` days (a few runs minutes apart say nothing about a drift of months:
  their noise divided by minutes is a huge, meaningless slope). The slope is given per 30 days
  with its standard error, its 95 % confidence interval and the p-value of "no slope".
- Forecast: where the fitted line meets the action level that lies in the direction of the
  slope, only when the slope is significant (p < ``SIGNIFICANCE``); more than ``HORIZON_DAYS``
  ahead is "not within a year". Every "no" carries its reason in words.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy import stats

DAY = 86400.0
CONTROL_RUNS = 10
CONTROL_K = 3.0
HORIZON_DAYS = 365.0
SLOPE_PERIOD_DAYS = 30.0
MIN_TREND_RUNS = 5  # a working week of daily QA
MIN_TREND_DAYS = 7.0  # a calendar week: longer than any one day's noise or a weekend gap
SIGNIFICANCE = 0.05  # a forecast only when p(slope = 0) is below this

CONTROL_METHOD = (
    f"mean ± {CONTROL_K:g} SD of the first {CONTROL_RUNS} completed runs after the latest baseline, per axis"
)
TREND_RULE = (
    f"a trend needs {MIN_TREND_RUNS} runs over {MIN_TREND_DAYS:g} days since the latest "
    f"baseline; a forecast needs a significant slope (p < {SIGNIFICANCE:g}) and a crossing "
    f"within {HORIZON_DAYS:g} days"
)


@dataclass(frozen=True)
class ControlLimits:
    """Control limits of one axis. ``mean``/``lower``/``upper`` are None while pending."""

    n: int  # runs used (at most CONTROL_RUNS)
    start: float | None  # time of the first and last run used
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
class Trend:
    """A least-squares line ``drift = intercept + slope * (t - t0) / DAY`` (px, px/day).

    ``ok`` False (no slope) when the runs are too few or span too short a time: ``reason`` says
    which, in words.
    """

    n: int
    span_days: float = 0.0
    t0: float | None = None
    t_end: float | None = None
    intercept: float | None = None
    slope_per_day: float | None = None
    slope_se_per_day: float | None = None
    ci95_per_day: float | None = None  # half-width of the slope's 95 % confidence interval
    p_value: float | None = None  # of the hypothesis "slope = 0" (two-sided t-test)
    residual_sd: float | None = None

    @property
    def ok(self) -> bool:
        return self.slope_per_day is not None

    @property
    def reason(self) -> str:
        """Why there is no trend ('' when there is one)."""
        if self.ok:
            return ""
        runs = "1 run" if self.n == 1 else f"{self.n} runs"
        return (
            f"{runs} over {self.span_days:.1f} days: a trend needs {MIN_TREND_RUNS} runs over {MIN_TREND_DAYS:g} days"
        )

    @property
    def short_reason(self) -> str:
        """``3 runs / 0.0 d`` (for a table cell)."""
        runs = "1 run" if self.n == 1 else f"{self.n} runs"
        return "" if self.ok else f"{runs} / {self.span_days:.1f}\u00a0d"  # no line break before "d"

    def _per_30d(self, v):
        return None if v is None else v * SLOPE_PERIOD_DAYS

    @property
    def slope_per_30d(self) -> float | None:
        return self._per_30d(self.slope_per_day)

    @property
    def slope_se_per_30d(self) -> float | None:
        return self._per_30d(self.slope_se_per_day)

    @property
    def ci95_per_30d(self) -> float | None:
        return self._per_30d(self.ci95_per_day)

    @property
    def significant(self) -> bool:
        """The slope differs from zero at the ``SIGNIFICANCE`` level."""
        return self.ok and self.p_value is not None and self.p_value < SIGNIFICANCE

    def at(self, t):
        """Fitted drift at time(s) ``t`` (epoch seconds)."""
        return self.intercept + self.slope_per_day * (np.asarray(t, dtype=float) - self.t0) / DAY

    def as_dict(self) -> dict:
        return {
            **asdict(self),
            "slope_per_30d": self.slope_per_30d,
            "slope_se_per_30d": self.slope_se_per_30d,
            "ci95_per_30d": self.ci95_per_30d,
            "significant": self.significant,
            "reason": self.reason,
        }


@dataclass(frozen=True)
class Forecast:
    """When the fitted line reaches the action level.

    ``status`` is one of: ``date`` (``t`` is the crossing, within the horizon), ``reached`` (the
    fitted line is already beyond the level: ``t`` is when it crossed), ``beyond horizon``,
    ``away`` (a zero slope), ``no limit`` (no action level that way), ``not significant``
    (a slope that may be noise: no date is given), ``no fit`` (no trend). ``reason`` says in
    words why there is no date.
    """

    status: str
    t: float | None = None
    level: float | None = None  # the action level aimed at (px)
    reason: str = ""

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
        if self.status == "not significant":
            return "none: trend not significant"
        return "none: too few runs for a trend"

    def as_dict(self) -> dict:
        return {**asdict(self), "within_year": self.within_year}


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
    return ControlLimits(n=len(v), start=start, end=end, mean=mean, sd=sd, lower=mean - k * sd, upper=mean + k * sd)


def fit_trend(t, v, min_runs: int = MIN_TREND_RUNS, min_days: float = MIN_TREND_DAYS) -> Trend:
    """Least-squares line through (t, v) with the slope's standard error, 95 % CI and p-value.

    Needs ``min_runs`` finite points spanning ``min_days``; otherwise ``Trend.ok`` is False and
    ``Trend.reason`` says why.
    """
    t, v = _finite(t, v)
    n = len(v)
    span = float(np.ptp(t)) / DAY if n else 0.0
    if n < max(min_runs, 3) or span < min_days or span <= 0:
        return Trend(n=n, span_days=span)
    t0 = float(t.min())
    d = (t - t0) / DAY
    fit = stats.linregress(d, v)
    slope, se = float(fit.slope), float(fit.stderr)
    resid = v - (fit.intercept + slope * d)
    s2 = float(np.sum(resid**2) / (n - 2))
    p = float(fit.pvalue) if math.isfinite(fit.pvalue) else (0.0 if se == 0 and slope != 0 else 1.0)
    return Trend(
        n=n,
        span_days=span,
        t0=t0,
        t_end=float(t.max()),
        intercept=float(fit.intercept),
        slope_per_day=slope,
        slope_se_per_day=se,
        ci95_per_day=float(stats.t.ppf(0.975, n - 2)) * se,
        p_value=p,
        residual_sd=math.sqrt(s2),
    )


def forecast(
    trend: Trend, action_low: float | None, action_high: float | None, now: float, horizon_days: float = HORIZON_DAYS
) -> Forecast:
    """When the fitted line meets the action level in the direction of its slope.

    No date unless the trend exists and its slope is significant."""
    b, t0, intercept = trend.slope_per_day, trend.t0, trend.intercept  # set together by fit_trend
    if b is None or t0 is None or intercept is None:
        return Forecast("no fit", reason=trend.reason)
    if not trend.significant:
        return Forecast(
            "not significant",
            reason=(
                f"the slope {trend.slope_per_30d:+.3f} ± {trend.slope_se_per_30d:.3f} px/30 d is not "
                f"significant (p = {trend.p_value:.2f}, needs < {SIGNIFICANCE:g})"
            ),
        )
    if b == 0:
        return Forecast("away", reason="the slope is zero")
    level = action_high if b > 0 else action_low
    if level is None:
        return Forecast("no limit", reason=f"no action level {'above' if b > 0 else 'below'}")
    t_cross = t0 + (level - intercept) / b * DAY
    if t_cross <= now:
        # moving towards this level, the line has met it already (possibly before the fit began)
        return Forecast("reached", t=float(t_cross), level=level)
    if t_cross - now > horizon_days * DAY:
        return Forecast(
            "beyond horizon",
            t=float(t_cross),
            level=level,
            reason=f"the line reaches {level:+g} px more than {horizon_days:g} days ahead",
        )
    return Forecast("date", t=float(t_cross), level=level)
