"""`vts qa ...`: the daily QA set and the wall-marker drift check."""

from __future__ import annotations

import os
import sys

import click

from vts_hw.cli import cli
from vts_hw.cli.common import json_option, with_rig
from vts_hw.cli.qa_push import check_push_config, push


@cli.group()
def qa() -> None:
    """QA procedures. Exit status: 0 OK, 10 TOLERANCE, 20 ACTION; 2-5 when the QA could not run."""


qa.add_command(push)


def _common(f):
    f = click.option("--camera", "cameras", multiple=True, help="Only this camera (repeatable).")(f)
    f = click.option(
        "--frames", type=click.IntRange(1, 50), default=5, show_default=True, help="LED-on snapshots per camera."
    )(f)
    f = click.option("--plots", is_flag=True, help="Save a drift plot per camera next to the saved frames.")(f)
    f = click.option("--dry-run", is_flag=True, help="List the steps without touching the rig or the store.")(f)
    f = click.option("--operator", default=lambda: os.environ.get("USER", ""), help="Who runs it.")(f)
    return json_option(f)


@qa.command()
@_common
@click.option("--set-baseline", is_flag=True, help="Record today's markers as the baseline instead of checking.")
@with_rig
def drift(rig, cameras, frames, plots, dry_run, operator, as_json, set_baseline) -> None:
    """Wall-marker drift and LED check: has a camera moved since its baseline?

    LED on and a few snapshots per camera, the wall markers' sub-pixel centroids matched to the
    baseline markers, mean and SD of the displacement in x and y (px and mm at the wall); an
    LED-off frame checks that the markers vanish. Stored in the results store.
    """
    from vts_hw.cli.qa_run import run_qa
    from vts_hw.cli.qa_run import set_baseline as do_baseline

    if set_baseline:
        do_baseline(rig, list(cameras), frames, dry_run, operator, as_json)
        return
    sys.exit(run_qa(rig, ("drift",), list(cameras), frames, plots, dry_run, operator, as_json))


@qa.command()
@_common
@click.option(
    "--push",
    "push_after",
    is_flag=True,
    help="Then post the stored run to QATrack+ (rig.yaml's qatrack: section, see `vts qa push`); a "
    "failed push is one line on stderr and stays in the outbox; the exit status stays the QA's.",
)
@with_rig
def daily(rig, cameras, frames, plots, dry_run, operator, as_json, push_after) -> None:
    """The daily set: each camera reachable, its parameters still locked, its clock, the LED, the drift."""
    from vts_hw.cli.qa_run import run_qa

    if push_after and not dry_run:
        check_push_config(rig)
    sys.exit(
        run_qa(
            rig,
            ("reachable", "params", "clock", "drift"),
            list(cameras),
            frames,
            plots,
            dry_run,
            operator,
            as_json,
            push=push_after,
        )
    )


@qa.command("import")
@click.argument("files", nargs=-1, required=True, type=click.Path(exists=True, dir_okay=False))
@with_rig
def import_(rig, files) -> None:
    """Store QA runs that the results store could not take when they ran.

    A run whose store could not be written (disk full, read-only, database down) is kept in
    an ``unsaved/*.json`` file next to the store (the run says where). This stores each FILE
    as the run it was, with its own times, states and tolerance windows, and renames the
    file ``*.imported`` so it is never stored twice.
    """
    from vts_hw.cli.qa_run import import_runs

    for f, run_id in import_runs(rig, files):
        click.echo(f"{f}: stored as run {run_id}")
