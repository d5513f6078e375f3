"""The simulated room: camera model, reference geometry, drift, clocks, LED and table schedules."""

import itertools
import threading

import cv2
import numpy as np
import pytest

from vts_hw.sim_devices.clock import RealClock, VirtualClock
from vts_hw.sim_devices.scene import DAY, CameraClock, CameraModel, Scene, Schedule

T0 = 1_700_000_000.0


@pytest.fixture
def scene():
    s = Scene.reference(seed=0, start_epoch=T0)
    s.add_phantom()
    return s


# ---------------------------------------------------------------- camera model
def test_projection_round_trip(scene):
    rng = np.random.default_rng(1)
    for cam in scene.cameras.values():
        pts = rng.uniform(-300, 300, (50, 3))
        uv = cam.project(pts)
        depth = cam.to_camera(pts)[:, 2]
        norm = cv2.undistortPoints(
            uv.reshape(-1, 1, 2),
            cam.K,
            cam.dist,
            None,
            None,
            None,
            (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12),
        )
        xc = np.column_stack([norm.reshape(-1, 2) * depth[:, None], depth])
        back = (xc - cam.t) @ cam.R  # R^T (x_c - t)
        assert np.abs(back - pts).max() < 1e-6


def test_project_matches_the_pinhole_formula():
    K = np.array([[3000.0, 0, 321.0], [0, 3000.0, 238.0], [0, 0, 1]])
    dist = np.array([-0.05, 0.01, 0.001, -0.002, 0.0])
    cam = CameraModel.from_rvec("c", K, dist, [0.1, -0.2, 0.05], [10.0, -20.0, 3000.0])
    p = np.array([[120.0, -80.0, 200.0]])
    x, y, z = cam.to_camera(p)[0]
    a, b = x / z, y / z
    r2 = a * a + b * b
    k1, k2, p1, p2, _ = dist
    radial = 1 + k1 * r2 + k2 * r2 * r2
    ad = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a)
    bd = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b
    expected = np.array([K[0, 0] * ad + K[0, 2], K[1, 1] * bd + K[1, 2]])
    assert np.allclose(cam.project(p)[0], expected, atol=1e-9)
    assert np.allclose(cam.center, -cam.R.T @ cam.t)


def test_look_at_puts_the_target_on_the_principal_point():
    K = np.array([[3000.0, 0, 322.0], [0, 3000.0, 236.0], [0, 0, 1]])
    cam = CameraModel.look_at("c", (-600, 1100, -3530), (10, -5, 20), K, np.zeros(5), roll_rad=0.01)
    assert np.allclose(cam.project([[10, -5, 20]])[0], [322.0, 236.0], atol=1e-9)
    assert np.allclose(cam.center, [-600, 1100, -3530])
    # image "up" is world up: a point above the target is higher in the image (smaller v)
    assert cam.project([[10, 95, 20]])[0, 1] < 236.0 - 50


# ---------------------------------------------------------------- reference rig
@pytest.mark.parametrize("n_cameras", [1, 2, 3, 4, 8])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_all_wall_markers_inside_every_image_with_margin(seed, n_cameras):
    """Every camera sees the five markers of the wall beyond its end of the table: W1-W5 from
    the head end, W6-W10 from the foot end (pairs alternate ends: cam1, cam2 at the head)."""
    s = Scene.reference(seed=seed, n_cameras=n_cameras, start_epoch=T0)
    margin = 40.0  # px, from a marker centre to the image edge (markers are ~20 px across)
    for name, cam in s.cameras.items():
        truth = {mid: (u, v) for mid, u, v in s.truth(name, T0)}
        head_end = cam.center[2] < 0
        assert head_end == ((int(name[3:]) - 1) // 2 % 2 == 0 or n_cameras == 1)
        first = 1 if head_end else 6
        assert sorted(truth, key=lambda m: int(m[1:])) == [f"W{k}" for k in range(first, first + 5)]
        uv = np.array(list(truth.values()))
        assert uv[:, 0].min() > margin and uv[:, 0].max() < cam.width - 1 - margin
        assert uv[:, 1].min() > margin and uv[:, 1].max() < cam.height - 1 - margin
        # far apart from each other, so they can be told apart
        assert min(np.linalg.norm(a - b) for a, b in itertools.combinations(uv, 2)) > 60


def test_reference_geometry_matches_the_room(scene):
    wall = np.array([m.center for m in scene.wall_markers])
    for cam in scene.cameras.values():
        c = cam.center
        assert c[1] == pytest.approx(1100.0) and c[2] == pytest.approx(-3530.0)
        assert np.linalg.norm(c) == pytest.approx(3700, rel=0.05)
        # scale (mm per px) = depth / focal
        centre_scale = cam.to_camera([[0, 0, 0]])[0, 2] / cam.focal
        wall_scale = cam.to_camera(wall)[:, 2].mean() / cam.focal
        assert centre_scale == pytest.approx(1.11, rel=0.10)
        assert wall_scale == pytest.approx(1.25, rel=0.10)
        assert abs(cam.K[0, 2] - 319.5) <= 10 and abs(cam.K[1, 2] - 239.5) <= 10
        assert cam.dist[0] == pytest.approx(-0.05, abs=0.02) and cam.dist[1] == 0.0
        # a real 1 mm step at the FOV centre moves the image by about 1/1.11 px
        d = np.linalg.norm(np.diff(cam.project([[0, 0, 0], [1, 0, 0]]), axis=0))
        assert d == pytest.approx(1 / 1.11, rel=0.1)
    baseline = np.linalg.norm(scene.cameras["cam1"].center - scene.cameras["cam2"].center)
    assert baseline == pytest.approx(1200.0)
    for m in scene.wall_markers:
        assert m.kind == "disk" and m.diameter_mm == 25.0
        assert all(m.faces(cam.center) for cam in scene.cameras.values())


def test_reference_is_reproducible_and_products_are_axis_like():
    a = Scene.reference(seed=3, n_cameras=8, start_epoch=T0)
    b = Scene.reference(seed=3, n_cameras=8, start_epoch=T0)
    c = Scene.reference(seed=4, n_cameras=8, start_epoch=T0)
    assert a.camera_names == [f"cam{i}" for i in range(1, 9)]
    assert all(np.array_equal(a.cameras[n].K, b.cameras[n].K) for n in a.cameras)
    assert not np.array_equal(a.cameras["cam1"].K, c.cameras["cam1"].K)
    macs = [p.mac for p in a.products.values()]
    assert len(set(macs)) == 8 and all(m[:3] == bytes.fromhex("ACCC8E") for m in macs)
    assert all(p.firmware == (5, 55, 1) for p in a.products.values())
    assert a.products == b.products
    for clock in a.clocks.values():
        assert abs(clock.offset_s) <= 3 and abs(clock.skew_ppm) <= 50


def test_phantom_spheres(scene):
    spheres = [m for m in scene.markers_world(T0) if m.kind == "sphere"]
    assert [m.id for m in spheres] == [f"S{i}" for i in range(1, 8)]
    pts = np.array([m.center for m in spheres])
    assert all(m.diameter_mm == 13.0 for m in spheres)
    assert 120 < np.ptp(pts, axis=0).max() < 200  # spread about 15 cm
    assert np.linalg.norm(pts.mean(axis=0)) < 60  # near the FOV centre
    sv = np.linalg.svd(pts - pts.mean(axis=0), compute_uv=False)
    assert sv[-1] > 20 * np.sqrt(len(pts)) / 2  # not coplanar
    for name in scene.cameras:
        truth = {mid: np.array([u, v]) for mid, u, v in scene.truth(name, T0)}
        assert set(truth) == {f"W{i}" for i in range(1, 6)} | {f"S{i}" for i in range(1, 8)}
        # no two markers overlap in the image (spheres ~12 px, disks ~20 px across)
        for (ia, a), (ib, b) in itertools.combinations(truth.items(), 2):
            assert np.linalg.norm(a - b) > 25, (name, ia, ib)


def test_table_and_phantom_pose_follow_their_schedules(scene):
    before = {m.id: m.center for m in scene.markers_world(T0)}
    scene.move_table(10.0, -5.0, t=T0 + 100)
    at_99 = {m.id: m.center for m in scene.markers_world(T0 + 99)}
    at_100 = {m.id: m.center for m in scene.markers_world(T0 + 100)}
    assert all(np.array_equal(before[k], at_99[k]) for k in before)
    for k in before:
        expected = before[k] + ([0, 10, -5] if k.startswith("S") else [0, 0, 0])
        assert np.allclose(at_100[k], expected)
    # a rigid pose keeps the distances between spheres
    scene.set_phantom_pose([0.1, -0.2, 0.3], (5.0, -60.0, 20.0), t=T0 + 200)
    moved = {m.id: m.center for m in scene.markers_world(T0 + 200)}
    ids = [f"S{i}" for i in range(1, 8)]
    for a, b in itertools.combinations(ids, 2):
        assert np.linalg.norm(moved[a] - moved[b]) == pytest.approx(np.linalg.norm(before[a] - before[b]))
    assert not np.allclose(moved["S1"], at_100["S1"])
    assert scene.pose_key(T0 + 200) != scene.pose_key(T0 + 100)


# ---------------------------------------------------------------- drift
def _wall_shift(scene, cam, days):
    a = np.array([x[1:] for x in scene.truth(cam, T0) if x[0].startswith("W")])
    b = np.array([x[1:] for x in scene.truth(cam, T0 + days * DAY) if x[0].startswith("W")])
    return np.linalg.norm(b - a, axis=1).mean()


@pytest.mark.parametrize("seed", range(10))
def test_drift_over_60_days_is_that_of_the_reference_rig(seed):
    s = Scene.reference(seed=seed, start_epoch=T0)
    for cam in s.cameras:
        assert 0.7 <= _wall_shift(s, cam, 60) <= 1.6
        assert _wall_shift(s, cam, 1 / 24) < 0.01  # nothing visible within an hour


def test_drift_is_deterministic_and_order_free():
    a = Scene.reference(seed=5, start_epoch=T0)
    b = Scene.reference(seed=5, start_epoch=T0)
    c = Scene.reference(seed=6, start_epoch=T0)
    times = [T0 + d * DAY for d in (0.0, 3.25, 17.5, 60.0, 400.0)]
    ra = [a.drifts["cam1"].rotation_at(t) for t in times]
    rb = [b.drifts["cam1"].rotation_at(t) for t in reversed(times)][::-1]
    assert all(np.array_equal(x, y) for x, y in zip(ra, rb))
    assert not np.allclose(ra[3], c.drifts["cam1"].rotation_at(times[3]))
    assert np.array_equal(ra[0], np.zeros(3))
    assert np.array_equal(a.drifts["cam1"].rotation_at(T0 - DAY), np.zeros(3))
    # the random walk is continuous between its daily table entries
    d = a.drifts["cam1"]
    assert np.linalg.norm(d.rotation_at(T0 + 3 * DAY - 1) - d.rotation_at(T0 + 3 * DAY + 1)) < 1e-8
    # drift turns the camera about its own centre
    assert np.allclose(a.camera_at("cam1", times[4]).center, a.cameras["cam1"].center)


# ---------------------------------------------------------------- clocks
def test_camera_clock_forward_inverse_and_skew():
    clock = CameraClock(offset_s=2.5, skew_ppm=40.0, ref_epoch=T0)
    assert clock.camera_time(T0) == pytest.approx(T0 + 2.5, abs=1e-6)
    assert clock.camera_time(T0 + DAY) - clock.camera_time(T0) == pytest.approx(DAY * (1 + 40e-6), abs=1e-6)
    for host in (T0 - 1000.0, T0 + 123.456, T0 + 30 * DAY):
        assert clock.host_time(clock.camera_time(host)) == pytest.approx(host, abs=1e-6)
    slow = CameraClock(offset_s=-1.0, skew_ppm=-30.0, ref_epoch=T0)
    assert slow.camera_time(T0 + 1e5) == pytest.approx(T0 + 1e5 - 1.0 - 3.0, abs=1e-6)


def test_virtual_clock_runs_at_its_rate_and_jumps():
    clock = VirtualClock(T0, rate=1000.0)
    t1 = clock.now()
    assert T0 <= t1 < T0 + 50
    clock.sleep(100.0)  # 0.1 real seconds
    t2 = clock.now()
    assert t2 - t1 >= 100.0
    t3 = clock.advance(60 * DAY)
    assert t3 - t2 >= 60 * DAY
    with pytest.raises(ValueError):
        clock.advance(-1)
    real = RealClock()
    assert abs(real.now() - __import__("time").time()) < 1.0


def test_virtual_clock_is_thread_safe():
    clock = VirtualClock(T0, rate=1.0)
    threads = [threading.Thread(target=lambda: [clock.advance(1.0) for _ in range(1000)]) for _ in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert clock.now() - T0 >= 4000.0
    assert clock.now() - T0 < 4000.0 + 30


# ---------------------------------------------------------------- LED schedule
def test_led_schedule_and_pulse(scene):
    assert not scene.led_on("cam1", T0)
    scene.set_led("cam1", True, T0 + 10)
    assert not scene.led_on("cam1", T0 + 9.999)
    assert scene.led_on("cam1", T0 + 10) and scene.led_on("cam1", T0 + 1e6)
    assert not scene.led_on("cam2", T0 + 20)  # per camera
    scene.set_led("cam1", False, T0 + 20)
    scene.pulse_led("cam1", T0 + 30, 0.3)
    assert not scene.led_on("cam1", T0 + 29.9)
    assert scene.led_on("cam1", T0 + 30.0) and scene.led_on("cam1", T0 + 30.29)
    assert not scene.led_on("cam1", T0 + 30.3)
    assert scene.led_on("cam1", T0 + 15)  # history is kept
    # the latest command wins: switching on during a pulse cancels its pending "off"
    scene.pulse_led("cam1", T0 + 40, 0.3)
    scene.set_led("cam1", True, T0 + 40.1)
    assert scene.led_on("cam1", T0 + 41)


def test_schedule_without_time_sets_all_times_and_history_is_bounded():
    s = Schedule(0, max_events=10)
    for i in range(100):
        s.set(i, float(i))
    assert s.at(99.5) == 99 and s.at(95) == 95
    assert s.at(-1) == 89  # older history folded into the initial value
    s.set("x")
    assert s.at(-1e9) == "x" and s.at(1e9) == "x"
