"""`vts motion ...`: offline patient motion of a scan session."""

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
def motion() -> None:
    """Patient motion: breathing, body pose, motion events and states, exports for reconstruction."""


@motion.command()
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
    help="VTS -> SPECT transform file (default: the rig config's calibration.mapping); without one "
    "poses are in the VTS frame.",
)
@click.option(
    "-o",
    "--output",
    "out",
    type=OutputFile(),
    default=None,
    help="Write the report here: NAME.html (self-contained: the plot inline) or NAME.pdf.",
)
@click.option("--plot", "plot_path", type=OutputFile(), default=None, help="Also write the plot as a PNG.")
@click.option(
    "--export",
    "export_dir",
    type=OutputFolder("export folder"),
    default=None,
    help="Write the motion files to DIR (docs/motion-formats.md): motion_6dof.csv/.json, respiration.csv, "
    "subsets.json, trajectories.csv/.json, CASToR's castor_motion.dyn and castor_motion_rigid.txt "
    "and YRT-PET's yrtpet_lor_motion.csv (these three only with --listmode and a mapping made from a "
    "volume: they are read on the list-mode clock); every pose with its health and confidence.",
)
@click.option(
    "--bins",
    type=click.IntRange(2, 20),
    default=4,
    show_default=True,
    help="Respiratory bins (by amplitude and by phase) in subsets.json.",
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
    bins,
    workers,
    as_json,
    config_path,
) -> None:
    """Breathing, body 6-DOF pose, motion events and motion states of a scan SESSION.

    The patient's markers are found by behaviour (they breathe or move); breathing is taken out
    of the body pose; a motion state is an interval of pose within the rig's motion.state_mm and
    motion.state_deg. With the scan's list-mode (--listmode, as `vts sync analyze` takes it: a
    glob of several picks the session's own) the session goes through the sync analysis and
    every time is list-mode seconds (the session then needs its trigger.csv); without it, host
    time. The scan's whole span is analysed (what the recording's index, manifest and scan
    times say it covers): frames a camera skipped, a .mjpeg cut short or a camera's missing
    files are time without a pose, counted in motion_pose_coverage (the share of the scan's
    time with a pose) and shown as such in every output; a breath counts only when seen whole,
    so a rate may be bounded (a range) or unknown, and a move that began in a gap has its start
    given as a range. Exit status like the QA procedures: 0 OK, 10 TOLERANCE, 20 ACTION
    (windows motion_body_max_mm, motion_body_max_deg, motion_pose_coverage); 2 bad input; 3 a
    file could not be read or written, or the run could not be stored (its figures then go
    to a file that `vts qa import` stores later).
    """
    from vts_hw.files import Outputs, write_atomic
    from vts_hw.report.renderers import report_format, write_report

    if out:
        report_format(out)  # -o x.txt: one sentence, exit 2, before anything is read
    cal, mp, rig = calibration_files(config_path, calibration, mapping)
    candidates = listmode_candidates(listmode, more)
    from vts_hw.procedures.motion import MotionAnalysis  # (its libraries load once the inputs are named)

    a = MotionAnalysis(
        session,
        candidates or None,
        cal,
        mp,
        motion_config=rig.motion if rig is not None else None,
        workers=workers,
        progress=FramesProgress(),
        clock_slack_s=clock_slack,
    )
    a.analyze(tolerances=rig.tolerances if rig is not None else None)
    data = a.results_data()
    # the report, the plot and the export are each written whole or not at all; one that cannot
    # be written (disk full) is said at the end: the analysis is still printed and stored
    outs = Outputs()
    exported = outs.attempt(a.export, export_dir, n_bins=bins) if export_dir else None
    if exported is not None:
        data["export"] = [str(p) for p in exported]
        data["export_notes"] = list(a.export_notes)
    png = a.plot() if (out or plot_path) else None
    plot_ok = bool(plot_path) and outs.attempt(write_atomic, plot_path, png) is not None
    report_ok = bool(out) and outs.attempt(write_report, "motion", out, data, png) is not None
    if report_ok:
        data["report"] = str(out)
    finish_analysis(
        rig,
        a,
        data,
        "motion analysis",
        as_json,
        notes=f"session {session}",
        artifacts=[plot_path] if plot_ok else [],
        outputs=outs,
        lines=[
            *([f"report: {out}"] if report_ok else []),
            *([f"plot: {plot_path}"] if plot_ok else []),
            *([f"exported ({data['clock']}): {', '.join(data['export'])}"] if exported else []),
            *(data.get("export_notes") or []),
        ],
    )
