"""The live motion view of `vts scan start`: what the live estimator says, printed (a rich
table on a terminal, a plain line otherwise). Nothing is computed here but formatting."""

from __future__ import annotations

import math

from rich.table import Table

SPARK = "▁▂▃▄▅▆▇█"


def sparkline(values) -> str:
    vals = [v for v in values if v is not None and math.isfinite(v)]
    if not vals:
        return ""
    lo, hi = min(vals), max(vals)
    span = hi - lo or 1.0
    return "".join(" " if v is None or not math.isfinite(v) else SPARK[min(7, int((v - lo) / span * 8))]
                   for v in values)


def _num(v, fmt="{:.1f}") -> str:
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else fmt.format(v)


def _six(est) -> str:
    if est.six_dof is None:
        return "-"
    t, r = est.six_dof[:3], est.six_dof[3:]
    return (f"T {t[0]:+.1f} {t[1]:+.1f} {t[2]:+.1f} mm  R {r[0]:+.2f} {r[1]:+.2f} {r[2]:+.2f} deg "
            f"({est.frame} frame)")


def _stats(st: dict) -> str:
    if not st:
        return ""
    drops = sum((st.get("live_dropped") or {}).values())
    return (f"{st.get('sets', 0)} frame sets, live latency p50 {_num(st.get('latency_ms_p50'))} ms "
            f"p95 {_num(st.get('latency_ms_p95'))} ms, {drops} dropped from the live path"
            + (f"; {st['error']}" if st.get("error") else ""))


def live_table(est) -> Table:
    """Per band: displacement, breathing trace and rate; the body's 6-DOF and alert state."""
    if est is None:
        return Table(title="live motion: off")
    state = est.state or est.phase
    if state == "ALERT":
        state = "[bold red]ALERT[/]"
    title = (f"live motion: {state}  body {_num(est.move_mm)} mm {_num(est.turn_deg, '{:.2f}')} deg "
             f"(breathing excluded)  alerts {est.alerts}")
    t = Table(title=title, title_justify="left", caption=" · ".join(x for x in (_six(est), est.note,
                                                                                 _stats(est.stats)) if x),
              caption_justify="left")
    for col in ("band", "markers", "displacement mm", "breathing", "mm", "rate /min"):
        t.add_column(col, justify="left" if col in ("band", "breathing") else "right")
    for b in est.bands:
        t.add_row(str(b.band), f"{b.seen}/{b.markers}", _num(b.distance_mm), sparkline(b.trace),
                  _num(b.breathing_mm), _num(b.rate_per_min))
    return t


def live_line(est) -> str:
    """One plain line (when stderr is not a terminal)."""
    if est is None:
        return "live motion: off"
    if est.phase != "tracking" or est.six_dof is None:
        return f"live motion: {est.phase}" + (f" ({est.note})" if est.note else "")
    bands = "; ".join(f"band {b.band} {b.seen}/{b.markers} markers {_num(b.distance_mm)} mm, breathing "
                      f"{_num(b.breathing_mm)} mm {_num(b.rate_per_min)}/min" for b in est.bands)
    return (f"live motion: {est.state}, body {_num(est.move_mm)} mm {_num(est.turn_deg, '{:.2f}')} deg, "
            f"alerts {est.alerts}; {bands}; {_six(est)}; {_stats(est.stats)}")
