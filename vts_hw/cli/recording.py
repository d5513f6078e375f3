"""`vts recording ...`: inspect recordings and rebuild their indexes."""

from __future__ import annotations

import os

import click

from vts_hw.cli import cli
from vts_hw.cli.common import OutputFolder, config_option, echo_json, fmt_time, json_option
from vts_hw.recording import promised as rec_mod


@cli.group()
def recording() -> None:
    """Inspect recordings (folders, .mjpg captures, JPEG files) and repair their indexes."""


@recording.command()
@click.argument("folder", type=click.Path(file_okay=False))
@json_option
def reindex(folder: str, as_json: bool) -> None:
    """Rebuild every NAME.index.csv in FOLDER from NAME.mjpeg alone (after a crash).

    An index is replaced only when the rebuilt one keeps every frame the old one lists;
    otherwise the old one stays and the rebuilt one is written beside it as
    NAME.index.rebuilt.csv. A manifest that is not a recording manifest is kept as
    manifest.unreadable.json and a fresh one written; one left "recording" by a vts that was
    killed is marked recovered. Exit status: 0 rebuilt; 2 a vts is recording into FOLDER right
    now (nothing changed); 3 something was damaged or could not be written (said in one
    sentence per problem).
    """
    from vts_hw.errors import DataError
    from vts_hw.recording.reindex import reindex as do_reindex

    report = do_reindex(folder)
    if as_json:
        echo_json(
            {
                "folder": str(report.folder),
                "cameras": [c.as_dict() for c in report.cameras],
                "problems": report.problems,
            }
        )
    else:
        for r in report.cameras:
            torn = f", {r.torn} torn frame(s) at the end left out" if r.torn else ""
            what = "indexed" if r.replaced else "found (index NOT replaced)"
            click.echo(f"{r.name}: {r.frames} frames {what} ({r.host_times_kept} with host times kept){torn}")
    for problem in report.problems:
        click.echo(f"vts: {problem}", err=True)
    if report.problems:
        raise DataError(f"{folder}: reindexed with {len(report.problems)} problem(s) (above); nothing was lost")


@recording.command()
@click.argument("paths", nargs=-1, required=True, type=click.Path())
@json_option
def info(paths: tuple[str, ...], as_json: bool) -> None:
    """Frames in recordings, .mjpg captures or JPEG files: count, camera times, gaps.

    The frames counted are the readable ones. For a recording folder, each camera's line also
    says how many frames its index or the manifest promised, and a camera of the manifest whose
    files are gone is listed with the files missing. Exit status: 0 every recording holds what
    it promised; 3 one does not (a .mjpeg cut short, a file missing, an index shorter than the
    manifest; said last in one sentence), or a file could not be read, or a folder's manifest
    is gone, unreadable, or was left "recording" by a vts that was killed (an interrupted
    recording: 'vts recording reindex' marks it recovered). A recording being made now is
    counted as far as it goes (exit 0).
    """
    from vts_hw.errors import DataError
    from vts_hw.recording.promised import manifest_problem, shortfall

    summaries, short = [], []
    for p in paths:
        found = rec_mod.info(p)
        summaries += found
        unvouched = manifest_problem(p) if os.path.isdir(p) else ""
        if unvouched:
            short.append(unvouched)
        if shortfall(found):
            short.append(f"{p} is not whole ({shortfall(found)})")
    if as_json:
        echo_json([s.as_dict() for s in summaries])
    else:
        _print_info(summaries)
    if short:
        raise DataError("; ".join(short))


def _print_info(summaries) -> None:
    for s in summaries:
        dur = (s.last_time - s.first_time) if s.first_time is not None and s.last_time is not None else None
        promised = f" of {s.promised} promised" if s.promised is not None and s.promised != s.frames else ""
        missing = f" ({' and '.join(s.missing_files)} missing)" if s.missing_files else ""
        click.echo(
            f"{s.source}: {s.frames}{promised} frame(s) readable{missing}, {s.with_time} with Axis time, {s.torn} torn"
        )
        if s.first_time is not None:
            click.echo(
                f"  camera time {fmt_time(s.first_time)} .. {fmt_time(s.last_time)}"
                f" ({dur:.2f} s{f', {s.fps:g} fps' if s.fps else ''})"
            )
        if s.gaps:
            missing = sum(g["missing"] for g in s.gaps)
            click.echo(f"  {len(s.gaps)} gap(s), {missing} frame(s) missing:")
            for g in s.gaps[:20]:
                click.echo(f"    after frame {g['after_frame']}: {g['seconds']} s ({g['missing']} missing)")
        for p in s.problems[:20]:
            click.echo(f"  note: {p}")


@recording.command()
@click.argument("session", type=click.Path(file_okay=False))
@click.option(
    "-o",
    "--output",
    "out",
    type=OutputFolder("output folder"),
    required=True,
    help="Folder for trajectories.csv and trajectories.json (docs/trajectory-format.md).",
)
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
    help="VTS -> SPECT transform file (default: the rig config's calibration.mapping): adds SPECT-frame positions.",
)
@click.option("--workers", type=click.IntRange(1, 256), default=None, help="Processes (default: every core).")
@json_option
@config_option
def process(session, out, calibration, mapping, workers, as_json, config_path) -> None:
    """The marker tracks of a recording SESSION alone (for researchers): every frame set
    triangulated, identities kept, written to OUT/trajectories.csv and .json (host time).
    Exit status: 0 written; 2 no calibration; 3 the recording or the output could not be read
    or written."""
    from vts_hw.cli.common import FramesProgress, calibration_files
    from vts_hw.files import ensure_dir
    from vts_hw.tracking.processing import process_recording
    from vts_hw.vision.calibration_io import read_calibration
    from vts_hw.vision.registration import read_mapping

    cal, mp, _ = calibration_files(config_path, calibration, mapping)
    tracks = process_recording(
        session, read_calibration(cal), workers=workers, mapping=read_mapping(mp), progress=FramesProgress()
    )
    folder = ensure_dir(out, "output folder")
    paths = tracks.save(folder / "trajectories.csv")
    if as_json:
        echo_json(
            {
                "session": str(session),
                "files": [str(p) for p in paths],
                "frames": len(tracks),
                "points": int(len(tracks.marker)),
                "markers": tracks.marker_summary(),
                "warnings": tracks.meta.get("warnings", []),
            }
        )
    else:
        click.echo(
            f"{session}: {len(tracks)} frame sets, {len(tracks.marker)} points, "
            f"{len(tracks.marker_ids())} marker ids -> {', '.join(str(p) for p in paths)}"
        )
