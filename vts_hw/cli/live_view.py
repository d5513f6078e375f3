"""The live motion view of `vts scan start`: what the live estimator says, printed (a rich
table on a terminal, a plain line otherwise). Nothing is computed here but formatting."""

from __future__ import annotations

import math

from rich.markup import escape
from rich.table import Table

SPARK = "▁▂▃▄▅▆▇█"


def sparkline(values) -> str:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    if not vals:
        return ""
    lo, hi = min(vals), max(vals)
    span = hi - lo or 1.0
    return "".join(
        " " if v is None or not math.isfinite(v) else SPARK[min(7, int((v - lo) / span * 8))] for v in values
    )


def _num(v, fmt="{:.1f}") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)


def _six(est) -> str:
    if est.six_dof is None:
        return "-"
    t, r = est.six_dof[:3], est.six_dof[3:]
    return f"T {t[0]:+.1f} {t[1]:+.1f} {t[2]:+.1f} mm  R {r[0]:+.2f} {r[1]:+.2f} {r[2]:+.2f} deg ({est.frame} frame)"


def _stats(st: dict) -> str:
    if not st:
        return ""
    drops = sum((st.get("live_dropped") or {}).values())
    return (
        f"{st.get('sets', 0)} frame sets, live latency p50 {_num(st.get('latency_ms_p50'))} ms "
        f"p95 {_num(st.get('latency_ms_p95'))} ms, {drops} dropped from the live path"
        + (f"; {st['error']}" if st.get("error") else "")
    )


def _status(est, markup: bool) -> str:
    """TRACKING / REFERENCE / NOT TRACKING, for how long, and why; the age of the figures."""
    if not est.status:  # an estimate read straight from the estimator: its phase
        return est.phase
    colour = {"TRACKING": "green", "REFERENCE": "yellow"}.get(est.status, "bold red")
    head = f"[{colour}]{est.status}[/]" if markup else est.status
    if est.status_for_s is not None and est.status != "TRACKING":
        head += f" {est.status_for_s:.1f} s"
    if est.reason:
        head += f": {escape(est.reason) if markup else est.reason}"
    return head


def _age(est) -> str:
    return "" if est.age_s is None else f"figures {est.age_s:.1f} s old"


def _pose(est) -> str:
    """The body's offset: as it is while tracked; while not, the last one and its age, never
    "still" (time without frames is time without data)."""
    if est.six_dof is None:
        return ""
    body = f"body {_num(est.move_mm)} mm {_num(est.turn_deg, '{:.2f}')} deg (breathing excluded)"
    if est.status in ("", "TRACKING"):
        return f"{est.state}, {body}"
    ago = f" {est.age_s:.1f} s ago" if est.age_s is not None else ""
    return f"last pose{ago}: {body}; motion since then NOT KNOWN"


def _breathing(b) -> str:
    return sparkline(b.trace) if b.breathes else "none seen (fitted rigidly)"


def live_table(est) -> Table:
    """Whether the patient is tracked (and why not), the age of what is shown; per band:
    displacement, breathing trace and rate; the body's 6-DOF and alert state."""
    if est is None:
        return Table(title="live motion: off")
    pose = _pose(est)
    if est.state == "ALERT" and est.status in ("", "TRACKING"):
        pose = "[bold red]ALERT[/] " + pose
    title = "  ".join(x for x in (f"live motion: {_status(est, True)}", pose, f"alerts {est.alerts}", _age(est)) if x)
    old = est.status not in ("", "TRACKING")  # the last pose's rows, dimmed and said to be old
    if old and est.bands and est.age_s is not None:
        title += f"\nthe bands as of {est.age_s:.1f} s ago:"
    t = Table(
        title=title,
        title_justify="left",
        caption=" · ".join(escape(x) for x in (_six(est), est.note, _stats(est.stats)) if x),
        caption_justify="left",
    )
    for col in ("band", "markers", "displacement mm", "breathing", "mm", "rate /min"):
        t.add_column(col, justify="left" if col in ("band", "breathing") else "right")
    for b in est.bands:
        t.add_row(
            str(b.band),
            f"{b.seen}/{b.markers}",
            _num(b.distance_mm),
            _breathing(b),
            _num(b.breathing_mm),
            _num(b.rate_per_min) + _bounds(b),
            style="dim" if old else None,
        )
    return t


def _bounds(b) -> str:
    """`` (12.1-16.3)`` after a rate that is only bounded: the breaths seen do not pin it to 0.5 /min."""
    r = getattr(b, "rate_range", None)
    return f" ({r[0]:.1f}-{r[1]:.1f})" if r else ""


def live_line(est) -> str:
    """One plain line (when stderr is not a terminal)."""
    if est is None:
        return "live motion: off"
    age = f" ({_age(est)})" if est.age_s is not None else ""
    if est.phase != "tracking" or est.six_dof is None:
        return f"live motion: {_status(est, False)}" + (f" ({est.note})" if est.note else "") + age
    bands = "; ".join(
        f"band {b.band} {b.seen}/{b.markers} markers {_num(b.distance_mm)} mm, breathing "
        + (f"{_num(b.breathing_mm)} mm {_num(b.rate_per_min)}/min{_bounds(b)}" if b.breathes else "none seen")
        for b in est.bands
    )
    status = f"{_status(est, False)}; " if est.status else ""
    return f"live motion: {status}{_pose(est)}, alerts {est.alerts}{age}; {bands}; {_six(est)}; {_stats(est.stats)}"
