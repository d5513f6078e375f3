"""The sync check's report: one self-contained HTML file (styles of the drift report, the plot
as an inline PNG ``data:`` URI: it opens with no network).

Input: ``SyncAnalysis.results_data()`` and the PNG bytes of ``SyncAnalysis.plot()``. Times
in the tables are seconds since the trigger's first edge (host clock) and ms for differences.
"""

from __future__ import annotations

import base64
import datetime as _dt
from html import escape

from vts_hw.report.html import kpi as _kpi
from vts_hw.report.html import page


def _limits(data: dict) -> tuple[float, float]:
    """(goal, limit) in s: the sync_max_abs_dt_ms window the analysis judged with."""
    w = (data.get("windows") or {}).get("sync_max_abs_dt_ms") or {}
    return (w.get("tolerance_high") or 20.0) / 1e3, (w.get("action_high") or 100.0) / 1e3


def _ms(v, fmt="+.1f") -> str:
    return "–" if v is None else format(v * 1e3, fmt)


def _events_table(data: dict) -> str:
    goal_s, _ = _limits(data)
    rows = []
    for e in data["events"]:
        fit = e["spect_fit"] or {}
        vfit = e["vts_fit"] or {}
        bad = e["dt_s"] is not None and abs(e["dt_s"]) > goal_s
        cls = ' class="s-ACTION"' if bad else (' class="s-TOLERANCE"' if e["dt_s"] is None else "")
        step = e["step_spect_mm"] if e["step_spect_mm"] is not None else e["step_vts_mm"]
        rows.append(
            f"<tr><td>{e['event']}</td><td class=num>{e['t_rel_s']:.3f}</td><td class=num>{e['t_list_s']:.3f}</td>"
            f"<td class=num>{step:+.1f}</td><td>{escape(e['seen_by'])}</td>"
            f"<td class=num{cls}>{_ms(e['dt_s'])}</td>"
            f"<td class=num>{_ms(vfit.get('t_err_s'), '.1f')}</td><td class=num>{_ms(fit.get('t_err_s'), '.1f')}</td>"
            f"<td>{escape(e['note'])}</td></tr>"
        )
    if not rows:
        return '<p class="muted">No motion event was found.</p>'
    return (
        '<div class="scroll"><table><thead><tr><th>#</th><th class=num>time s</th>'
        "<th class=num>list-mode s</th><th class=num>step mm</th><th>seen by</th>"
        "<th class=num>t_VTS − t_SPECT ms</th><th class=num>VTS ± ms</th><th class=num>SPECT ± ms</th>"
        "<th>note</th></tr></thead><tbody>" + "".join(rows) + "</tbody></table></div>"
    )


def _intervals(pairs, t0) -> str:
    if not pairs:
        return "none"
    return ", ".join(f"{a - t0:.2f}–{b - t0:.2f} s" for a, b in pairs)


def kpi_rows(data: dict) -> list[tuple[str, str, str]]:
    """The summary's figures as (label, value, unit), plain text (the HTML and PDF reports')."""
    s = data["summary"]
    return [
        ("offset VTS − SPECT", _ms(s["offset_s"]), "ms (median)"),
        ("spread", _ms(s["spread_sd_s"], ".1f"), "ms (SD)"),
        ("largest |dt|", _ms(s["max_abs_dt_s"], ".1f"), "ms"),
        ("events", f"{s['events_both']} / {s['events']}", "seen by both"),
        ("SPECT start delay", _ms(s["start_delay_s"], ".1f"), f"ms (mod {s['start_delay_modulo_s']:.3f} s)"),
        ("SPECT clock", f"{s['spect_skew_ppm']:+.1f}", "ppm"),
    ]


def render_sync_html(data: dict, png: bytes, title: str = "VTS–SPECT sync check") -> str:
    """The report as an HTML string."""
    s, g = data["summary"], data["gating"]
    state = s["state"]
    goal_s, limit_s = _limits(data)
    t0 = data["trigger"]["start_host"]
    kpis = "".join(_kpi(*k) for k in kpi_rows(data))
    problems = "".join(f"<li>{escape(p)}</li>" for p in data["problems"])
    banner = f'<p class="quiet">{escape(s["state_reason"])}.</p>' + (f"<ul>{problems}</ul>" if problems else "")
    vts = data["vts"]
    fits = "".join(
        f"<tr><td>{escape(name)}</td><td class=num>{f.get('offset_s', float('nan')):+.4f}</td>"
        f"<td class=num>{f.get('skew_ppm', float('nan')):+.2f}</td>"
        f"<td class=num>{_ms(f.get('uncertainty_s'), '.2f')}</td></tr>"
        for name, f in (vts.get("clock_fits") or {}).items()
        if isinstance(f, dict)
    )
    cal = data.get("calibration") or {}
    note = f"<br><b>{escape(cal['note'])}</b>" if cal.get("note") else ""
    img = base64.b64encode(png).decode("ascii")
    now = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M:%S")
    meta = f"session {escape(data['session'])} · list-mode {escape(data['listmode'])} · generated {now} UTC"
    return page(
        title,
        state,
        meta,
        f"""<section class="card banner {state}">
<div class="big">{f'<span class="badge {state}">{state}</span>'} <span class="meta">goal: every event within
{goal_s * 1e3:.0f} ms; {limit_s * 1e3:.0f} ms is what the previous system achieved</span></div>
{banner}
</section>
<section class="card"><h2>Summary</h2><div class="cards">{kpis}</div>
<img class="plot" alt="VTS and SPECT traces on one time axis" src="data:image/png;base64,{img}">
</section>
<section class="card"><h2>Motion events</h2>{_events_table(data)}
<p class="muted">Times in seconds since the trigger's first edge (host clock); list-mode s since the SPECT
acquisition start. Each time is the fitted mid-crossing of the step; ± its standard error.</p></section>
<section class="card"><h2>Gating and dead time</h2>
<table><tbody>
<tr><th>trigger</th><td>{escape(data["trigger"]["device"])}: period {data["trigger"]["period_s"]:.6g} s,
duty {data["trigger"]["duty"]:.3g}, first edge from {escape(data["trigger"]["how"])}</td></tr>
<tr><th>gating edges</th><td>{g["rising_edges"]} rising, {g["falling_edges"]} falling; levels
{g["gate_low_v"]:.3f} / {g["gate_high_v"]:.3f} V; fit RMS {_ms(g["fit_rms_s"], ".3f")} ms</td></tr>
<tr><th>SPECT wall clock − host</th><td>{s["spect_clock_offset_s"]:+.3f} s</td></tr>
<tr><th>dead time</th><td>{_intervals(data["dead_time_host"], t0)}</td></tr>
</tbody></table></section>
<section class="card"><h2>Calibration</h2><p>stereo: {escape(str(cal.get("stereo")))}; VTS → SPECT:
{escape(str(cal.get("spect") or "none (the VTS trace is not SPECT Z)"))}{note}</p></section>
<section class="card"><h2>VTS</h2>
<p>marker {escape("+".join(str(m) for m in vts["markers"]))} ({escape(vts["trace"])}), {vts["samples"]} samples,
gaps: {_intervals(vts["gaps_host"], t0)}</p>
<table><thead><tr><th>camera</th><th class=num>clock offset s</th><th class=num>skew ppm</th>
<th class=num>uncertainty ms</th></tr></thead><tbody>{fits}</tbody></table></section>
<footer>All times UTC. Host clock unless named. vts-hw sync check.</footer>""",
    )


__all__ = ["render_sync_html", "kpi_rows"]
