"""Every report's renderers by the suffix of the file asked for: the one door reports go out by.

``RENDERERS[report][suffix]`` turns a report's content into the text (``.html``) or the bytes
(``.pdf``) of its file; every report has a renderer for every suffix of :data:`FORMATS`.

| report | content | ``.html`` | ``.pdf`` |
| --- | --- | --- | --- |
| ``drift`` | a :class:`~vts_hw.report.model.DriftReport` | report/html.py | report/pdf.py |
| ``drift-every-rig`` | a list of them, one per rig | report/html.py | report/pdf.py |
| ``department`` | a :class:`~vts_hw.report.rooms.RoomsReport` (the rooms page) | report/rooms_html.py | report/rooms_pdf.py |
| ``sync`` | ``SyncAnalysis.results_data()`` and its plot's PNG | report/sync_html.py | report/sync_pdf.py |
| ``motion`` | ``MotionAnalysis.results_data()`` and its plot's PNG | report/motion_html.py | report/motion_pdf.py |
| ``commission`` | a :class:`~vts_hw.report.commission.CommissionReport` | report/commission_html.py | report/commission_pdf.py |

:func:`report_format` reads the suffix (``.htm`` is ``.html``; any other is a
:class:`ReportError`, exit 2, before anything is computed); :func:`write_report` renders in
memory and writes the file whole (``files.write_atomic``: on a full disk nothing is
half-written and ``WriteFailed``, exit 3, names the file). Builders that read the store are in
:mod:`vts_hw.report.build`. See docs/decisions/0058-tracking-room-and-report-door.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from vts_hw.errors import ConfigError
from vts_hw.files import ensure_dir, write_atomic
from vts_hw.report.commission_html import render_commission_html
from vts_hw.report.commission_pdf import render_commission_pdf
from vts_hw.report.html import render_drift_html, render_drift_html_every_rig
from vts_hw.report.motion_html import render_motion_html
from vts_hw.report.motion_pdf import render_motion_pdf
from vts_hw.report.pdf import render_drift_pdf, render_drift_pdf_every_rig
from vts_hw.report.rooms_html import render_department_html
from vts_hw.report.rooms_pdf import render_department_pdf
from vts_hw.report.sync_html import render_sync_html
from vts_hw.report.sync_pdf import render_sync_pdf

FORMATS = (".html", ".pdf")
RENDERERS: dict[str, dict[str, Callable[..., str | bytes]]] = {
    "drift": {".html": render_drift_html, ".pdf": render_drift_pdf},
    "drift-every-rig": {".html": render_drift_html_every_rig, ".pdf": render_drift_pdf_every_rig},
    "department": {".html": render_department_html, ".pdf": render_department_pdf},
    "sync": {".html": render_sync_html, ".pdf": render_sync_pdf},
    "motion": {".html": render_motion_html, ".pdf": render_motion_pdf},
    "commission": {".html": render_commission_html, ".pdf": render_commission_pdf},
}


class ReportError(ConfigError):
    """A report asked for in a format it cannot be written in (exit 2, like a usage error)."""


def report_format(out: str | Path) -> str:
    """``.html`` or ``.pdf`` (from the name's suffix); ReportError (exit 2) for anything else."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix == ".htm":
        return ".html"
    if suffix not in FORMATS:
        raise ReportError(f"{out}: the report is written as .html or .pdf, not {suffix or 'a name without suffix'}: "
                          f"give -o report.html or -o report.pdf")
    return suffix


def render(report: str, out: str | Path, *content) -> str | bytes:
    """The file ``out`` of ``report`` (a key of :data:`RENDERERS`), by its suffix, in memory."""
    return RENDERERS[report][report_format(out)](*content)


def write_report(report: str, out: str | Path, *content) -> Path:
    """Render ``report`` by the suffix of ``out`` and write it whole; returns the path."""
    out = Path(out)
    data = render(report, out, *content)
    ensure_dir(out.parent, "report folder")
    return write_atomic(out, data)


__all__ = ["FORMATS", "RENDERERS", "ReportError", "render", "report_format", "write_report"]
