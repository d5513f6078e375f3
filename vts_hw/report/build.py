"""The reports built from the results store and written by the suffix of their file.

Each builder collects (:mod:`vts_hw.report.drift`, :mod:`vts_hw.report.rooms`) and writes
through the one table of renderers (:mod:`vts_hw.report.renderers`): ``.html`` or ``.pdf``,
refused before anything is read for any other suffix (ReportError, exit 2), rendered in memory
and written whole.
"""

from __future__ import annotations

import time
from pathlib import Path

from vts_hw.report.drift import collect
from vts_hw.report.model import DriftReport
from vts_hw.report.renderers import report_format, write_report
from vts_hw.report.rooms import RoomsReport, collect_rooms


def build_drift_report(
    store,
    out: str | Path,
    since: float | None = None,
    now: float | None = None,
    rig: str | None = None,
    title: str | None = None,
) -> DriftReport:
    """Compute the drift report from ``store`` and write it to ``out``.

    ``out`` ending in ``.html`` gives one self-contained HTML file (plots as inline PNG, no
    external resources); ``.pdf`` gives a title page with the summary and one page per camera.
    ``since``/``now`` bound the period shown (UTC epoch seconds; ``now`` defaults to the current
    time, runs after it are ignored); ``rig`` keeps only that rig's runs.

    The file is rendered in memory and written whole (``files.write_atomic``): on a full disk
    or an unwritable folder nothing is half-written, a previous report stays as it was, and
    ``WriteFailed`` (exit 3) names the file.
    """
    out = Path(out)
    report_format(out)
    report = collect(store, since=since, now=now, rig=rig, title=title)
    report.out = out
    write_report("drift", out, report)
    return report


def build_drift_report_every_rig(
    store, out: str | Path, since: float | None = None, now: float | None = None, rigs=None
) -> list[DriftReport]:
    """The drift report of every rig in the store (or of ``rigs``) in one file: per rig its own
    section (HTML) or pages (PDF), numbers computed per rig (cam1 of one rig is not cam1 of
    another). Written whole, as :func:`build_drift_report`."""
    out = Path(out)
    report_format(out)
    now = time.time() if now is None else float(now)
    reports = [collect(store, since=since, now=now, rig=r) for r in (store.rigs() if rigs is None else rigs)]
    for r in reports:
        r.out = out
    write_report("drift-every-rig", out, reports)
    return reports


def build_rooms_report(
    store, out: str | Path, since: float | None = None, now: float | None = None, rigs=None, progress=None
) -> RoomsReport:
    """Write each rig's drift report beside ``out`` and then the rooms page (``.html`` or
    ``.pdf``); every file is written whole (``files.write_atomic``). ``progress(text)`` hears
    of each file written."""
    out = Path(out)
    report_format(out)
    report = collect_rooms(store, since=since, now=now, rigs=rigs, out=out)
    report.out = out
    for room in report.rooms:
        path = out.parent / room.drift_file
        room.drift.out = path
        write_report("drift", path, room.drift)
        if progress:
            progress(f"wrote {path} ({room.label})")
    write_report("department", out, report)
    return report


__all__ = ["build_drift_report", "build_drift_report_every_rig", "build_rooms_report"]
