"""`vts sync ...`: line the VTS and the SPECT list-mode up in time."""

from __future__ import annotations

import click

from vts_hw.cli import cli
from vts_hw.cli.common import (
    FramesProgress,
    OutputFile,
    OutputFolder,
    calibration_files,
    config_option,
    finish_analysis,
    json_option,
    listmode_candidates,
    listmode_options,
)


@cli.group()
def sync() -> None:
    """Time synchronisation of a scan session with the SPECT list-mode."""


@sync.command()
@click.argument("session", type=click.Path())
@listmode_options
@click.option(
    "--calibration",
    type=click.Path(dir_okay=False),
    default=None,
    help="Camera calibration file (default: the rig config's calibration.cameras).",
)
@click.option(
    "--mapping",
    type=click.Path(dir_okay=False),
    default=None,
    help="VTS -> SPECT transform file (default: the rig config's calibration.mapping).",
)
@click.option(
    "-o",
    "--output",
    "out",
    type=OutputFile(),
    default=None,
    help="Write the report here: NAME.html (self-contained: the plot inline) or NAME.pdf.",
)
@click.option("--plot", "plot_path", type=OutputFile(), default=None, help="Also write the plot as a PNG here.")
@click.option(
    "--export",
    "export_dir",
    type=OutputFolder("export folder"),
    default=None,
    help="Export the marker trajectories in the SPECT frame on SPECT time to DIR "
    "(trajectories.csv and .json, docs/trajectory-format.md).",
)
@click.option(
    "--marker", type=int, default=None, help="The marker id to follow (default: the one with the largest axial range)."
)
@click.option(
    "--workers", type=click.IntRange(1, 256), default=None, help="Processes for the recording (default: every core)."
)
@json_option
@config_option
def analyze(
    session,
    more,
    listmode,
    clock_slack,
    calibration,
    mapping,
    out,
    plot_path,
    export_dir,
    marker,
    workers,
    as_json,
    config_path,
) -> None:
    """Put a scan SESSION and its SPECT list-mode on one clock.

    The gating signal gives the SPECT start delay, clock and dead time; the recording gives the
    marker's motion on the host clock; the motion events found in both give the time
    difference of each and the overall offset (VTS - SPECT, median).

    A list-mode whose acquisition (its header's start time and duration) does not overlap the
    session is refused (exit 3), as is a choice of several that overlap; when none belongs, a
    failure record the SPECT left beside the files says why it recorded nothing.

    Exit status like the QA procedures: 0 OK (every event seen by both within 20 ms), 10
    TOLERANCE (within 100 ms, or an event seen by one system only), 20 ACTION. The windows
    are the tolerance table's sync_max_abs_dt_ms, sync_events_one_system and
    sync_events_both (rig.yaml may override them). The check is stored as a run of
    procedure "sync" in the results store (rig.yaml's store.url); when the store cannot take
    it, its figures go to a file that `vts qa import` stores later, and the exit status is 3.
    """
    from vts_hw.files import Outputs, write_atomic
    from vts_hw.procedures.sync_inputs import CLOCK_SLACK_S, check_session
    from vts_hw.report.renderers import report_format, write_report

    if out:
        report_format(out)  # -o x.txt: one sentence, exit 2, before anything is read
    candidates = listmode_candidates(listmode, more)
    if not candidates:
        raise click.UsageError("give the scan's list-mode: --listmode FILE")
    check_session(session)  # a bad folder says so before anything else is read
    cal, mp, rig = calibration_files(config_path, calibration, mapping)
    from vts_hw.procedures.sync import SyncAnalysis, export_trajectories  # (its libraries load now)

    a = SyncAnalysis(
        session,
        candidates,
        cal,
        mp,
        marker=marker,
        workers=workers,
        progress=FramesProgress(),
        clock_slack_s=CLOCK_SLACK_S if clock_slack is None else clock_slack,
    )
    a.analyze(tolerances=rig.tolerances if rig is not None else None)
    data = a.results_data()
    # the report, the plot and the export are each written whole or not at all; one that cannot
    # be written (disk full) is said at the end: the check is still printed and stored
    outs = Outputs()
    png = a.plot() if (out or plot_path) else None
    plot_ok = bool(plot_path) and outs.attempt(write_atomic, plot_path, png) is not None
    report_ok = bool(out) and outs.attempt(write_report, "sync", out, data, png) is not None
    if report_ok:
        data["report"] = str(out)
    exported = outs.attempt(export_trajectories, a.tracks, a.gating, export_dir, mp) if export_dir else None
    if exported is not None:
        data["export"] = [str(p) for p in exported]
    finish_analysis(
        rig,
        a,
        data,
        "sync check",
        as_json,
        notes=f"session {session}",
        artifacts=[plot_path] if plot_ok else [],
        outputs=outs,
        lines=[
            *([f"report: {out}"] if report_ok else []),
            *([f"plot: {plot_path}"] if plot_ok else []),
            *([f"trajectories (SPECT frame, SPECT time): {', '.join(data['export'])}"] if exported else []),
        ],
    )
