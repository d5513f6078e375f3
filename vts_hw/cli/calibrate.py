"""`vts calibrate ...`: N cameras in one frame from checkerboard images (`cameras`), the stereo
pair (`stereo`, the two-camera form), and the VTS → SPECT mapping from the 7-sphere phantom
(`spect`)."""

from __future__ import annotations

import functools
import re
import sys
from pathlib import Path

import click

from vts_hw.cli import cli
from vts_hw.cli.common import (
    OutputFile,
    config_option,
    echo_json,
    json_option,
    positive,
    rig_if_any,
    say_stored,
    store_qa_result,
)
from vts_hw.errors import DataError
from vts_hw.procedures.mapping_points import read_points  # noqa: F401  (the points file, as `--vts` reads it)


@cli.group()
def calibrate() -> None:
    """Calibration of the cameras."""


def _pattern(ctx, param, value: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", value)
    if not m or int(m.group(1)) < 2 or int(m.group(2)) < 2:
        raise click.BadParameter(f"{value!r} is not COLSxROWS of inner corners such as 9x6")
    return int(m.group(1)), int(m.group(2))


def _board_options(f):
    """The checkerboard and simulation options every calibration from boards takes."""
    for option in reversed(
        [
            click.option(
                "--sim-seed", type=int, default=0, show_default=True, help="Seed of the simulated rig, poses and noise."
            ),
            click.option(
                "--pattern",
                default="9x6",
                show_default=True,
                callback=_pattern,
                help="Inner corners of the board, COLSxROWS.",
            ),
            click.option(
                "--square",
                type=positive("a length"),
                default=None,
                help="Side of a square (default: the simulated board's 50 mm with --sim, else 1 square).",
            ),
            click.option(
                "--unit",
                type=click.Choice(["mm", "squares"]),
                default=None,
                help="Unit of --square (default: mm when --square or --sim is given, else squares).",
            ),
        ]
    ):
        f = option(f)
    return f


@calibrate.command()
@click.argument("images", nargs=-1, type=click.Path())
@click.option(
    "--sim",
    is_flag=True,
    help="Calibrate from checkerboard views rendered by the simulator"
    " (no IMAGES) and compare with the simulated cameras.",
)
@click.option(
    "--sim-poses", type=click.IntRange(3, 200), default=20, show_default=True, help="Number of simulated board poses."
)
@_board_options
@click.option(
    "-o",
    "--output",
    type=OutputFile(),
    default="calibration.json",
    show_default=True,
    help="Calibration file to write.",
)
@click.option(
    "--previous",
    type=click.Path(dir_okay=False),
    default=None,
    help="Calibration to compare with (default: the existing -o file, if any).",
)
@click.option(
    "--distortion",
    type=click.Choice(["auto", "k1", "opencv"]),
    default="auto",
    show_default=True,
    help="Lens distortion fitted: k1 alone, OpenCV's five terms (k1, k2,"
    " p1, p2, k3), or auto: whichever the data support (BIC), per camera.",
)
@click.option(
    "--force",
    is_flag=True,
    help="Replace the -o file even if it holds a calibration in mm"
    " and this one is in squares, or is not a calibration file; write a fit whose RMS is above 1 px.",
)
@config_option
@json_option
def stereo(
    images: tuple[str, ...],
    sim: bool,
    sim_poses: int,
    sim_seed: int,
    pattern: tuple[int, int],
    square: float | None,
    unit: str | None,
    output: str,
    previous: str | None,
    distortion: str,
    force: bool,
    config_path: str | None,
    as_json: bool,
) -> None:
    """Calibrate the two cameras from IMAGES: leftNN/rightNN checkerboard pairs (files or a
    directory), or from simulated views with --sim. The two-camera case of `vts calibrate
    cameras`: each camera's intrinsics from OpenCV on its own views, then the pair with those
    intrinsics fixed, so every figure is plain OpenCV's; the file is the same kind (cameras
    'left' and 'right', 'cam1' and 'cam2' with --sim).

    Prints the RMS reprojection error of each camera and of the pair with each parameter's
    standard deviation, the error of each pair with outliers flagged, the pairs skipped, and
    the change from the previous calibration; writes the calibration to -o. A parameter that
    moved by more than 3 combined standard deviations (or, with --sim, is that far from the
    truth) gets a WARNING line; warnings do not change the exit code (0). Exit 2: a usage
    mistake (e.g. squares over a calibration in mm); 3: bad images or files, a fit that cannot
    be trusted (RMS above 1 px: a WARNING line, -o not written unless --force), or -o could not
    be written (the calibration is then saved in the current folder or $TMPDIR, said where).

    The calibration is stored as a run (procedure "calibration": the RMS of each camera and of
    the pair, judged by the calibration_rms_px window) in the rig's results store when there is
    a rig config (--config, $VTS_CONFIG, ./rig.yaml), else in the per-user store; a --sim
    calibration is not stored.
    """
    from vts_hw.procedures import calibration as proc

    if sim and images:
        raise click.UsageError("give either IMAGES or --sim, not both")
    if not sim and not images:
        raise click.UsageError("give the checkerboard IMAGES (or a directory of them), or --sim")
    rig = None if sim else rig_if_any(config_path)  # a --config that cannot be read: before the work
    if unit is None:
        unit = "mm" if (square is not None or sim) else "squares"
    if square is None:
        square = _sim_square_mm() if (sim and unit == "mm") else 1.0
    if unit == "squares" and square != 1.0:
        raise click.UsageError("with --unit squares the square is 1; give --unit mm with --square")

    names = truth = score = None
    cameras = ("left", "right")
    proc.replaceable(
        Path(output), unit, force, "stereo calibration"
    )  # before the work: a forgotten --square, a wrong -o
    if sim:
        from vts_hw.sim_devices.scenarios.calibration_views import sim_views
        from vts_hw.vision.calibration_uncertainty import compare_with_truth

        square_mm = square if unit == "mm" else None  # "squares": the simulated board's size
        pairs, names, truth = sim_views(sim_seed, sim_poses, pattern, square_mm)
        truth = truth if unit == "mm" else None
        cameras = tuple(truth.names) if truth is not None else ("cam1", "cam2")  # the scene's cameras
        score = compare_with_truth
    else:
        pairs = proc.image_pairs(list(images))
    run = proc.run(
        pairs=pairs,
        output=output,
        pattern=pattern,
        square=square,
        unit=unit,
        names=names,
        cameras=cameras,
        previous=previous,
        force=force,
        truth=truth,
        score=score,
        distortion=distortion,
        what="stereo calibration",
    )
    _end_calibration(run, rig, sim, as_json)
    if run.refused:
        raise DataError(run.refused)


@calibrate.command()
@click.argument("images", nargs=-1, type=click.Path())
@click.option(
    "--sim",
    is_flag=True,
    help="Calibrate from checkerboard views rendered by the simulator"
    " (no IMAGES) and compare with the simulated cameras.",
)
@click.option(
    "--cameras",
    "n_cameras",
    type=click.IntRange(2, 8),
    default=4,
    show_default=True,
    help="Cameras of the simulated room (with --sim).",
)
@click.option(
    "--sim-poses",
    type=click.IntRange(3, 50),
    default=8,
    show_default=True,
    help="Simulated board poses held towards each chosen pair of cameras.",
)
@_board_options
@click.option(
    "--reference", default=None, help="The camera whose frame is the calibration's (default: the first camera by name)."
)
@click.option(
    "-o",
    "--output",
    type=OutputFile(),
    default="calibration.json",
    show_default=True,
    help="Calibration file to write (compared with first if it exists).",
)
@click.option(
    "--previous",
    type=click.Path(dir_okay=False),
    default=None,
    help="Calibration to compare with (default: the existing -o file, if any).",
)
@click.option(
    "--distortion",
    type=click.Choice(["auto", "k1", "opencv"]),
    default="auto",
    show_default=True,
    help="Lens distortion fitted per camera (as for `stereo`).",
)
@click.option(
    "--force",
    is_flag=True,
    help="Replace the -o file even if it holds a calibration in mm"
    " and this one is in squares, or is not a calibration file; write a fit that did not"
    " converge or whose RMS is above 1 px.",
)
@config_option
@json_option
def cameras(
    images: tuple[str, ...],
    sim: bool,
    n_cameras: int,
    sim_poses: int,
    sim_seed: int,
    pattern: tuple[int, int],
    square: float | None,
    unit: str | None,
    reference: str | None,
    output: str,
    previous: str | None,
    distortion: str,
    force: bool,
    config_path: str | None,
    as_json: bool,
) -> None:
    """Calibrate N >= 2 cameras into one frame (the reference camera's) from checkerboard IMAGES,
    or from simulated views with --sim.

    \b
    IMAGES are files or folders:
      <camera>_<view>.jpg   one image; the camera is the name before the last '_'
                            (cam1_01.jpg, cam2_01.jpg, cam2_02.png ...)
      DIR                   a folder of such images, or a folder with one folder per
                            camera (DIR/cam1/01.jpg, DIR/cam2/01.jpg: named after the
                            camera, each image after its view)
      DIR/cam1 DIR/cam2     the camera folders themselves (images named by view)
      leftNN/rightNN        stereo names: cameras 'left' and 'right'

    Each view must be seen by two or more cameras, and the views must connect every camera
    (no view needs all). Each camera's intrinsics come from OpenCV on its own views, the poses
    are chained from the reference camera over shared views, then one bundle adjustment refines
    everything. Prints per camera and per view RMS (outliers flagged), the view graph, and the
    change from the previous calibration; writes -o. Exit 2: a usage mistake (e.g. squares over
    a calibration in mm); 3: images or files that cannot be used — among them views that do
    not connect the cameras, or a camera in no view shared with another, or a fit that cannot be
    trusted (the bundle adjustment did not converge, or RMS above 1 px: WARNING lines, -o not
    written unless --force) — or -o could not be written (the calibration is then saved in the
    current folder or $TMPDIR, said where), or the store did not take the run.

    The calibration is stored as a run (procedure "calibration", as `vts calibrate stereo`'s: the
    RMS of each camera and of the set, judged by the calibration_rms_px window, and whether the
    bundle adjustment converged; runs stored before as "calibration_cameras" are read as
    calibrations too), a fit not written too, in the rig's results store with the rig's name when
    there is a rig config (--config, $VTS_CONFIG, ./rig.yaml), else in the per-user store with
    an empty rig name. A --sim calibration is not stored.
    """
    from vts_hw.procedures import calibration as proc

    if sim and images:
        raise click.UsageError("give either IMAGES or --sim, not both")
    if not sim and not images:
        raise click.UsageError("give the checkerboard IMAGES (or folders of them), or --sim")
    rig = None if sim else rig_if_any(config_path)
    if unit is None:
        unit = "mm" if (square is not None or sim) else "squares"
    if square is None:
        square = _sim_square_mm() if (sim and unit == "mm") else 1.0
    if unit == "squares" and square != 1.0:
        raise click.UsageError("with --unit squares the square is 1; give --unit mm with --square")
    proc.replaceable(Path(output), unit, force)  # before the work
    truth = score = info = None
    if sim:
        from vts_hw.sim_devices.scenarios.calibration_views import cameras_against_truth, sim_camera_views

        imgs, truth, info = sim_camera_views(sim_seed, n_cameras, sim_poses, pattern, square if unit == "mm" else None)
        truth = truth if unit == "mm" else None
        score = functools.partial(cameras_against_truth, points=info.pop("fov_points"))
    else:
        imgs = proc.camera_images(list(images))
    run = proc.run(
        images=imgs,
        output=output,
        pattern=pattern,
        square=square,
        unit=unit,
        previous=previous,
        force=force,
        distortion=distortion,
        reference=reference,
        truth=truth,
        score=score,
        sim=info,
    )
    _end_calibration(run, rig, sim, as_json)
    if run.refused:
        raise DataError(run.refused)


def _end_calibration(run, rig, sim: bool, as_json: bool) -> None:
    """Store a calibration from images as a run (not a simulated one: a demonstration, not the
    room's history), print it, say where it was stored; -o's error, else exit 3 when the store
    did not take it."""
    run.tolerances = rig.tolerances if rig is not None else None  # the rig's windows judge it
    data = run.results_data()
    stored = None
    if not sim:
        sv = run.saved
        notes = (
            f"saved to {sv.written}"
            if sv.written
            else f"saved to {sv.fallback} ({sv.path} could not be written)"
            if sv.fallback
            else f"not written: {getattr(run, 'refused', None) or sv.error or sv.path}"
        )
        stored = store_qa_result(rig, run, data, notes=notes)
    if as_json:
        echo_json(data)
        for line in run.warnings:
            click.echo(line, err=True)
    else:
        click.echo(run.results())
    sys.stdout.flush()
    failed = stored is not None and say_stored(stored, run, "calibration", as_json)
    if run.saved.error is not None:
        raise run.saved.error
    if failed:
        sys.exit(3)


def _sim_square_mm() -> float:
    from vts_hw.sim_devices.scenarios.calibration_views import sim_square_mm

    return sim_square_mm()


# ---------------------------------------------------------------- vts calibrate spect


def _from_cameras(config_path, calibration_path, volume, frames: int, quiet: bool):
    """The mapping with the VTS side measured now by every camera the calibration covers."""
    from vts_hw.drivers.registry import check_camera_kinds
    from vts_hw.procedures.mapping_inputs import calibrated_cameras, camera_calibration_for, mapping_from_cameras
    from vts_hw.room import Room

    with Room.open(config_path) as room:  # the cameras it opens are closed with it
        calib = camera_calibration_for(room.rig, calibration_path or room.calibration_file)
        cfgs = calibrated_cameras(room.rig, calib)
        check_camera_kinds(cfgs)
        cams = [room.camera(c.name) for c in cfgs]
        return mapping_from_cameras(
            cams, calib, volume, frames, progress=None if quiet else (lambda m: click.echo(m, err=True))
        )


@calibrate.command()
@click.option(
    "--vts",
    "vts_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Phantom sphere centres in the VTS frame: CSV with a header x,y,z (mm), or a JSON list of [x, y, z].",
)
@click.option(
    "--volume",
    type=click.Path(),
    default=None,
    help="Reconstructed SPECT volume of the phantom (any format `read_volume` reads).",
)
@click.option(
    "--from-cameras",
    is_flag=True,
    help="Take the VTS side from the rig's cameras now (every camera the calibration covers: LED"
    " on, --frames snapshots each, triangulated); the spheres are picked out by the"
    " shape of the SPECT's. Needs --volume.",
)
@click.option(
    "--calibration",
    "calibration_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Camera calibration (stereo or N cameras) for --from-cameras (default: the config's calibration.cameras).",
)
@click.option(
    "--frames",
    type=click.IntRange(1, 100),
    default=10,
    show_default=True,
    help="Snapshots per camera with --from-cameras.",
)
@config_option
@click.option(
    "--sim",
    is_flag=True,
    help="Map a simulated session (stereo VTS + SimSpect volume) and compare with the simulated truth.",
)
@click.option("--sim-seed", type=int, default=0, show_default=True, help="Seed of the simulated rig, noise and volume.")
@click.option(
    "-o",
    "--output",
    type=OutputFile(),
    default="spect_mapping.json",
    show_default=True,
    help="VTS → SPECT transform file to write (an earlier mapping there is"
    " replaced; any other file is refused, exit 3, unless --force).",
)
@click.option("--force", is_flag=True, help="Replace the -o file even if it is not a mapping file.")
@json_option
def spect(
    vts_path: str | None,
    volume: str | None,
    from_cameras: bool,
    calibration_path: str | None,
    frames: int,
    config_path: str | None,
    sim: bool,
    sim_seed: int,
    output: str,
    force: bool,
    as_json: bool,
) -> None:
    """VTS → SPECT mapping from the 7-sphere phantom: its sphere centres in the VTS frame
    (--vts, or --from-cameras to measure them now) and its reconstructed SPECT volume
    (--volume), or a simulated session (--sim).

    Prints the transform, the FRE and the leave-one-out TRE; writes the transform to -o. If -o
    cannot be written (exit 3) the mapping is saved in the current folder or $TMPDIR instead.
    An -o that exists and is not a mapping file is refused before any work (exit 3).

    The mapping is stored as a run (procedure "spect_mapping") in the rig's results store with
    the rig's name when there is a rig config (--config, $VTS_CONFIG, ./rig.yaml), else in the
    per-user store with an empty rig name; a --sim mapping is not stored. Exit 3 also when the
    store did not take the run (its figures go to a file `vts qa import` stores later).
    """
    import json
    import tempfile

    from vts_hw.procedures.spect_mapping import SpectMapping, replaceable
    from vts_hw.save_or_keep import save_or_keep

    if sim and (vts_path or volume or from_cameras):
        raise click.UsageError("give either --vts/--from-cameras and --volume, or --sim, not both")
    if vts_path and from_cameras:
        raise click.UsageError("give either --vts POINTS or --from-cameras, not both")
    if not sim and not ((vts_path or from_cameras) and volume):
        raise click.UsageError("give --vts POINTS (or --from-cameras) and --volume VOLUME, or --sim")

    out_path = Path(output)
    replaceable(out_path, force)  # before the work: a rig.yaml given as -o by mistake
    info = None
    if sim:
        from vts_hw.sim_devices.scenarios.calibration_views import compare_mapping_with_truth, sim_spect_inputs

        with tempfile.TemporaryDirectory(prefix="vts-spect-sim-") as tmp:
            points, vol_path, info = sim_spect_inputs(sim_seed, Path(tmp))
            mapping = SpectMapping.from_volume(points, vol_path).analyze()
    elif volume is None:  # the usage check above refuses a run with neither --sim nor --volume
        raise RuntimeError("--volume missing past the usage check")
    elif from_cameras:
        if not Path(volume).exists():
            raise DataError(f"{volume}: no such file or directory.")
        mapping = _from_cameras(config_path, calibration_path, volume, frames, as_json)
    else:
        points = read_points(vts_path)
        if not Path(volume).exists():
            raise DataError(f"{volume}: no such file or directory.")
        mapping = SpectMapping.from_volume(points, volume).analyze()
    compare = compare_mapping_with_truth(mapping, info) if info is not None else None
    rig = None if sim else rig_if_any(config_path)
    mapping.tolerances = rig.tolerances if rig is not None else None  # the rig's windows judge it
    # the transform file as RigidTransform.save writes it, but kept if -o cannot be written
    saved = save_or_keep(out_path, json.dumps(mapping.fitted().transform.to_dict(), indent=2) + "\n", "mapping")

    data = mapping.results_data()
    stored = None
    if not sim:  # a simulated session is a demonstration, not the room's history
        stored = store_qa_result(rig, mapping, data, notes=f"saved to {saved.path}")
    if as_json:
        data.update(saved.data())
        if info is not None:
            data["sim"] = {k: v for k, v in info.items() if k != "truth"}
            data["sim"]["phantom_centre_spect_mm"] = info["phantom_centre_spect_mm"].tolist()
            data["sim_truth"] = compare
        echo_json(data)
    else:
        _spect_text(mapping, info, compare, saved)
    if stored is not None and say_stored(stored, mapping, "mapping", as_json) and saved.error is None:
        sys.exit(3)
    if saved.error is not None:
        raise saved.error


def _spect_text(mapping, info, compare, saved) -> None:
    if info is not None:
        err = info["triangulation_error_mm"]
        click.echo(
            f"Simulated session (seed {info['seed']}): VTS = the two simulated cameras with"
            f" their TRUE models (as if perfectly calibrated), detections averaged over"
            f" {info['frames_averaged']} noisy frames, VTS frame = camera 1;"
            f" triangulation error RMS {err['rms']:.3f} mm, max {err['max']:.3f} mm."
        )
    click.echo(mapping.results())
    if compare is not None:
        click.echo(
            f"Compared with the simulated truth (camera 1's pose inverse): rotation off by"
            f" {compare['rotation_error_deg']:.4f} deg, translation off by"
            f" {compare['translation_error_at_phantom_mm']:.3f} mm at the phantom."
        )
    if saved.written:
        click.echo(f"wrote {saved.written}")
