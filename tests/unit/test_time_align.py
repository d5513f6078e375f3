"""Views of a moving marker brought to one instant before triangulation (decision 0037):
two cameras exposing 15 ms apart watch a marker moving at 200 mm/s."""

import numpy as np

from vts_hw.sim_devices.scene import Scene
from vts_hw.tracking.time_align import align_views
from vts_hw.vision.multiview import ViewGeometry, triangulate_groups

T0 = 1_700_000_000.0


def test_a_fast_marker_is_triangulated_where_it_was_at_the_set_time():
    scene = Scene.reference(seed=0, n_cameras=2, start_epoch=T0)
    cams = [scene.camera_at(c, T0) for c in scene.camera_names]
    geo = ViewGeometry(cams, scene.camera_names)
    F, period, lag = 50, 0.04, 0.015
    t_cam = np.column_stack([T0 + period * np.arange(F), T0 + period * np.arange(F) + lag])
    set_time = t_cam.mean(axis=1)
    start, velocity = np.array([0.0, 50.0, 0.0]), np.array([120.0, 40.0, 150.0])  # mm, mm/s

    def where(t):
        return start + np.outer(np.asarray(t) - T0, velocity)

    uv = np.column_stack([geo.project(c, where(t_cam[:, c])) for c in range(2)])
    point_frame, marker = np.arange(F), np.ones(F, int)
    # as recorded: each view of its own instant
    obs = uv.reshape(F, 2, 2)
    norm = np.stack([geo.normalize(c, obs[:, c]) for c in range(2)], axis=1)
    raw, _ = triangulate_groups(geo, obs, norm, np.ones((F, 2), bool), iterations=2)
    xyz, rms, uv_new, n = align_views(geo, point_frame, marker, uv, t_cam, set_time, max_gap_s=2.5 * period)
    truth = where(set_time)
    inner = slice(1, F - 1)  # the first and last views have no frame on one side
    err_raw = np.linalg.norm(raw[inner] - truth[inner], axis=1)
    err = np.linalg.norm(xyz[inner] - truth[inner], axis=1)
    assert err_raw.min() > 0.5  # 7.5 ms of 260 mm/s, off the path
    assert err.max() < 0.01 and np.nanmax(rms[inner]) < 1e-3
    # the views with no frame beyond the set's time are left as recorded: camera 2's first
    # (15 ms after the set's first time, nothing before it) and camera 1's last
    assert n == 2 * F - 2
    assert np.array_equal(uv_new[0, 2:4], uv[0, 2:4]) and np.array_equal(uv_new[-1, 0:2], uv[-1, 0:2])
    assert not np.allclose(uv_new[0, 0:2], uv[0, 0:2], atol=0.1)


def test_a_still_marker_stays_and_a_gap_is_not_bridged():
    scene = Scene.reference(seed=1, n_cameras=2, start_epoch=T0)
    geo = ViewGeometry([scene.camera_at(c, T0) for c in scene.camera_names], scene.camera_names)
    t_cam = np.column_stack([T0 + 0.04 * np.arange(6), T0 + 0.04 * np.arange(6) + 0.01])
    t_cam[3:] += 1.0  # a second-long gap in both cameras after frame 2
    set_time = t_cam.mean(axis=1)
    X = np.array([10.0, 20.0, 30.0])
    still = np.column_stack([geo.project(c, np.repeat(X[None], 6, axis=0)) for c in range(2)])
    xyz, _, uv_new, _ = align_views(geo, np.arange(6), np.ones(6, int), still, t_cam, set_time, max_gap_s=0.1)
    done = ~np.isnan(xyz[:, 0])
    assert done.any() and np.allclose(xyz[done], X, atol=1e-6) and np.allclose(uv_new, still)
    # moving: camera 1's view of frame 2 would need frame 3, beyond the gap: left as recorded;
    # camera 2's view of frame 2 has frame 1 before it: brought to the set's time
    moving = np.column_stack([geo.project(c, X + np.outer(t_cam[:, c] - T0, [100.0, 0, 0])) for c in range(2)])
    _, _, uv_new, _ = align_views(geo, np.arange(6), np.ones(6, int), moving, t_cam, set_time, max_gap_s=0.1)
    assert np.array_equal(uv_new[2, 0:2], moving[2, 0:2])
    assert not np.allclose(uv_new[2, 2:4], moving[2, 2:4], atol=0.05)
