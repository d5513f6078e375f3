"""The motion analysis's report as a PDF: what the HTML report says (report/motion_html.py), on
A4 landscape pages made the way the drift PDF is (matplotlib's PDF backend, in memory).

Input: ``MotionAnalysis.results_data()`` and the PNG of ``MotionAnalysis.plot()``. Every time is
on the clock the data names, and the report says which at the top.
"""

from __future__ import annotations

import datetime as _dt

from vts_hw.report.motion_html import _f, event_rows, kpi_rows, state_rows
from vts_hw.report.pdf_flow import Heading, Image, Table, Text, render_pages


def render_motion_pdf(data: dict, png: bytes, title: str = "Patient motion") -> bytes:
    """The report as PDF bytes."""
    s, b, cov = data["summary"], data["breathing"], data["coverage"]
    state = s["state"]
    kpis = [list(k) for k in kpi_rows(data)]
    events, states = event_rows(data), state_rows(data)
    unknown = [
        [f"{u['interval_s'][0]:.2f}", f"{u['interval_s'][1]:.2f}", f"{u['seconds']:.2f}", u["why"]]
        for u in cov["unknown_s"]
    ]
    markers = [
        [
            m["marker"],
            "yes" if m["patient"] else "no",
            m["band"] or "",
            f"{100 * m['seen_fraction']:.0f} %",
            ", ".join(f"{k} {v}" for k, v in m["points_by_camera"].items()),
            m["why"],
        ]
        for m in data["markers"]
    ]
    measures = [[m["metric"], _f(m["value"], ".3g"), m["unit"], m["state"]] for m in data["measures"]]
    ref = data["reference_period_s"]
    meta = (
        f"session {data['session']} · list-mode {data['listmode'] or 'none'} · analysed {data['date']} UTC · "
        f"vts-hw {data['vts_hw_version']}"
    )
    blocks = [
        Text(f"Time: {s['time']}. Breathing: {b['why']}."),
        Text(
            f"Times: {data['clock']}. Positions: {data['frame']['definition']}. Breathing is taken out of "
            f"the body pose; the reference is the first still period ({ref[0]:.1f}–{ref[1]:.1f} s).",
            muted=True,
        ),
        *[Text(f"• {p}") for p in data["problems"]],
        Heading("Summary"),
        Table(["", "value", "unit"], kpis),
        Image(png, "respiratory trace, body 6-DOF with events and states, body speed and still periods"),
        Heading("Measures"),
        Table(["metric", "value", "unit", "state"], measures),
        Heading("Body-motion events"),
        Table(["#", "start s", "end s", "centroid mm", "turn deg", "change tx ty tz mm, rx ry rz deg"], events),
        Text("A start given as a range fell in time without a pose: the move began somewhere in it.", muted=True),
        Heading("Motion states"),
        Table(
            [
                "state",
                "start s",
                "end s",
                "without a pose s (in no state)",
                "pose from the reference (tx ty tz mm, rx ry rz deg)",
                "frames with a pose",
            ],
            states,
        ),
        Heading("Time without a pose"),
        Table(["start s", "end s", "seconds", "why"], unknown),
        Text(
            f"No motion state covers this time (a stretch of at most {data['settings'].get('bridge_s', 2.0):g} s "
            f"with the same pose on both sides is covered by its state; {len(cov['bridged_s'])} such). It is not "
            "still and not OK: nothing was seen.",
            muted=True,
        ),
        Heading("Markers and cameras"),
        Table(["marker", "patient", "band", "seen", "points by camera", "why"], markers),
        Text(f"Bands: {data.get('band_naming', '')}.", muted=True),
        Text(
            "vts-hw patient motion. Method: docs/decisions/0035-breathing-and-body-motion.md; files: "
            "docs/motion-formats.md.",
            muted=True,
        ),
    ]
    pdf_meta = {
        "Title": title,
        "Subject": f"session {data['session']}",
        "Creator": f"vts-hw {data['vts_hw_version']}",
        "CreationDate": _dt.datetime.now(_dt.UTC).replace(microsecond=0),
    }
    return render_pages(title, state, meta, blocks, pdf_meta)


__all__ = ["render_motion_pdf"]
