"""The commissioning report as one self-contained HTML page (report/commission.py's content):
the state in colour and words, the devices, the steps, every figure against its window, what
was skipped and why, the sign-off block."""

from __future__ import annotations

from html import escape

from vts_hw.report.commission import WORDS, CommissionReport
from vts_hw.report.html import badge, page, table
from vts_hw.report.times import fmt_datetime

EXTRA_CSS = """
.badge.SKIPPED, .badge.NOT { background: #9aa3ad; }
.badge.ABORTED { background: #8a1c1c; }
.signoff { border: 2px solid #1d2733; padding: 10px 14px; border-radius: 6px; }
.signoff.unsigned { border-style: dashed; color: #8a1c1c; }
"""


def _td(text, cls: str = "") -> str:
    attr = f' class="{cls}"' if cls else ""
    return f"<td{attr}>{escape(str(text))}</td>"


def _value(v, unit: str) -> str:
    return "not measured" if v is None else f"{v:.4g} {unit}".strip()


def signoff_text(report: CommissionReport) -> str:
    if report.signed_by:
        return f"Signed off by {report.signed_by} on {fmt_datetime(report.signed_at)}"
    return "Not signed off"


def render_commission_html(report: CommissionReport) -> str:
    state = str(report.state)
    cams = [
        f'<tr data-camera="{escape(c.get("name", "?"))}">'
        + _td(c.get("name", "?"))
        + _td(c.get("model", "?"))
        + _td(c.get("serial", "?"))
        + _td(c.get("firmware", "?"))
        + _td(c.get("address", "?"))
        + _td(c.get("announced", "?"))
        + _td(", ".join(f"{k}={v}" for k, v in (c.get("locked_params") or {}).items()))
        + "</tr>"
        for c in report.cameras
    ]
    t = report.trigger
    trig = (
        (
            f"<p>Trigger: {escape(str(t.get('device', '?')))}, serial {escape(str(t.get('serial', '?')))}, firmware "
            f"{escape(str(t.get('firmware', '?')))} at {escape(str(t.get('address', '?')))}; "
            f"{escape(str(t.get('note', '')))}</p>"
        )
        if t
        else '<p class="muted">Trigger: not recorded.</p>'
    )
    steps = [
        f'<tr class="step" data-step="{escape(s.name)}" data-state="{escape(s.state)}">'
        + _td(s.label)
        + f"<td>{badge(s.state)}</td>"
        + _td(fmt_datetime(s.started) if s.started else "-")
        + _td(s.run_id if s.run_id is not None else "-")
        + _td(s.notes)
        + "</tr>"
        for s in report.steps
    ]
    figs = [
        f'<tr class="figure" data-state="{escape(f.state)}">'
        + _td(f.step)
        + _td(f.subject)
        + _td(f.metric)
        + _td(_value(f.value, f.unit), "num")
        + _td(f.window)
        + f"<td>{badge(f.state)}</td>"
        + "</tr>"
        for f in report.figures
    ]
    skipped = "".join(f"<li><b>{escape(label)}</b>: {escape(why)}</li>" for label, why in report.skipped)
    signed = bool(report.signed_by)
    sign = (
        f'<section class="card"><h2>Sign-off</h2><div class="signoff{"" if signed else " unsigned"}" '
        f'id="signoff" data-signed="{"yes" if signed else "no"}"><b>{escape(signoff_text(report))}</b>'
        + (
            ""
            if signed
            else "<p>Give <code>vts commission --resume --sign-off NAME</code> once a physicist has "
            "reviewed this report.</p>"
        )
        + "</div></section>"
    )
    verdict = f"{WORDS[state]}" if report.complete else "NOT COMMISSIONED: a step has not passed"
    body = (
        f"<style>{EXTRA_CSS}</style>"
        f'<section class="card banner {escape(state)}"><div class="big" id="verdict">Room {escape(report.rig)}: '
        f"{badge(state)} {escape(verdict)}</div></section>"
        '<section class="card"><h2>Devices</h2>'
        + table(
            ["camera", "model", "serial", "firmware", "address", "announced", "settings locked"],
            cams,
            "No camera recorded.",
        )
        + trig
        + "</section>"
        '<section class="card"><h2>Steps</h2>'
        + table(["step", "state", "when (UTC)", "run", "notes"], steps, "No step recorded.")
        + "</section>"
        '<section class="card"><h2>Figures against their tolerance</h2>'
        + table(["step", "subject", "figure", "value", "tolerance window", "state"], figs, "No figure.")
        + '<p class="muted">OK: within tolerance. TOLERANCE: within the action limits, to be reviewed. '
        "ACTION: outside the action limits. A figure without a window carries its procedure's own verdict.</p>"
        "</section>"
        '<section class="card"><h2>Skipped</h2>'
        + (f'<ul id="skipped">{skipped}</ul>' if skipped else '<p class="muted" id="skipped">Nothing was skipped.</p>')
        + "</section>"
        + sign
    )
    meta = (
        f"rig {escape(report.rig)} · commissioning {report.cid} · generated {fmt_datetime(report.now)} · "
        f"vts-hw {escape(report.software_version)} · all times UTC"
    )
    return page(f"{report.title}: {report.rig}", state, meta, body, plots_expected=0)


__all__ = ["render_commission_html", "signoff_text"]
