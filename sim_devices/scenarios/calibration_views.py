"""The simulated sessions behind `vts calibrate stereo --sim` and `vts calibrate spect --sim`.

:func:`sim_views` renders checkerboard pairs as the reference rig's two cameras see them and gives
the true cameras to score the calibration against; :func:`sim_spect_inputs` stages the 7-sphere
phantom before the simulated VTS and a simulated SPECT volume; :func:`compare_mapping_with_truth`
scores the VTS → SPECT mapping found from them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vts_hw.procedures.steps import average_centroids
from vts_hw.sim_devices import checkerboard as cb
from vts_hw.sim_devices.board_plan import plan_views
from vts_hw.sim_devices.render import Renderer
from vts_hw.sim_devices.scene import Scene
from vts_hw.sim_devices.spect import SimSpect
from vts_hw.sim_devices.step_table import sphere_centres
from vts_hw.sim_devices.sync_truth import true_spect_mapping, true_stereo_calibration
from vts_hw.spect import find_spheres, read_volume
from vts_hw.vision.body_finder import locate_body
from vts_hw.vision.calibration_io import CameraCalibration, CameraFit
from vts_hw.vision.detect import detect
from vts_hw.vision.multi_compare import against_truth
from vts_hw.vision.registration import difference

SIM_FRAMES = 5  # noisy frames averaged per camera in `vts calibrate spect --sim`


def sim_square_mm() -> float:
    """Side of a square of the simulated board (mm)."""
    return cb.SQUARE_MM


def sim_views(seed: int, n: int, pattern=(9, 6), square_mm: float | None = None):
    """``n`` rendered stereo views of the board held before the reference rig of ``seed``:
    (pairs, names, truth) with ``truth`` the rig's two true cameras (cam1, cam2) as a calibration in mm."""
    scene = Scene.reference(seed, start_epoch=0.0)
    pairs, names = cb.render_pairs(
        scene, n=n, seed=seed, pattern=pattern, square_mm=cb.SQUARE_MM if square_mm is None else square_mm
    )
    return pairs, names, true_stereo_calibration(scene)


def sim_spect_inputs(seed: int, workdir: Path) -> tuple[np.ndarray, Path, dict]:
    """The simulated session: the phantom triangulated by the stereo VTS (in camera 1's frame)
    and a SimSpect volume of its true centres (SPECT frame = scene world frame).

    Which detections are spheres (the wall markers are seen too, and some stereo pairings are
    ambiguous) is decided as on the real rig: by the shape of the SPECT's centroids
    (:func:`vts_hw.vision.body_finder.locate_body`); the truth is used only to score.
    Returns the VTS points, the volume path and a dict of what the sim did and its truth.
    """
    scene = Scene.reference(seed, start_epoch=0.0)
    scene.add_phantom()
    t = 10.0
    names = ("cam1", "cam2")
    for cam in names:
        scene.set_led(cam, True, t - 1)
    renderer = Renderer(scene, seed=seed)
    pts = [average_centroids([detect(renderer.render(cam, t)) for _ in range(SIM_FRAMES)]) for cam in names]
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
        "triangulation_error_mm": {"rms": float(np.sqrt(np.mean(tri_err**2))), "max": float(tri_err.max())},
        "phantom_centre_spect_mm": spheres_true.mean(axis=0),
        "truth": truth,
    }
    return vts, volume, info


def compare_mapping_with_truth(mapping, info: dict) -> dict:
    """How the recovered VTS → SPECT transform compares with the simulated truth."""
    truth, est = info["truth"], mapping.transform
    d = difference(truth, est)
    centre_vts = truth.inverse().apply(info["phantom_centre_spect_mm"])
    at_phantom = np.linalg.norm(est.apply(centre_vts) - truth.apply(centre_vts))
    return {
        "rotation_error_deg": d.angle_deg,
        "translation_error_at_phantom_mm": float(at_phantom),
        "translation_error_at_origin_mm": d.translation_norm_mm,
        "true_transform": {"R": truth.R.tolist(), "t_mm": truth.t.tolist()},
    }


# ------------------------------------------------------------------ N cameras
FOV_BOX_MM = (250.0, 150.0, 250.0)  # half-sizes (X, Y, Z) of the box of points the 3D error is measured on
FOV_POINTS = 400


def true_cameras(scene, names=None, square_mm: float = 1.0, pattern=(9, 6)):
    """The scene's true cameras as a CameraCalibration in mm, in the first camera's frame."""
    names = list(names or scene.camera_names)
    ref = scene.cameras[names[0]]
    fits = []
    for n in names:
        c = scene.cameras[n]
        R = c.R @ ref.R.T
        fits.append(CameraFit(n, c.K, c.dist, R, c.t - R @ ref.t, (int(c.width), int(c.height))))
    return CameraCalibration(
        fits, tuple(pattern), float(square_mm), "mm", 0.0, [], "simulated rig: the scene's true cameras", method="truth"
    )


def fov_points(scene, names=None, seed: int = 99) -> np.ndarray:
    """``FOV_POINTS`` points spread uniformly over a box about the field of view's centre
    (± FOV_BOX_MM), in the first camera's frame (where the calibration puts them)."""
    names = list(names or scene.camera_names)
    ref = scene.cameras[names[0]]
    world = np.random.default_rng(seed).uniform(-1, 1, (FOV_POINTS, 3)) * np.array(FOV_BOX_MM)
    return ref.to_camera(world)


def sim_camera_views(
    seed: int, n_cameras: int, per_pair: int, pattern=(9, 6), square_mm: float | None = None, scene=None
):
    """Checkerboard views for an N-camera calibration of the reference rig with ``n_cameras``
    (or of ``scene``): the board held ``per_pair`` times towards each pair of cameras that
    :func:`vts_hw.sim_devices.board_plan.plan_views` chooses, rendered (JPEG, noise) in those
    two cameras. Returns (images: camera → view → grey image, truth: the true cameras,
    info: the plan and the FOV points to score against)."""
    square_mm = cb.SQUARE_MM if square_mm is None else square_mm
    scene = scene or Scene.reference(seed, n_cameras=n_cameras, start_epoch=0.0)
    names = list(scene.camera_names)
    plan = plan_views(scene, per_pair, seed, pattern=pattern, square_mm=square_mm)
    images: dict[str, dict[str, np.ndarray]] = {n: {} for n in names}
    k = 0
    for (a, b), poses in plan:
        for pose in poses:
            k += 1
            view = f"v{k:02d}"
            for i, cam in enumerate((a, b)):
                images[cam][view] = cb.decode(
                    cb.render_board(scene, cam, pose, pattern, square_mm, seed=seed * 10007 + 2 * k + i)
                )
    info = {
        "seed": seed,
        "n_cameras": len(names),
        "pairs": [{"cameras": list(p), "views": len(v)} for p, v in plan],
        "held_for": "each view is rendered in the two cameras it is held towards",
        "fov_box_mm": list(FOV_BOX_MM),
        "fov_points": fov_points(scene, names),
    }
    return images, true_cameras(scene, names, square_mm, pattern), info


def cameras_against_truth(calib, truth, points) -> dict:
    """The calibration's errors against the simulated truth (:func:`vts_hw.vision.multi_compare.against_truth`
    on the FOV points ``info["fov_points"]`` of :func:`sim_camera_views`), with what the points were."""
    out = against_truth(calib, truth, points)
    out["points_3d"]["where"] = (
        f"{FOV_POINTS} points uniform in ±{FOV_BOX_MM[0]:g} x ±{FOV_BOX_MM[1]:g} x"
        f" ±{FOV_BOX_MM[2]:g} mm about the FOV centre, projected exactly by the true"
        " cameras, triangulated with the calibrated ones in the reference camera's frame"
    )
    return out
