"""The simulated checkerboard: poses fit both cameras, rendered corners are where they should be."""

import numpy as np
import pytest

from vts_hw.sim_devices import checkerboard as cb
from vts_hw.sim_devices.scene import Scene
from vts_hw.vision.checkerboard import find_corners


@pytest.fixture(scope="module")
def scene():
    return Scene.reference(0, start_epoch=0.0)


@pytest.fixture(scope="module")
def poses(scene):
    return cb.board_poses(scene, n=18, seed=0)


def _rms(found, truth):
    return float(np.sqrt(np.mean(np.sum((found.reshape(-1, 2) - truth) ** 2, axis=1))))


def test_poses_are_rigid_varied_and_fully_visible_in_both_cameras(scene, poses):
    assert len(poses) == 18
    base = cb._base_rotation(scene)
    tilts = []
    for R, t in poses:
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) > 0
        assert cb.fully_visible(scene, (R, t))
        outline = cb._to_world((R, t), cb.board_outline())
        for cam in scene.cameras.values():
            uv = cam.project(outline)
            assert uv.min() >= cb.IMAGE_MARGIN_PX
            assert np.all(uv[:, 0] <= cam.width - 1 - cb.IMAGE_MARGIN_PX)
            assert np.all(uv[:, 1] <= cam.height - 1 - cb.IMAGE_MARGIN_PX)
        # angle between the board normal and the normal of a board facing the cameras
        tilts.append(np.degrees(np.arccos(np.clip(R[:, 2] @ base[:, 2], -1, 1))))
        centre = cb._to_world((R, t), [[120.0, 75.0, 0.0]])[0]
        assert np.linalg.norm(centre) < 400.0  # near the FOV centre
    assert max(tilts) > 20.0 and max(tilts) < 43.0  # tilted, within +-30 deg about each axis
    assert len({tuple(np.round(t, 3)) for _, t in poses}) == 18


def test_poses_are_deterministic(scene):
    a = cb.board_poses(scene, n=4, seed=3)
    b = cb.board_poses(scene, n=4, seed=3)
    assert all(np.array_equal(ra, rb) and np.array_equal(ta, tb) for (ra, ta), (rb, tb) in zip(a, b))


def test_noise_free_render_corners_match_truth(scene, poses):
    worst = 0.0
    for k, pose in enumerate(poses[:6]):
        for cam in ("cam1", "cam2"):
            img = cb.decode(cb.render_board(scene, cam, pose, noise_sigma=0.0, quality=100, seed=k))
            assert img.shape == (480, 640)
            found = find_corners(img)
            assert found is not None, f"pose {k}, {cam}: board not found"
            worst = max(worst, _rms(found, cb.truth_corners(scene, cam, pose)))
    assert worst < 0.1  # measured: 0.04-0.07 px


def test_noisy_render_corners_match_truth(scene, poses):
    for k, pose in enumerate(poses):
        for cam in ("cam1", "cam2"):
            img = cb.decode(cb.render_board(scene, cam, pose, noise_sigma=2.0, quality=75, seed=k))
            found = find_corners(img)
            assert found is not None, f"pose {k}, {cam}: board not found"
            assert _rms(found, cb.truth_corners(scene, cam, pose)) < 0.2  # measured <= 0.08 px


def test_render_is_grey_jpeg_with_board_brighter_than_background(scene, poses):
    jpeg = cb.render_board(scene, "cam1", poses[0], seed=1)
    assert jpeg[:2] == b"\xff\xd8"
    img = cb.decode(jpeg)
    uv = cb.truth_corners(scene, "cam1", poses[0])
    u, v = np.rint(uv.mean(axis=0)).astype(int)
    assert img[:20, :20].mean() < 40  # dim room
    patch = img[v - 20 : v + 20, u - 20 : u + 20]
    assert patch.max() > 150 and patch.min() < 70  # white paper and black squares
    clean = cb.render_clean(scene, "cam1", poses[0])
    assert clean.dtype == np.float32 and clean.shape == (480, 640)


def test_truth_corners_order_matches_board_points(scene, poses):
    from vts_hw.vision.checkerboard import board_points

    R, t = poses[0]
    world = board_points((9, 6), cb.SQUARE_MM).astype(float) @ R.T + t
    assert np.allclose(cb.truth_corners(scene, "cam2", poses[0]), scene.cameras["cam2"].project(world))
