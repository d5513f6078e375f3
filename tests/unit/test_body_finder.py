"""Finding the 7-sphere phantom among the points the stereo VTS sees, by its shape."""

import numpy as np
import pytest

from vts_hw.errors import DataError
from vts_hw.sim_devices.scene import PHANTOM_LAYOUT, Scene
from vts_hw.sim_devices.step_table import sphere_centres
from vts_hw.vision.body_finder import candidate_points, find_body, locate_body
from vts_hw.vision.registration import RigidTransform
from vts_hw.vision.triangulate import as_camera

TEMPLATE = np.array([PHANTOM_LAYOUT[f"S{k}"] for k in range(1, 8)], float)


def moved(angles=(10, -20, 35), t=(300.0, -50.0, 900.0)):
    return RigidTransform.from_euler_xyz_deg(angles, t).apply(TEMPLATE)


def test_finds_the_body_among_extra_points_in_any_order():
    rng = np.random.default_rng(1)
    body = moved() + rng.normal(0, 0.05, (7, 3))
    extras = rng.uniform(-1500, 1500, (9, 3))
    pts = np.vstack([extras[:4], body[::-1], extras[4:]])
    fit = find_body(pts, TEMPLATE)
    # template point i is body[i], which sits at index 4 + (6 - i) in pts
    assert fit.index.tolist() == [4 + 6 - i for i in range(7)]
    assert fit.rms_mm < 0.2
    assert np.allclose(fit.points, body)


def test_a_missing_sphere_is_an_error_that_says_which():
    pts = np.delete(moved(), 3, axis=0)
    pts = np.vstack([pts, [[5000.0, 0, 0]]])
    with pytest.raises(DataError, match=r"6 of its 7 points: point\(s\) 4 not seen"):
        find_body(pts, TEMPLATE)


def test_too_few_points_and_no_match():
    with pytest.raises(DataError, match="only 5 point"):
        find_body(moved()[:5], TEMPLATE)
    with pytest.raises(DataError, match="not found"):
        find_body(np.random.default_rng(0).uniform(-1000, 1000, (12, 3)), TEMPLATE)


def test_a_symmetric_body_is_reported_ambiguous_not_guessed():
    square = np.array([[0, 0, 0], [100, 0, 0], [100, 100, 0], [0, 100, 0]], float)
    with pytest.raises(DataError, match="two ways"):
        find_body(square + [10, 20, 30], square)


def test_detections_shared_by_two_spheres_are_refused():
    body = moved()
    pts = np.vstack([body, [[9000.0, 0, 0]]])
    exclusive = np.array([[i, i] for i in range(8)])
    exclusive[1] = exclusive[0]  # spheres 1 and 2 built from the same detections
    with pytest.raises(DataError, match="same detection"):
        find_body(pts, TEMPLATE, exclusive=exclusive)


def test_locate_body_settles_pairings_the_epipolar_constraint_leaves_open():
    """Wall markers and spheres on near-common epipolar lines give wrong stereo hypotheses; the
    phantom's shape picks the right ones, with the true cameras, to well under a millimetre."""
    scene = Scene.reference(0, start_epoch=0.0)
    scene.add_phantom()
    scene.move_table(60.0, 0.0)  # a position with epipolar ambiguities
    cams = [as_camera(scene.camera_at(c, 0.0)) for c in ("cam1", "cam2")]
    truth = np.array([m.center for m in scene.markers_world(0.0)])
    uv = [c.project(truth) for c in cams]
    hyp = candidate_points(cams, uv[0], uv[1], max_px=2.0)
    assert len(hyp.points) > len(truth)  # more hypotheses than markers: some pairings are open
    spheres = sphere_centres(scene, 0.0)
    fit = locate_body(cams, uv[0], uv[1], spheres - [0.0, 0.0, 0.0])
    assert np.abs(fit.points - spheres).max() < 1e-6
