"""Short texts shared by the HTML and PDF renderers (numbers, slopes, forecasts, periods)."""

from __future__ import annotations

import math
from html import escape

from .model import CameraDrift, DriftReport, RunPoint
from .times import fmt_date
from .trend import Forecast, Trend


def fmt_num(v, spec: str = ".3f") -> str:
    """A number, or an en dash when missing."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "–"
    return format(v, spec)


def fmt_slope(trend: Trend, html: bool = False) -> str:
    """``+0.600 ± 0.012`` px per 30 days, marked n.s. when below twice its standard error."""
    if not trend.ok:
        return "–"
    text = f"{trend.slope_per_30d:+.3f} ± {trend.slope_se_per_30d:.3f}"
    if trend.significant:
        return escape(text) if html else text
    return f'{escape(text)} <span class="ns">n.s.</span>' if html else text + " n.s."


def forecast_text(f: Forecast) -> str:
    return f.label(fmt_date)


def latest_text(cam: CameraDrift, p: RunPoint | None, axis: str) -> str:
    """``+0.52 (+0.65)``: the latest drift in px and, in brackets, mm at the wall."""
    if p is None:
        return "–"
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

    The earliest axis within a year (``2026-09-23 (y)``); else ``not within a year`` when at least
    one axis has a trend, else why there is none (``too few runs``).
    """
    nf = cam.nearest_forecast()
    if nf:
        return f"{forecast_text(nf[1])} ({nf[0]})", True
    if any(s.trend.ok for s in cam.axes.values()):
        return "not within a year", False
    return forecast_text(next(iter(cam.axes.values())).forecast), False
