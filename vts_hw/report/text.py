"""Short texts shared by the HTML and PDF renderers (numbers, slopes, forecasts, periods)."""

from __future__ import annotations

import math
from html import escape

from vts_hw.report.model import CameraDrift, DriftReport, RunPoint
from vts_hw.report.times import fmt_date
from vts_hw.report.trend import SIGNIFICANCE, Forecast, Trend


def fmt_num(v, spec: str = ".3f") -> str:
    """A number, or an en dash when missing."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    text = format(v, spec)
    if text.startswith("-") and not any(c in "123456789" for c in text):  # no "-0.00"
        text = ("+" if "+" in spec else "") + text[1:]
    return text


def fmt_slope(trend: Trend, html: bool = False) -> str:
    """``+0.600 ± 0.012`` px per 30 days (± its standard error), marked n.s. when not
    significant; ``none yet`` while there are too few runs (``trend_detail`` says why)."""
    if not trend.ok:
        return "none yet"
    text = f"{trend.slope_per_30d:+.3f} ± {trend.slope_se_per_30d:.3f}"
    if trend.significant:
        return escape(text) if html else text
    return f'{escape(text)} <span class="ns">n.s.</span>' if html else text + " n.s."


def trend_detail(trend: Trend) -> str:
    """The fit in words: runs, dates, 95 % CI and p-value; or why there is no trend."""
    p_value, slope, ci = trend.p_value, trend.slope_per_30d, trend.ci95_per_30d  # set together by fit_trend
    if p_value is None or slope is None or ci is None:
        return trend.reason
    p = "p < 0.001" if p_value < 0.001 else f"p = {p_value:.3f}"
    sig = "" if trend.significant else f", not significant (p ≥ {SIGNIFICANCE:g})"
    return (
        f"{trend.n} runs, {fmt_date(trend.t0)} – {fmt_date(trend.t_end)} ({trend.span_days:.1f} days); "
        f"95 % CI {slope - ci:+.3f} … {slope + ci:+.3f}"
        f" px/30 d, {p}{sig}; residual SD {trend.residual_sd:.3f} px"
    )


def forecast_text(f: Forecast) -> str:
    return f.label(fmt_date)


def forecast_detail(f: Forecast) -> str:
    """The forecast with its reason when there is no date."""
    if f.status == "no fit":
        return "none (no trend yet)"
    if f.status == "not significant":
        return "none (the slope is not significant)"
    if f.status == "no limit" and f.reason:
        return f"none ({f.reason})"
    return f.label(fmt_date)


def latest_text(cam: CameraDrift, p: RunPoint | None, axis: str) -> str:
    """``+0.52 (+0.65)``: the latest drift in px and, in brackets, mm at the wall."""
    if p is None:
        return "–"
    if not p.drift_measured:
        return "not measured"
    px = p.values.get(f"drift_{axis}_px")
    mm = p.values.get(f"drift_{axis}_mm")
    return f"{fmt_num(px, '+.2f')} ({fmt_num(mm, '+.2f')})"


def led_text(cam: CameraDrift) -> str:
    """The LED check over the period: ``OK (58 runs)`` or ``failed 1 of 58, last 2026-...``."""
    runs = [p for p in cam.points if "led_off_visible" in p.values]
    bad = cam.events("led_off_visible")
    if not runs:
        return "not measured"
    if not bad:
        return f"OK ({len(runs)} runs)"
    return f"failed {len(bad)}× of {len(runs)} runs, last {fmt_date(bad[-1].t)}"


def period_text(report: DriftReport) -> str:
    rig = f"rig {report.rig} · " if report.rig else ""
    start = fmt_date(report.period_start) if report.period_start is not None else "the first run"
    return f"{rig}period {start} – {fmt_date(report.now)}"


def camera_forecast_text(cam: CameraDrift) -> tuple[str, bool]:
    """The camera's action-level forecast for a summary, and whether it falls within a year.

    The earliest axis within a year (``2026-09-23 (y)``); else ``not within a year`` when a
    significant trend points far away; else why there is no forecast: ``none yet (3 runs / 0.0 d)``
    (too few runs for a trend) or ``none: trend not significant``.
    """
    nf = cam.nearest_forecast()
    if nf:
        return f"{forecast_text(nf[1])} ({nf[0]})", True
    fs = [s.forecast for s in cam.axes.values()]
    if any(f.status in ("beyond horizon", "away") for f in fs):
        return "not within a year", False
    if any(f.status == "no limit" for f in fs):
        return "no action level", False
    if any(f.status == "not significant" for f in fs):
        return "none: trend not significant", False
    trend = next(iter(cam.axes.values())).trend
    return f"none yet ({trend.short_reason})" if trend.short_reason else "none", False
