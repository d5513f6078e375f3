"""The simulated sessions behind `vts calibrate stereo --sim` and `vts calibrate spect --sim`.

:func:`sim_views` renders checkerboard pairs as the reference rig's two cameras see them and gives
the true cameras to score the calibration against; :func:`sim_spect_inputs` stages the 7-sphere
phantom before the simulated VTS and a simulated SPECT volume; :func:`compare_mapping_with_truth`
scores the VTS → SPECT mapping found from them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

SIM_FRAMES = 5          # noisy frames averaged per camera in `vts calibrate spect --sim`


def sim_square_mm() -> float:
    """Side of a square of the simulated board (mm)."""
    from vts_hw.sim_devices.checkerboard import SQUARE_MM
    return SQUARE_MM


def sim_views(seed: int, n: int, pattern=(9, 6), square_mm: float | None = None):
    """``n`` rendered stereo views of the board held before the reference rig of ``seed``:
    (pairs, names, truth) with ``truth`` the rig's true cameras as a StereoCalibration in mm."""
    from vts_hw.sim_devices import checkerboard as cb
    from vts_hw.sim_devices.scene import Scene
    from vts_hw.sim_devices.sync_truth import true_stereo_calibration

    scene = Scene.reference(seed, start_epoch=0.0)
    pairs, names = cb.render_pairs(scene, n=n, seed=seed, pattern=pattern,
                                   square_mm=cb.SQUARE_MM if square_mm is None else square_mm)
    return pairs, names, true_stereo_calibration(scene)


def sim_spect_inputs(seed: int, workdir: Path) -> tuple[np.ndarray, Path, dict]:
    """The simulated session: the phantom triangulated by the stereo VTS (in camera 1's frame)
    and a SimSpect volume of its true centres (SPECT frame = scene world frame).

    Which detections are spheres (the wall markers are seen too, and some stereo pairings are
    ambiguous) is decided as on the real rig: by the shape of the SPECT's centroids
    (:func:`vts_hw.vision.body_finder.locate_body`); the truth is used only to score.
    Returns the VTS points, the volume path and a dict of what the sim did and its truth.
    """
    from vts_hw.vision.body_finder import locate_body
    from vts_hw.vision.detect import detect
    from vts_hw.sim_devices.render import Renderer
    from vts_hw.sim_devices.scene import Scene
    from vts_hw.sim_devices.spect import SimSpect
    from vts_hw.sim_devices.step_table import sphere_centres
    from vts_hw.sim_devices.sync_truth import true_spect_mapping, true_stereo_calibration
    from vts_hw.spect import find_spheres, read_volume
    from vts_hw.procedures.steps import average_centroids

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


def compare_mapping_with_truth(mapping, info: dict) -> dict:
    """How the recovered VTS → SPECT transform compares with the simulated truth."""
    from vts_hw.vision.registration import difference

    truth, est = info["truth"], mapping.transform
    d = difference(truth, est)
    centre_vts = truth.inverse().apply(info["phantom_centre_spect_mm"])
    at_phantom = np.linalg.norm(est.apply(centre_vts) - truth.apply(centre_vts))
    return {"rotation_error_deg": d.angle_deg,
            "translation_error_at_phantom_mm": float(at_phantom),
            "translation_error_at_origin_mm": d.translation_norm_mm,
            "true_transform": {"R": truth.R.tolist(), "t_mm": truth.t.tolist()}}
