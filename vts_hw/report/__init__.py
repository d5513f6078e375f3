"""Reports built from the results store.

- ``build_drift_report(store, out, since=None, now=None, rig=None, title=None)``: the camera drift
  trend report, written as a self-contained HTML file or a PDF; returns a ``DriftReport``
  (``results_data()`` gives its numbers as a JSON-ready dict).
- ``parse_since("60d" | "8w" | "12h" | "2026-09-01")``: the start of a report period, as UTC epoch
  seconds, for ``vts report drift --since``.
"""

from vts_hw.report.drift import ReportError, build_drift_report, collect
from vts_hw.report.model import DriftReport
from vts_hw.report.times import BadSince, parse_since

__all__ = ["build_drift_report", "collect", "DriftReport", "ReportError", "parse_since", "BadSince"]
