"""`vts calibrate ...`: stereo calibration of the two cameras from checkerboard images."""

from __future__ import annotations

import re
from pathlib import Path

import click
import numpy as np

from ..errors import DataError
from . import cli
from .common import echo_json, json_option

_IMAGE = re.compile(r"^(left|right)(.*)\.(jpe?g|png|bmp|tiff?)$", re.IGNORECASE)


@cli.group()
def calibrate() -> None:
    """Calibration of the cameras."""


def _pattern(ctx, param, value: str) -> tuple[int, int]:
    m = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", value)
    if not m or int(m.group(1)) < 2 or int(m.group(2)) < 2:
        raise click.BadParameter(f"{value!r} is not COLSxROWS of inner corners such as 9x6")
    return int(m.group(1)), int(m.group(2))


def image_pairs(args: list[str]) -> list[tuple[Path, Path]]:
    """(left, right) image paths from directories and/or files named leftNN / rightNN.

    A directory gives its pairs (:func:`vts_hw.calibration.find_pairs`); files are paired by
    what follows 'left' / 'right' in their names. DataError for a missing file, a file not
    named left* or right*, an unmatched image, or no pair at all.
    """
    from ..calibration import find_pairs

    pairs: list[tuple[Path, Path]] = []
    files: dict[str, dict[str, Path]] = {"left": {}, "right": {}}
    for arg in args:
        path = Path(arg)
        if path.is_dir():
            found = find_pairs(path)
            if not found:
                raise DataError(f"{path}: no leftNN/rightNN image pairs in this directory.")
            pairs.extend(found)
            continue
        if not path.exists():
            raise DataError(f"{path}: no such file or directory.")
        m = _IMAGE.match(path.name)
        if not m:
            raise DataError(f"{path}: image names must be leftNN.jpg / rightNN.jpg (or .png) so"
                            " that left and right can be paired.")
        side, key = m.group(1).lower(), m.group(2).lower()
        if key in files[side]:
            raise DataError(f"{path} and {files[side][key]} are both {side} image {key!r}.")
        files[side][key] = path
    for side, other in (("left", "right"), ("right", "left")):
        for key, path in files[side].items():
            if key not in files[other]:
                raise DataError(f"{path} has no matching {other} image ({other}{key}.*).")
    pairs.extend((files["left"][k], files["right"][k]) for k in sorted(files["left"]))
    if not pairs:
        raise DataError("no image pairs given: name leftNN/rightNN images or a directory of them.")
    return pairs


def sim_truth(calib, scene) -> dict:
    """How `calib` (cam1 = left, cam2 = right, unit mm) compares with the simulated cameras."""
    from ..calibration_io import rotation_angle_deg

    c1, c2 = scene.cameras["cam1"], scene.cameras["cam2"]
    r_true = c2.R @ c1.R.T
    t_true = c2.t - r_true @ c1.t
    out: dict = {"cameras": {}}
    for cam, k_est, d_est in ((c1, calib.K1, calib.d1), (c2, calib.K2, calib.d2)):
        rows = {}
        for key, (i, j) in (("fx", (0, 0)), ("fy", (1, 1)), ("cx", (0, 2)), ("cy", (1, 2))):
            rows[key] = {"estimated": float(k_est[i, j]), "true": float(cam.K[i, j]),
                         "error": float(k_est[i, j] - cam.K[i, j])}
            if key in ("fx", "fy"):
                rows[key]["error_percent"] = 100.0 * rows[key]["error"] / float(cam.K[i, j])
        rows["k1"] = {"estimated": float(d_est.ravel()[0]), "true": float(cam.dist[0]),
                      "error": float(d_est.ravel()[0] - cam.dist[0])}
        out["cameras"][cam.name] = rows
    base_true = float(np.linalg.norm(t_true))
    base_err = calib.baseline - base_true
    cos = float(np.dot(calib.T.ravel(), t_true) / (calib.baseline * base_true))
    out["rotation"] = {"estimated_deg": rotation_angle_deg(calib.R),
                       "true_deg": rotation_angle_deg(r_true),
                       "error_deg": rotation_angle_deg(calib.R @ r_true.T)}
    out["baseline"] = {"estimated": calib.baseline, "true": base_true, "error": base_err,
                       "error_percent": 100.0 * base_err / base_true, "unit": calib.unit,
                       "direction_error_deg": float(np.degrees(np.arccos(min(1.0, cos))))}
    return out


def _sim_text(truth: dict) -> str:
    lines = ["Compared with the simulated truth (estimated - true):"]
    for name, rows in truth["cameras"].items():
        fx, fy, cx, cy, k1 = (rows[k] for k in ("fx", "fy", "cx", "cy", "k1"))
        lines.append(f"  {name}: fx {fx['error']:+.2f} px ({fx['error_percent']:+.3f} %),"
                     f" fy {fy['error']:+.2f} px ({fy['error_percent']:+.3f} %),"
                     f" cx {cx['error']:+.2f} px, cy {cy['error']:+.2f} px,"
                     f" k1 {k1['estimated']:+.4f} vs {k1['true']:+.4f}")
    rot, base = truth["rotation"], truth["baseline"]
    lines.append(f"  stereo rotation {rot['estimated_deg']:.4f} deg vs {rot['true_deg']:.4f} deg:"
                 f" off by {rot['error_deg']:.4f} deg")
    lines.append(f"  baseline {base['estimated']:.2f} vs {base['true']:.2f} {base['unit']}:"
                 f" {base['error']:+.2f} {base['unit']} ({base['error_percent']:+.3f} %),"
                 f" direction off by {base['direction_error_deg']:.4f} deg")
    return "\n".join(lines)


def _compare_text(change: dict, prev_path: Path) -> str:
    unit = change["unit"]
    lines = [f"Change from the previous calibration {prev_path}:"]
    for cam in ("1", "2"):
        lines.append(f"  camera {cam}: fx {change['fx' + cam]:+.2f} fy {change['fy' + cam]:+.2f}"
                     f" cx {change['cx' + cam]:+.2f} cy {change['cy' + cam]:+.2f} px")
    text = f"  rotation between cameras changed by {change['rotation_deg']:.4f} deg"
    if unit is None:
        text += "; translation not compared (different units)"
    else:
        text += (f", translation by {change['translation']:.4g} {unit},"
                 f" baseline {change['baseline']:+.4g} {unit}")
    lines.append(text)
    return "\n".join(lines)


@calibrate.command()
@click.argument("images", nargs=-1, type=click.Path())
@click.option("--sim", is_flag=True, help="Calibrate from checkerboard views rendered by the simulator"
              " (no IMAGES) and compare with the simulated cameras.")
@click.option("--sim-poses", type=click.IntRange(3, 200), default=18, show_default=True,
              help="Number of simulated board poses.")
@click.option("--sim-seed", type=int, default=0, show_default=True,
              help="Seed of the simulated rig, poses and noise.")
@click.option("--pattern", default="9x6", show_default=True, callback=_pattern,
              help="Inner corners of the board, COLSxROWS.")
@click.option("--square", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Side of a square (default: 30 mm with --sim, else 1 square).")
@click.option("--unit", type=click.Choice(["mm", "squares"]), default=None,
              help="Unit of --square (default: mm when --square or --sim is given, else squares).")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default="calibration.json",
              show_default=True, help="Calibration file to write.")
@click.option("--previous", type=click.Path(dir_okay=False), default=None,
              help="Calibration to compare with (default: the existing -o file, if any).")
@json_option
def stereo(images: tuple[str, ...], sim: bool, sim_poses: int, sim_seed: int,
           pattern: tuple[int, int], square: float | None, unit: str | None, output: str,
           previous: str | None, as_json: bool) -> None:
    """Calibrate the two cameras from IMAGES: leftNN/rightNN checkerboard pairs (files or a
    directory), or from simulated views with --sim.

    Prints the RMS reprojection error of each camera and of the pair, the error of each
    pair with outliers flagged, the pairs skipped, and the change from the previous
    calibration; writes the calibration to -o.
    """
    from ..calibration import calibrate_stereo
    from ..calibration_io import StereoCalibration

    if sim and images:
        raise click.UsageError("give either IMAGES or --sim, not both")
    if not sim and not images:
        raise click.UsageError("give the checkerboard IMAGES (or a directory of them), or --sim")
    if unit is None:
        unit = "mm" if (square is not None or sim) else "squares"
    if square is None:
        square = 30.0 if (sim and unit == "mm") else 1.0
    if unit == "squares" and square != 1.0:
        raise click.UsageError("with --unit squares the square is 1; give --unit mm with --square")

    out_path = Path(output)
    prev_path = Path(previous) if previous else (out_path if out_path.exists() else None)
    prev = None
    if prev_path is not None:
        try:
            prev = StereoCalibration.load(prev_path)
        except DataError:
            if previous:
                raise
            raise DataError(f"{out_path} exists and is not a stereo calibration file; give another"
                            " -o (or move it away).") from None

    truth = None
    if sim:
        from ..sim_devices import checkerboard as cb
        from ..sim_devices.scene import Scene

        scene = Scene.reference(sim_seed, start_epoch=0.0)
        square_mm = square if unit == "mm" else cb.SQUARE_MM  # "squares": a 30 mm board
        poses = cb.board_poses(scene, n=sim_poses, seed=sim_seed, pattern=pattern,
                               square_mm=square_mm)
        pairs, names = [], []
        for k, pose in enumerate(poses):
            views = [cb.decode(cb.render_board(scene, cam, pose, pattern, square_mm,
                                               seed=sim_seed * 10007 + 2 * k + i))
                     for i, cam in enumerate(("cam1", "cam2"))]
            pairs.append(tuple(views))
            names.append(f"sim{k + 1:02d}")
        calib = calibrate_stereo(pairs, pattern=pattern, square=square, unit=unit, names=names)
        truth = sim_truth(calib, scene) if unit == "mm" else None
    else:
        calib = calibrate_stereo(image_pairs(list(images)), pattern=pattern, square=square, unit=unit)

    change = calib.compare(prev) if prev is not None else None
    calib.save(out_path)
    if as_json:
        data = calib.results_data()
        data["output"] = str(out_path)
        if change is not None:
            data["change"] = dict(change, previous=str(prev_path))
        if truth is not None:
            data["sim_truth"] = truth
        echo_json(data)
        return
    click.echo(calib.results())
    if truth is not None:
        click.echo(_sim_text(truth))
    if change is not None:
        click.echo(_compare_text(change, prev_path))
    click.echo(f"wrote {out_path}")
