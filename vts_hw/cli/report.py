"""`vts report ...`: trend reports from the results store."""

from __future__ import annotations

import click

from . import cli
from .common import echo_json, json_option, with_rig


@cli.group()
def report() -> None:
    """Reports from the results store."""


@report.command()
@click.option("--since", default="60d", show_default=True,
              help="Period to show: 60d, 8w, 12h, or a date such as 2026-09-01.")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), default="drift-report.html",
              show_default=True, help="report.html (self-contained) or report.pdf.")
@json_option
@with_rig
def drift(since: str, out: str, as_json: bool, rig) -> None:
    """Drift trend per camera: drift in x and y over time with tolerance and action bands,
    control limits, the LED checks, and a forecast of the day the action level is reached."""
    from ..report import build_drift_report, parse_since
    from .qa_run import open_store

    if not (out.endswith(".html") or out.endswith(".pdf")):
        raise click.UsageError("the report is written as .html or .pdf: give -o report.html or -o report.pdf")
    try:
        start = parse_since(since)
    except ValueError as exc:
        raise click.BadParameter(str(exc), param_hint="--since") from None
    with open_store(rig) as store:
        rep = build_drift_report(store, out, since=start, rig=rig.rig)
    if as_json:
        echo_json(rep.results_data())
    else:
        click.echo(f"wrote {out}")
