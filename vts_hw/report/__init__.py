"""Reports built from the results store.

- ``build_drift_report(store, out, since=None, now=None, rig=None, title=None)``: the camera drift
  trend report, written as a self-contained HTML file or a PDF; returns a ``DriftReport``
  (``results_data()`` gives its numbers as a JSON-ready dict).
- ``parse_since("60d" | "8w" | "12h" | "2026-09-01")``: the start of a report period, as UTC epoch
  seconds, for ``vts report drift --since``.
- ``camera_figure(report, camera)``: one camera's drift plot (a matplotlib figure).

Every report is written by the suffix of its file, ``.html`` or ``.pdf``, through the one table
of renderers (:mod:`vts_hw.report.renderers`); the builders that read the store are in
:mod:`vts_hw.report.build`.
"""

from vts_hw.lazy import exports

# imported when first asked for: `vts report drift -o x.txt` says no before the plots' libraries load
__getattr__ = exports(
    __name__,
    {
        "build_drift_report": "build",
        "collect": "drift",
        "DriftReport": "model",
        "ReportError": "renderers",
        "parse_since": "times",
        "BadSince": "times",
        "camera_figure": "plots",
    },
)

__all__ = ["build_drift_report", "collect", "DriftReport", "ReportError", "parse_since", "BadSince", "camera_figure"]
