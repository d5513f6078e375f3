"""`vts report ...`: trend reports from the results store."""

from __future__ import annotations

import click

from vts_hw.cli import cli
from vts_hw.cli.common import echo_json, json_option, with_rig


@cli.group()
def report() -> None:
    """Reports from the results store."""


@report.command()
@click.option("--since", default="60d", show_default=True,
              help="Period to show: 60d, 8w, 12h, a UTC date such as 2026-09-01, or all. A period "
                   "reaching back before 1970 or starting in the future is refused (exit 2).")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), default="drift-report.html",
              show_default=True, help="report.html (self-contained) or report.pdf.")
@json_option
@with_rig
def drift(since: str, out: str, as_json: bool, rig) -> None:
    """Drift trend per camera: drift in x and y over time with tolerance and action bands,
    control limits, the LED checks, and a forecast of the day the action level is reached.

    A trend needs 5 runs over 7 days since the latest baseline, a forecast a significant slope
    (p < 0.05); the report says why when there is none. The file is written whole or not at all.

    Exit status: 0 written; 2 a bad --since or -o; 3 the store or the file could not be
    read or written (a previous report is left as it was).
    """
    from vts_hw.report.drift import build_drift_report, parse_since, report_format
    from vts_hw.cli.qa_run import open_store

    report_format(out)                  # ReportError: one sentence, exit 2
    start = parse_since(since)          # BadSince: one sentence, exit 2
    with open_store(rig) as store:
        rep = build_drift_report(store, out, since=start, rig=rig.rig)
    if as_json:
        echo_json(rep.results_data())
    else:
        click.echo(f"wrote {out}" + ("" if rep.cameras else " (no completed drift runs in the period)"))
