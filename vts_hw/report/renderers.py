"""Every report's renderers by the suffix of the file asked for: the one door reports go out by.

``RENDERERS[report][suffix]`` turns a report's content into the text (``.html``) or the bytes
(``.pdf``) of its file; every report has a renderer for every suffix of :data:`FORMATS`. Each is
named by its module and imported when it renders (:class:`Renderer`).

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

from vts_hw.errors import ConfigError
from vts_hw.files import ensure_dir, write_atomic
from vts_hw.lazy import load


class Renderer:
    """``module.function`` of vts_hw.report, imported when a report is rendered by it: a bad
    ``-o`` or a missing input is said before any plotting or font library is loaded, and an HTML
    report never loads the PDF's."""

    def __init__(self, module: str, function: str):
        self.module, self.function = module, function

    def target(self):
        return load(f"vts_hw.report.{self.module}", self.function)

    def __call__(self, *content) -> str | bytes:
        return self.target()(*content)

    def __repr__(self) -> str:
        return f"Renderer({self.module}.{self.function})"


FORMATS = (".html", ".pdf")
RENDERERS: dict[str, dict[str, Renderer]] = {
    "drift": {".html": Renderer("html", "render_drift_html"), ".pdf": Renderer("pdf", "render_drift_pdf")},
    "drift-every-rig": {
        ".html": Renderer("html", "render_drift_html_every_rig"),
        ".pdf": Renderer("pdf", "render_drift_pdf_every_rig"),
    },
    "department": {
        ".html": Renderer("rooms_html", "render_department_html"),
        ".pdf": Renderer("rooms_pdf", "render_department_pdf"),
    },
    "sync": {".html": Renderer("sync_html", "render_sync_html"), ".pdf": Renderer("sync_pdf", "render_sync_pdf")},
    "motion": {
        ".html": Renderer("motion_html", "render_motion_html"),
        ".pdf": Renderer("motion_pdf", "render_motion_pdf"),
    },
    "commission": {
        ".html": Renderer("commission_html", "render_commission_html"),
        ".pdf": Renderer("commission_pdf", "render_commission_pdf"),
    },
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
        raise ReportError(
            f"{out}: the report is written as .html or .pdf, not {suffix or 'a name without suffix'}: "
            f"give -o report.html or -o report.pdf"
        )
    return suffix


def render(report: str, out: str | Path, *content) -> str | bytes:
    """The file ``out`` of ``report`` (a key of :data:`RENDERERS`), by its suffix, in memory."""
    return RENDERERS[report][report_format(out)](*content)


def write_report(report: str, out: str | Path, *content) -> Path:
    """Render ``report`` by the suffix of ``out`` and write it whole; returns the path."""
    out = Path(out)
    data = render(report, out, *content)
    ensure_dir(out.parent, "report folder", link_ok=True)  # the file's folder, as the kernel resolves it
    return write_atomic(out, data)


__all__ = ["FORMATS", "RENDERERS", "Renderer", "ReportError", "render", "report_format", "write_report"]
