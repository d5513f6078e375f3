"""`vts calibrate ...`: stereo calibration of the two cameras from checkerboard images
(`stereo`), and the VTS → SPECT mapping from the 7-sphere phantom (`spect`)."""

from __future__ import annotations

import re
from pathlib import Path

import click
import numpy as np

from ..errors import DataError
from . import cli
from .common import config_option, echo_json, json_option

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


def _sim_square_mm() -> float:
    from ..sim_devices.checkerboard import SQUARE_MM
    return SQUARE_MM


@calibrate.command()
@click.argument("images", nargs=-1, type=click.Path())
@click.option("--sim", is_flag=True, help="Calibrate from checkerboard views rendered by the simulator"
              " (no IMAGES) and compare with the simulated cameras.")
@click.option("--sim-poses", type=click.IntRange(3, 200), default=20, show_default=True,
              help="Number of simulated board poses.")
@click.option("--sim-seed", type=int, default=0, show_default=True,
              help="Seed of the simulated rig, poses and noise.")
@click.option("--pattern", default="9x6", show_default=True, callback=_pattern,
              help="Inner corners of the board, COLSxROWS.")
@click.option("--square", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Side of a square (default: the simulated board's 50 mm with --sim, else 1 square).")
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
        square = _sim_square_mm() if (sim and unit == "mm") else 1.0
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
        square_mm = square if unit == "mm" else cb.SQUARE_MM  # "squares": the simulated board
        pairs, names = cb.render_pairs(scene, n=sim_poses, seed=sim_seed, pattern=pattern,
                                       square_mm=square_mm)
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


# ---------------------------------------------------------------- vts calibrate spect
SIM_FRAMES = 5          # noisy frames averaged per camera in --sim


def read_points(path) -> np.ndarray:
    """Sphere centres (N×3, mm) from a CSV with a header x,y,z or a JSON list of [x, y, z].

    DataError for a missing or unreadable file, a missing column, a non-number or a row that
    is not three numbers.
    """
    import csv
    import json

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such file.")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read the points ({exc}).") from None
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno}).") from None
        if isinstance(data, dict) and "points" in data:
            data = data["points"]
        if not isinstance(data, list) or not all(
                isinstance(p, list) and len(p) == 3
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)
                for p in data):
            raise DataError(f"{path}: expected a JSON list of [x, y, z] points in mm.")
        pts = np.array(data, dtype=float).reshape(-1, 3)
    else:
        rows = [r for r in csv.reader(text.splitlines()) if any(c.strip() for c in r)]
        if not rows:
            raise DataError(f"{path}: empty; expected a CSV with a header x,y,z (mm).")
        header = [c.strip().lower() for c in rows[0]]
        missing = [k for k in ("x", "y", "z") if k not in header]
        if missing:
            raise DataError(f"{path}: the header {','.join(rows[0])!r} lacks column(s) "
                            f"{','.join(missing)}; expected x,y,z (mm).")
        cols = [header.index(k) for k in ("x", "y", "z")]
        pts_list = []
        for n, row in enumerate(rows[1:], start=2):
            try:
                pts_list.append([float(row[c]) for c in cols])
            except (IndexError, ValueError):
                raise DataError(f"{path}, line {n}: {','.join(row)!r} is not three numbers "
                                "x,y,z.") from None
        pts = np.array(pts_list, dtype=float).reshape(-1, 3)
    if len(pts) == 0:
        raise DataError(f"{path}: no points.")
    if not np.all(np.isfinite(pts)):
        raise DataError(f"{path}: non-finite coordinates.")
    return pts


def sim_spect_inputs(seed: int, workdir: Path) -> tuple[np.ndarray, Path, dict]:
    """The simulated session: the phantom triangulated by the stereo VTS (in camera 1's frame)
    and a SimSpect volume of its true centres (SPECT frame = scene world frame).

    Which detections are spheres (the wall markers are seen too, and some stereo pairings are
    ambiguous) is decided as on the real rig: by the shape of the SPECT's centroids
    (:func:`vts_hw.body_finder.locate_body`); the truth is used only to score.
    Returns the VTS points, the volume path and a dict of what the sim did and its truth.
    """
    from ..body_finder import locate_body
    from ..detect import detect
    from ..procedures.steps import average_centroids
    from ..sim_devices.render import Renderer
    from ..sim_devices.scene import Scene
    from ..sim_devices.spect import SimSpect
    from ..sim_devices.step_table import sphere_centres
    from ..sim_devices.sync_sim import true_spect_mapping, true_stereo_calibration
    from ..spect import find_spheres, read_volume

    scene = Scene.reference(seed, start_epoch=0.0)
    scene.add_phantom()
    t = 10.0
    names = ("cam1", "cam2")
    for cam in names:
        scene.set_led(cam, True, t - 1)
    renderer = Renderer(scene, seed=seed)
    pts = [average_centroids([detect(renderer.render(cam, t)) for _ in range(SIM_FRAMES)])
           for cam in names]
    # the true cameras in camera 1's frame, as a perfect stereo calibration would give them
    cams = true_stereo_calibration(scene, t, names).cameras(names)
    spheres_true = sphere_centres(scene, t)
    volume = SimSpect(seed=seed).write(workdir / "sim_spect.npz", spheres_true)
    spect = find_spheres(read_volume(volume), strict=True).centroids
    fit = locate_body(cams, pts[0], pts[1], spect)
    vts = fit.points
    truth = true_spect_mapping(scene, t, names)  # VTS (cam1) -> SPECT (world)
    world = truth.apply(vts)
    tri_err = np.min(np.linalg.norm(world[:, None, :] - spheres_true[None, :, :], axis=-1), axis=1)
    info = {
        "seed": seed,
        "frames_averaged": SIM_FRAMES,
        "calibration": "the simulator's true camera models (as if perfectly calibrated)",
        "vts_frame": "camera 1",
        "spheres_found_by": "the shape of the SPECT centroids among the stereo hypotheses",
        "shape_rms_mm": fit.rms_mm,
        "triangulation_error_mm": {"rms": float(np.sqrt(np.mean(tri_err ** 2))),
                                   "max": float(tri_err.max())},
        "phantom_centre_spect_mm": spheres_true.mean(axis=0),
        "truth": truth,
    }
    return vts, volume, info


def _from_cameras(config_path, calibration_path, volume, frames: int, quiet: bool):
    """The mapping with the VTS side measured now by the rig's first two cameras."""
    import time

    from ..calibration_io import StereoCalibration
    from ..config import load_rig
    from ..detect import detect_jpeg
    from ..drivers.axis import AxisCamera
    from ..errors import ConfigError
    from ..procedures.spect_mapping import SpectMapping
    from ..procedures.steps import LED_SETTLE_S, SNAPSHOT_COMPRESSION, average_centroids

    rig = load_rig(config_path)
    path = calibration_path or rig.calibration.stereo
    if path is None:
        raise ConfigError("no stereo calibration: give --calibration or set calibration.stereo in the "
                          "rig config (`vts calibrate stereo`).")
    if len(rig.cameras) < 2:
        raise ConfigError("--from-cameras needs two cameras in the rig config.")
    calib = StereoCalibration.load(path)
    pts = []
    for cfg in rig.cameras[:2]:
        with AxisCamera.from_config(cfg) as cam:
            cam.led_on()
            time.sleep(LED_SETTLE_S)
            if not quiet:
                click.echo(f"{cam.name}: {frames} snapshots", err=True)
            pts.append(average_centroids([detect_jpeg(cam.snapshot(SNAPSHOT_COMPRESSION).jpeg)
                                          for _ in range(frames)]))
    return SpectMapping.from_stereo(calib, pts[0], pts[1], volume).analyze()


def _sim_compare(mapping, info: dict) -> dict:
    """How the recovered VTS → SPECT transform compares with the simulated truth."""
    from ..registration import difference

    truth, est = info["truth"], mapping.transform
    d = difference(truth, est)
    centre_vts = truth.inverse().apply(info["phantom_centre_spect_mm"])
    at_phantom = np.linalg.norm(est.apply(centre_vts) - truth.apply(centre_vts))
    return {"rotation_error_deg": d.angle_deg,
            "translation_error_at_phantom_mm": float(at_phantom),
            "translation_error_at_origin_mm": d.translation_norm_mm,
            "true_transform": {"R": truth.R.tolist(), "t_mm": truth.t.tolist()}}


@calibrate.command()
@click.option("--vts", "vts_path", type=click.Path(dir_okay=False), default=None,
              help="Phantom sphere centres in the VTS frame: CSV with a header x,y,z (mm), or a"
                   " JSON list of [x, y, z].")
@click.option("--volume", type=click.Path(), default=None,
              help="Reconstructed SPECT volume of the phantom (any format `read_volume` reads).")
@click.option("--from-cameras", is_flag=True,
              help="Take the VTS side from the rig's two cameras now (LED on, --frames snapshots each,"
                   " triangulated with the stereo calibration); the spheres are picked out by the"
                   " shape of the SPECT's. Needs --volume.")
@click.option("--calibration", "calibration_path", type=click.Path(dir_okay=False), default=None,
              help="Stereo calibration for --from-cameras (default: the config's calibration.stereo).")
@click.option("--frames", type=click.IntRange(1, 100), default=10, show_default=True,
              help="Snapshots per camera with --from-cameras.")
@config_option
@click.option("--sim", is_flag=True, help="Map a simulated session (stereo VTS + SimSpect volume)"
              " and compare with the simulated truth.")
@click.option("--sim-seed", type=int, default=0, show_default=True,
              help="Seed of the simulated rig, noise and volume.")
@click.option("-o", "--output", type=click.Path(dir_okay=False), default="spect_mapping.json",
              show_default=True, help="VTS → SPECT transform file to write.")
@json_option
def spect(vts_path: str | None, volume: str | None, from_cameras: bool, calibration_path: str | None,
          frames: int, config_path: str | None, sim: bool, sim_seed: int, output: str,
          as_json: bool) -> None:
    """VTS → SPECT mapping from the 7-sphere phantom: its sphere centres in the VTS frame
    (--vts, or --from-cameras to measure them now) and its reconstructed SPECT volume
    (--volume), or a simulated session (--sim).

    Prints the transform, the FRE and the leave-one-out TRE; writes the transform to -o.
    """
    import tempfile

    from ..procedures.spect_mapping import SpectMapping

    if sim and (vts_path or volume or from_cameras):
        raise click.UsageError("give either --vts/--from-cameras and --volume, or --sim, not both")
    if vts_path and from_cameras:
        raise click.UsageError("give either --vts POINTS or --from-cameras, not both")
    if not sim and not ((vts_path or from_cameras) and volume):
        raise click.UsageError("give --vts POINTS (or --from-cameras) and --volume VOLUME, or --sim")

    out_path = Path(output)
    info = None
    if sim:
        with tempfile.TemporaryDirectory(prefix="vts-spect-sim-") as tmp:
            points, vol_path, info = sim_spect_inputs(sim_seed, Path(tmp))
            mapping = SpectMapping.from_volume(points, vol_path).analyze()
    elif from_cameras:
        if not Path(volume).exists():
            raise DataError(f"{volume}: no such file or directory.")
        mapping = _from_cameras(config_path, calibration_path, volume, frames, as_json)
    else:
        points = read_points(vts_path)
        if not Path(volume).exists():
            raise DataError(f"{volume}: no such file or directory.")
        mapping = SpectMapping.from_volume(points, volume).analyze()
    compare = _sim_compare(mapping, info) if info is not None else None
    mapping.save(out_path)

    if as_json:
        data = mapping.results_data()
        data["output"] = str(out_path)
        if info is not None:
            data["sim"] = {k: v for k, v in info.items() if k != "truth"}
            data["sim"]["phantom_centre_spect_mm"] = info["phantom_centre_spect_mm"].tolist()
            data["sim_truth"] = compare
        echo_json(data)
        return
    if info is not None:
        err = info["triangulation_error_mm"]
        click.echo(f"Simulated session (seed {info['seed']}): VTS = the two simulated cameras with"
                   f" their TRUE models (as if perfectly calibrated), detections averaged over"
                   f" {info['frames_averaged']} noisy frames, VTS frame = camera 1;"
                   f" triangulation error RMS {err['rms']:.3f} mm, max {err['max']:.3f} mm.")
    click.echo(mapping.results())
    if compare is not None:
        click.echo(f"Compared with the simulated truth (camera 1's pose inverse): rotation off by"
                   f" {compare['rotation_error_deg']:.4f} deg, translation off by"
                   f" {compare['translation_error_at_phantom_mm']:.3f} mm at the phantom.")
    click.echo(f"wrote {out_path}")
