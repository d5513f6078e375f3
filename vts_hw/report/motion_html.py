"""The motion analysis's report: one self-contained HTML file (the styles of the other reports,
the plot inline as a PNG ``data:`` URI). Input: ``MotionAnalysis.results_data()`` and the PNG of
``MotionAnalysis.plot()``. Every time is on the clock the data names (SPECT list-mode seconds,
or seconds from the first frame on the host clock), and the report says which at the top."""

from __future__ import annotations

import base64
from html import escape

from vts_hw.report.html import kpi as _kpi
from vts_hw.report.html import page

__all__ = ["render_motion_html", "kpi_rows", "event_rows", "state_rows"]


def _f(v, fmt=".2f") -> str:
    return "–" if v is None else format(v, fmt)


def _table(head, rows) -> str:
    if not rows:
        return '<p class="muted">none</p>'
    h = "".join(f"<th>{escape(x)}</th>" for x in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f'<div class="scroll"><table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table></div>'


def _event_start(e) -> str:
    if e.get("start_bounds_s"):
        a, b = e["start_bounds_s"]
        return f"{a:.2f}–{b:.2f} (bounded)"
    return f"{e['t_start']:.2f}"


def _event_end(e) -> str:
    if e.get("end_bounds_s"):
        a, b = e["end_bounds_s"]
        return f"{a:.2f}–{b:.2f} (bounded)"
    return f"{e['t_end']:.2f}"


def kpi_rows(data: dict) -> list[tuple[str, str, str]]:
    """The summary's figures as (label, value, unit), plain text (the HTML and PDF reports')."""
    s = data["summary"]
    b = data["breathing"]
    rate = {"measured": _f(b["rate_per_min"], ".1f"), "none": "none"}.get(
        b["status"],
        "unknown"
        if b["rate_per_min"] is None
        else f"{b['rate_range_per_min'][0]:.1f}–{b['rate_range_per_min'][1]:.1f}",
    )
    amp = (
        "none"
        if b["status"] == "none"
        else "unknown"
        if s["breathing_amplitude_mm"] is None
        else _f(s["breathing_amplitude_mm"], ".1f")
    )
    return [
        ("pose known", _f(100 * s["motion_pose_coverage"], ".1f"), f"% of {s['duration_s']:.1f} s"),
        ("without frames", _f(s["no_frames_s"], ".1f"), f"s in {s['no_frames_gaps']} gap(s)"),
        ("body moved up to", _f(s["motion_body_max_mm"]), "mm"),
        ("turned up to", _f(s["motion_body_max_deg"]), "deg"),
        ("events / states", f"{s['events']} / {s['states']}", ""),
        ("breathing", rate, "/min" if b["status"] in ("measured", "bounded") else ""),
        ("breath amplitude", amp, "mm" if s["breathing_amplitude_mm"] is not None else ""),
    ]


def event_rows(data: dict) -> list[list[str]]:
    """The body-motion events' table rows, plain text."""
    return [
        [
            str(k),
            _event_start(e),
            _event_end(e),
            f"{e['centroid_shift_mm']:.2f}",
            f"{e['rotation_deg']:.2f}",
            " ".join(f"{x:+.2f}" for x in e["change_6dof"]),
        ]
        for k, e in enumerate(data["events"], 1)
    ]


def state_rows(data: dict) -> list[list[str]]:
    """The motion states' table rows, plain text."""
    return [
        [
            str(st["state"]),
            f"{st['t_start']:.2f}",
            f"{st['t_end']:.2f}",
            f"{st['unknown_s']:.1f}" if st["unknown_s"] else "0",
            " ".join(f"{x:+.2f}" for x in st["six_dof"]),
            str(st["frames"]),
        ]
        for st in data["states"]
    ]


def render_motion_html(data: dict, png: bytes, title: str = "Patient motion") -> str:
    s = data["summary"]
    state = s["state"]
    b = data["breathing"]
    kpis = "".join(_kpi(*k) for k in kpi_rows(data))
    events = event_rows(data)
    states = state_rows(data)
    cov = data["coverage"]
    unknown = [
        [f"{u['interval_s'][0]:.2f}", f"{u['interval_s'][1]:.2f}", f"{u['seconds']:.2f}", escape(u["why"])]
        for u in cov["unknown_s"]
    ]
    markers = [
        [
            escape(m["marker"]),
            "yes" if m["patient"] else "no",
            escape(m["band"] or ""),
            f"{100 * m['seen_fraction']:.0f} %",
            escape(", ".join(f"{k} {v}" for k, v in m["points_by_camera"].items())),
            escape(m["why"]),
        ]
        for m in data["markers"]
    ]
    measures = [
        [
            escape(m["metric"]),
            _f(m["value"], ".3g"),
            escape(m["unit"]),
            f'<span class="badge {m["state"]}">{m["state"]}</span>',
        ]
        for m in data["measures"]
    ]
    problems = "".join(f"<li>{escape(p)}</li>" for p in data["problems"])
    img = base64.b64encode(png).decode("ascii")
    meta = (
        f"session {escape(data['session'])} · list-mode {escape(str(data['listmode'] or 'none'))} · "
        f"analysed {escape(str(data['date']))} UTC · vts-hw {escape(data['vts_hw_version'])}"
    )
    return page(
        title,
        state,
        meta,
        f"""<section class="card banner {state}">
<div class="big"><span class="badge {state}">{state}</span></div>
<p><b>Time:</b> {escape(s["time"])}. <b>Breathing:</b> {escape(b["why"])}.</p>
<p class="quiet">Times: {escape(data["clock"])}. Positions: {escape(data["frame"]["definition"])}. Breathing is taken
out of the body pose; the reference is the first still period ({data["reference_period_s"][0]:.1f}–{data["reference_period_s"][1]:.1f} s).</p>
{f"<ul>{problems}</ul>" if problems else ""}
</section>
<section class="card"><h2>Summary</h2><div class="cards">{kpis}</div>
<img class="plot" alt="respiratory trace, body 6-DOF with events and states, body speed and still periods" src="data:image/png;base64,{img}">
</section>
<section class="card"><h2>Measures</h2>{_table(["metric", "value", "unit", "state"], measures)}</section>
<section class="card"><h2>Body-motion events</h2>{_table(["#", "start s", "end s", "centroid mm", "turn deg", "change tx ty tz mm, rx ry rz deg"], events)}
<p class="muted">A start given as a range fell in time without a pose: the move began somewhere in it.</p></section>
<section class="card"><h2>Motion states</h2>{_table(["state", "start s", "end s", "without a pose s (in no state)", "pose from the reference (tx ty tz mm, rx ry rz deg)", "frames with a pose"], states)}</section>
<section class="card"><h2>Time without a pose</h2>{_table(["start s", "end s", "seconds", "why"], unknown)}
<p class="muted">No motion state covers this time (a stretch of at most {data["settings"].get("bridge_s", 2.0):g} s with the same pose on both sides is covered by its state; {len(cov["bridged_s"])} such). It is not still and not OK: nothing was seen.</p></section>
<section class="card"><h2>Markers and cameras</h2>{_table(["marker", "patient", "band", "seen", "points by camera", "why"], markers)}
<p class="muted">Bands: {escape(data.get("band_naming", ""))}.</p></section>
<footer>vts-hw patient motion. Method: docs/decisions/0035-breathing-and-body-motion.md; files: docs/motion-formats.md.</footer>""",
    )
