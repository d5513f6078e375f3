"""The commissioning report as a PDF (what report/commission_html.py shows), made with the
report's PDF flow (report/pdf_flow.py)."""

from __future__ import annotations

import datetime as _dt

from vts_hw import __version__
from vts_hw.report.commission import WORDS, CommissionReport
from vts_hw.report.commission_html import _value, signoff_text
from vts_hw.report.pdf_flow import Heading, Table, Text, render_pages
from vts_hw.report.times import fmt_datetime


def render_commission_pdf(report: CommissionReport) -> bytes:
    state = str(report.state)
    title = f"{report.title}: {report.rig}"
    meta = (
        f"rig {report.rig} · commissioning {report.cid} · generated {fmt_datetime(report.now)} · "
        f"vts-hw {report.software_version} · all times UTC"
    )
    cams = [
        [
            c.get("name", "?"),
            c.get("model", "?"),
            c.get("serial", "?"),
            c.get("firmware", "?"),
            c.get("address", "?"),
            ", ".join(f"{k}={v}" for k, v in (c.get("locked_params") or {}).items()),
        ]
        for c in report.cameras
    ]
    t = report.trigger
    verdict = WORDS[state] if report.complete else "NOT COMMISSIONED: a step has not passed"
    blocks = [
        Text(f"Room {report.rig}: {verdict}"),
        Heading("Devices"),
        Table(
            ["camera", "model", "serial", "firmware", "address", "settings locked"], cams, empty="No camera recorded."
        ),
        Text(
            f"Trigger: {t.get('device', '?')}, serial {t.get('serial', '?')}, firmware {t.get('firmware', '?')}; "
            f"{t.get('note', '')}"
            if t
            else "Trigger: not recorded."
        ),
        Heading("Steps"),
        Table(
            ["step", "state", "when (UTC)", "run", "notes"],
            [
                [
                    s.label,
                    s.state,
                    fmt_datetime(s.started) if s.started else "-",
                    "-" if s.run_id is None else str(s.run_id),
                    s.notes,
                ]
                for s in report.steps
            ],
        ),
        Heading("Figures against their tolerance"),
        Table(
            ["step", "subject", "figure", "value", "tolerance window", "state"],
            [[f.step, f.subject, f.metric, _value(f.value, f.unit), f.window, f.state] for f in report.figures],
            empty="No figure.",
        ),
        Text(
            "OK: within tolerance. TOLERANCE: within the action limits, to be reviewed. ACTION: outside the "
            "action limits. A figure without a window carries its procedure's own verdict.",
            muted=True,
        ),
        Heading("Skipped"),
        *([Text(f"• {label}: {why}") for label, why in report.skipped] or [Text("Nothing was skipped.")]),
        Heading("Sign-off"),
        Text(signoff_text(report)),
        *([] if report.signed_by else [Text("Signature: ______________________   Date: ____________")]),
    ]
    now = _dt.datetime.now(_dt.UTC).replace(microsecond=0)
    return render_pages(
        title,
        state,
        meta,
        blocks,
        {
            "Title": title,
            "Subject": f"commissioning {report.cid}",
            "Creator": f"vts-hw {__version__}",
            "CreationDate": now,
        },
    )


__all__ = ["render_commission_pdf"]
