"""The sync check's report as a PDF: what the HTML report says (report/sync_html.py), on A4
landscape pages made the way the drift PDF is (matplotlib's PDF backend, in memory).

Input: ``SyncAnalysis.results_data()`` and the PNG bytes of ``SyncAnalysis.plot()``. Times in
the tables are seconds since the trigger's first edge (host clock) and ms for differences.
"""

from __future__ import annotations

import datetime as _dt

from vts_hw import __version__
from vts_hw.report.pdf_flow import Heading, Image, Table, Text, render_pages
from vts_hw.report.sync_html import _intervals, _limits, _ms, kpi_rows


def _events(data: dict) -> list[list[str]]:
    rows = []
    for e in data["events"]:
        fit = e["spect_fit"] or {}
        vfit = e["vts_fit"] or {}
        step = e["step_spect_mm"] if e["step_spect_mm"] is not None else e["step_vts_mm"]
        rows.append(
            [
                str(e["event"]),
                f"{e['t_rel_s']:.3f}",
                f"{e['t_list_s']:.3f}",
                f"{step:+.1f}",
                e["seen_by"],
                _ms(e["dt_s"]),
                _ms(vfit.get("t_err_s"), ".1f"),
                _ms(fit.get("t_err_s"), ".1f"),
                e["note"],
            ]
        )
    return rows


def render_sync_pdf(data: dict, png: bytes, title: str = "VTS–SPECT sync check") -> bytes:
    """The report as PDF bytes."""
    s, g, trig = data["summary"], data["gating"], data["trigger"]
    state = s["state"]
    goal_s, limit_s = _limits(data)
    t0 = trig["start_host"]
    now = _dt.datetime.now(_dt.UTC)
    meta = (
        f"session {data['session']} · list-mode {data['listmode']} · generated "
        f"{now.strftime('%Y-%m-%d %H:%M:%S')} UTC · goal: every event within {goal_s * 1e3:.0f} ms; "
        f"{limit_s * 1e3:.0f} ms is what the previous system achieved"
    )
    kpis = [list(k) for k in kpi_rows(data)]
    vts, cal = data["vts"], data.get("calibration") or {}
    fits = [
        [
            name,
            f"{f.get('offset_s', float('nan')):+.4f}",
            f"{f.get('skew_ppm', float('nan')):+.2f}",
            _ms(f.get("uncertainty_s"), ".2f"),
        ]
        for name, f in (vts.get("clock_fits") or {}).items()
        if isinstance(f, dict)
    ]
    blocks = [
        Text(f"{s['state_reason']}."),
        *[Text(f"• {p}") for p in data["problems"]],
        Heading("Summary"),
        Table(["", "value", "unit"], kpis),
        Image(png, "VTS and SPECT traces on one time axis"),
        Heading("Motion events"),
        Table(
            [
                "#",
                "time s",
                "list-mode s",
                "step mm",
                "seen by",
                "t_VTS − t_SPECT ms",
                "VTS ± ms",
                "SPECT ± ms",
                "note",
            ],
            _events(data),
            empty="No motion event was found.",
        ),
        Text(
            "Times in seconds since the trigger's first edge (host clock); list-mode s since the SPECT "
            "acquisition start. Each time is the fitted mid-crossing of the step; ± its standard error.",
            muted=True,
        ),
        Heading("Gating and dead time"),
        Table(
            ["", ""],
            [
                [
                    "trigger",
                    f"{trig['device']}: period {trig['period_s']:.6g} s, duty {trig['duty']:.3g}, "
                    f"first edge from {trig['how']}",
                ],
                [
                    "gating edges",
                    f"{g['rising_edges']} rising, {g['falling_edges']} falling; levels "
                    f"{g['gate_low_v']:.3f} / {g['gate_high_v']:.3f} V; fit RMS {_ms(g['fit_rms_s'], '.3f')} ms",
                ],
                ["SPECT wall clock − host", f"{s['spect_clock_offset_s']:+.3f} s"],
                ["dead time", _intervals(data["dead_time_host"], t0)],
            ],
        ),
        Heading("Calibration"),
        Text(
            f"stereo: {cal.get('stereo')}; VTS → SPECT: {cal.get('spect') or 'none (the VTS trace is not SPECT Z)'}"
            + (f". {cal['note']}" if cal.get("note") else "")
        ),
        Heading("VTS"),
        Text(
            f"marker {'+'.join(str(m) for m in vts['markers'])} ({vts['trace']}), {vts['samples']} samples, "
            f"gaps: {_intervals(vts['gaps_host'], t0)}"
        ),
        Table(["camera", "clock offset s", "skew ppm", "uncertainty ms"], fits),
        Text("All times UTC. Host clock unless named. vts-hw sync check.", muted=True),
    ]
    pdf_meta = {
        "Title": title,
        "Subject": f"session {data['session']}",
        "Creator": f"vts-hw {__version__}",
        "CreationDate": now.replace(microsecond=0),
    }
    return render_pages(title, state, meta, blocks, pdf_meta)


__all__ = ["render_sync_pdf"]
