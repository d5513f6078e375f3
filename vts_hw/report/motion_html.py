"""The motion analysis's report: one self-contained HTML file (the styles of the other reports,
the plot inline as a PNG ``data:`` URI). Input: ``MotionAnalysis.results_data()`` and the PNG of
``MotionAnalysis.plot()``. Every time is on the clock the data names (SPECT list-mode seconds,
or seconds from the first frame on the host clock), and the report says which at the top."""

from __future__ import annotations

import base64
from html import escape
from pathlib import Path

from vts_hw.files import write_atomic
from vts_hw.report.html import kpi as _kpi, page

__all__ = ["render_motion_html", "write_motion_html"]



def _f(v, fmt=".2f") -> str:
    return "–" if v is None else format(v, fmt)


def _table(head, rows) -> str:
    if not rows:
        return '<p class="muted">none</p>'
    h = "".join(f"<th>{escape(x)}</th>" for x in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f'<div class="scroll"><table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table></div>'


def render_motion_html(data: dict, png: bytes, title: str = "Patient motion") -> str:
    s = data["summary"]
    state = s["state"]
    kpis = "".join([
        _kpi("body moved up to", _f(s["motion_body_max_mm"]), "mm"),
        _kpi("turned up to", _f(s["motion_body_max_deg"]), "deg"),
        _kpi("events / states", f"{s['events']} / {s['states']}"),
        _kpi("breathing", _f(s["breathing_rate_per_min"], ".1f"), "/min"),
        _kpi("breath amplitude", _f(s["breathing_amplitude_mm"], ".1f"), "mm"),
        _kpi("pose coverage", _f(100 * s["motion_pose_coverage"], ".1f"), "% of frames"),
    ])
    events = [[str(k), f"{e['t_start']:.2f}", f"{e['t_end']:.2f}", f"{e['centroid_shift_mm']:.2f}",
               f"{e['rotation_deg']:.2f}", " ".join(f"{x:+.2f}" for x in e["change_6dof"])]
              for k, e in enumerate(data["events"], 1)]
    states = [[str(st["state"]), f"{st['t_start']:.2f}", f"{st['t_end']:.2f}",
               " ".join(f"{x:+.2f}" for x in st["six_dof"]), str(st["frames"])] for st in data["states"]]
    markers = [[escape(m["marker"]), "yes" if m["patient"] else "no", escape(m["band"] or ""),
                f"{100 * m['seen_fraction']:.0f} %", escape(", ".join(f"{k} {v}" for k, v in m["points_by_camera"].items())),
                escape(m["why"])] for m in data["markers"]]
    measures = [[escape(m["metric"]), _f(m["value"], ".3g"), escape(m["unit"]),
                 f'<span class="badge {m["state"]}">{m["state"]}</span>'] for m in data["measures"]]
    problems = "".join(f"<li>{escape(p)}</li>" for p in data["problems"])
    gaps = ", ".join(f"{a:.2f}–{b:.2f} s" for a, b in data["pose_gaps_s"]) or "none"
    img = base64.b64encode(png).decode("ascii")
    meta = (f"session {escape(data['session'])} · list-mode {escape(str(data['listmode'] or 'none'))} · "
            f"analysed {escape(str(data['date']))} UTC · vts-hw {escape(data['vts_hw_version'])}")
    return page(title, state, meta, f"""<section class="card banner {state}">
<div class="big"><span class="badge {state}">{state}</span></div>
<p class="quiet">Times: {escape(data['clock'])}. Positions: {escape(data['frame']['definition'])}. Breathing is taken
out of the body pose; the reference is the first still period ({data['reference_period_s'][0]:.1f}–{data['reference_period_s'][1]:.1f} s).</p>
{f"<ul>{problems}</ul>" if problems else ""}
</section>
<section class="card"><h2>Summary</h2><div class="cards">{kpis}</div>
<img class="plot" alt="respiratory trace, body 6-DOF with events and states, body speed and still periods" src="data:image/png;base64,{img}">
</section>
<section class="card"><h2>Measures</h2>{_table(["metric", "value", "unit", "state"], measures)}</section>
<section class="card"><h2>Body-motion events</h2>{_table(["#", "start s", "end s", "centroid mm", "turn deg", "change tx ty tz mm, rx ry rz deg"], events)}</section>
<section class="card"><h2>Motion states</h2>{_table(["state", "start s", "end s", "pose from the reference (tx ty tz mm, rx ry rz deg)", "frames"], states)}</section>
<section class="card"><h2>Markers and cameras</h2>{_table(["marker", "patient", "band", "seen", "points by camera", "why"], markers)}
<p class="muted">Bands: {escape(data.get("band_naming", ""))}. Frames without a body pose (fewer than 3 patient
markers seen): {gaps}.</p></section>
<footer>vts-hw patient motion. Method: docs/decisions/0035-breathing-and-body-motion.md; files: docs/motion-formats.md.</footer>""")


def write_motion_html(data: dict, png: bytes, out) -> Path:
    """Write the report whole or not at all (WriteFailed names the file)."""
    return write_atomic(Path(out), render_motion_html(data, png))
