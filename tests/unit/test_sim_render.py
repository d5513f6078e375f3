"""The renderer of what each simulated camera sees, and the camera source the HTTP server uses."""

import threading

import cv2
import numpy as np
import pytest
from scipy.optimize import brentq

from vts_hw.recording.axis_jpeg import inspect_jpeg
from vts_hw.sim_devices.camera_source import SimCameraSource
from vts_hw.sim_devices.clock import VirtualClock
from vts_hw.sim_devices.render import Renderer, polygon_centroid, polygon_coverage
from vts_hw.sim_devices.scene import DAY, PHANTOM_LAYOUT, Scene

T0 = 1_700_000_000.0


@pytest.fixture
def scene():
    s = Scene.reference(seed=0, start_epoch=T0)
    s.add_phantom()
    for cam in s.cameras:
        s.set_led(cam, True, T0)
    return s


def centroid(img, u, v, half=14):
    """Intensity-weighted centroid of ``img`` in a window around (u, v)."""
    u0, v0 = int(round(u)), int(round(v))
    win = img[v0 - half : v0 + half + 1, u0 - half : u0 + half + 1]
    yy, xx = np.mgrid[v0 - half : v0 + half + 1, u0 - half : u0 + half + 1]
    return np.array([(win * xx).sum(), (win * yy).sum()]) / win.sum()


def test_polygon_coverage_is_exact_for_a_square():
    # a 3 x 2 px rectangle from x = 10.25 to 13.25, y = 5.5 to 7.5 (pixel centres at integers)
    poly = np.array([[10.25, 5.5], [13.25, 5.5], [13.25, 7.5], [10.25, 7.5]])
    cov = polygon_coverage(poly, 8, 4, 8, 6, supersample=4)
    assert cov.sum() == pytest.approx(6.0)
    # columns 8..15, rows 4..9: pixel 10 is a quarter covered, 11 and 12 whole, 13 three quarters
    assert np.allclose(cov[2], [0, 0, 0.25, 1, 1, 0.75, 0, 0]) and np.array_equal(cov[2], cov[3])
    assert not cov[[0, 1, 4, 5]].any()
    yy, xx = np.mgrid[4:10, 8:16]
    c = np.array([(cov * xx).sum(), (cov * yy).sum()]) / cov.sum()
    assert np.allclose(c, polygon_centroid(poly), atol=1e-9)


def test_markers_are_bright_only_while_the_led_is_on(scene):
    r = Renderer(scene, noise_sigma=0)
    scene.set_led("cam1", False, T0 + 10)
    on = r.render("cam1", T0 + 5).astype(int)
    off = r.render("cam1", T0 + 15).astype(int)
    bg = r.background("cam1").astype(int)
    assert 10 < bg.mean() < 30 and bg.max() - bg.min() < 15
    for mid, u, v in scene.truth("cam1", T0 + 5):
        u0, v0 = int(round(u)), int(round(v))
        assert on[v0, u0] >= 200, mid  # bright
        assert 0 < off[v0, u0] - bg[v0, u0] <= 6, mid  # barely above background
    assert (on - bg).max() >= 195 and (off - bg).max() <= 5
    # far from any marker nothing changes with the LED
    assert np.array_equal(on[:20, :20], off[:20, :20])
    # noisy images: the same, within the noise
    noisy = Renderer(scene)
    u, v = scene.truth("cam1", T0 + 5)[0][1:]
    assert noisy.render("cam1", T0 + 5)[int(round(v)), int(round(u))] > 190
    assert noisy.render("cam1", T0 + 15)[int(round(v)), int(round(u))] < 45


@pytest.mark.parametrize("cam", ["cam1", "cam2"])
def test_rendered_centroids_match_the_truth(scene, cam):
    r = Renderer(scene, noise_sigma=0)
    t = T0 + 33 * DAY  # with some drift
    img = r.render(cam, t).astype(float) - r.background(cam)
    camera, markers, uv, visible = scene.project_markers(cam, t)
    assert visible.sum() == 12
    for m, (u, v) in zip(markers, uv):
        c = centroid(img, u, v)
        assert np.abs(c - (u, v)).max() < 0.02, (m.id, c - (u, v))
        # and against the centroid of the exact projected outline (no perspective bias)
        outline = polygon_centroid(camera.project(m.outline(camera.center, 4096)))
        assert np.abs(c - outline).max() < 0.015, m.id


def test_perspective_bias_is_tiny(scene):
    """Centroid of the projected outline minus projected centre: < 0.01 px (see ADR 0002)."""
    for cam in scene.cameras:
        camera, markers, uv, _ = scene.project_markers(cam, T0)
        bias = np.array(
            [polygon_centroid(camera.project(m.outline(camera.center, 4096))) - p for m, p in zip(markers, uv)]
        )
        assert np.abs(bias).max() < 0.01
        assert np.abs(bias[:5]).max() > 1e-3  # the tilted wall disks do show it


def test_noise_is_about_two_grey_levels_and_changes_every_frame(scene):
    r = Renderer(scene, noise_sigma=2.0)
    clean = r.clean("cam1", T0 + 1)
    frames = np.array([r.render("cam1", T0 + 1) for _ in range(16)], dtype=float)
    resid = frames[:, 10:120, 10:120] - clean[10:120, 10:120]  # no marker there
    assert resid.std() == pytest.approx(2.0, abs=0.1)
    assert abs(resid.mean()) < 0.05
    assert not np.array_equal(frames[0], frames[1])
    # the mean of many frames converges to the clean image (quantisation dithered by noise)
    assert np.abs(frames.mean(axis=0) - clean)[10:120, 10:120].mean() < 0.5 + 1e-9
    # averaging frames, marker centroids stay on the truth
    mean = frames.mean(axis=0) - r.background("cam1")
    for mid, u, v in scene.truth("cam1", T0 + 1)[:5]:
        assert np.abs(centroid(mean, u, v) - (u, v)).max() < 0.05, mid


def test_cache_follows_table_moves_and_drift(scene):
    r = Renderer(scene, noise_sigma=0)
    a = r.render("cam2", T0 + 1)
    b = r.render("cam2", T0 + 2)
    assert np.array_equal(a, b) and r.stats["misses"] == 1 and r.stats["hits"] == 1
    scene.move_table(10.0, 0.0, t=T0 + 3)
    c = r.render("cam2", T0 + 3).astype(float) - r.background("cam2")
    assert r.stats["misses"] == 2
    for mid, u, v in scene.truth("cam2", T0 + 3):
        assert np.abs(centroid(c, u, v) - (u, v)).max() < 0.02, mid
    # 60 days later the camera has drifted; the image follows the truth, not the cache
    late = T0 + 60 * DAY
    d = r.render("cam2", late).astype(float) - r.background("cam2")
    shifted = [
        np.hypot(u - u0, v - v0)
        for (_, u, v), (_, u0, v0) in zip(scene.truth("cam2", late), scene.truth("cam2", T0 + 3))
    ]
    assert min(shifted) > 0.5
    for mid, u, v in scene.truth("cam2", late):
        assert np.abs(centroid(d, u, v) - (u, v)).max() < 0.02, mid


def test_jpeg_decodes_to_the_image(scene):
    r = Renderer(scene)
    img = r.render("cam1", T0)
    data = r.encode(img, 75)
    colour = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    assert colour.shape == (480, 640, 3)  # colour, as a camera sends it
    back = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert back.shape == (480, 640) and back.dtype == np.uint8
    assert np.abs(back.astype(int) - img).mean() < 3
    assert len(r.encode(img, 30)) < len(data) < len(r.encode(img, 95))


def test_camera_source_stamps_the_camera_clock(scene):
    clock = VirtualClock(T0 + 1000.0)
    src = SimCameraSource(scene, Renderer(scene), "cam2", clock)
    assert (src.name, src.width, src.height) == ("cam2", 640, 480)
    data, cam_t = src.jpeg(75)
    info = inspect_jpeg(data)
    assert info.problems == () and (info.width, info.height) == (640, 480)
    assert info.product == scene.products["cam2"] == src.product
    assert abs(info.timestamp - cam_t) < 0.01
    host = scene.clocks["cam2"].host_time(cam_t)
    assert host == pytest.approx(clock.now(), abs=1.0)
    clk = scene.clocks["cam2"]
    assert cam_t - host == pytest.approx(clk.offset_s + clk.skew_ppm * 1e-6 * (host - T0), abs=1e-6)
    # an explicit host time: that frame, that stamp
    data, cam_t = src.jpeg(50, host_t=T0 + 5 * DAY)
    assert cam_t == pytest.approx(scene.clocks["cam2"].camera_time(T0 + 5 * DAY))
    assert abs(inspect_jpeg(data).timestamp - cam_t) < 0.01


def test_camera_source_led_and_pulse():
    s = Scene.reference(seed=1, start_epoch=T0)
    clock = VirtualClock(T0 + 10, rate=1.0)
    r = Renderer(s)
    src = SimCameraSource(s, r, "cam1", clock)
    u, v = [int(round(x)) for x in s.truth("cam1", T0)[0][1:]]

    def pixel():
        data, _ = src.jpeg(90)
        return cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)[v, u]

    assert not src.led_on() and pixel() < 50
    src.set_led(True)
    assert src.led_on() and pixel() > 190
    src.set_led(False)
    src.pulse_led(0.3)
    assert src.led_on()
    clock.advance(0.5)
    assert not src.led_on() and pixel() < 50
    assert not s.led_on("cam2", clock.now())  # the other camera never was on
    with pytest.raises(KeyError):
        SimCameraSource(s, r, "cam9", clock)


def test_camera_source_is_thread_safe():
    s = Scene.reference(seed=2, n_cameras=4, start_epoch=T0)
    s.add_phantom()
    clock = VirtualClock(T0, rate=3600.0)  # drift and clocks move while frames are served
    r = Renderer(s)
    sources = [SimCameraSource(s, r, name, clock) for name in s.cameras]
    errors, counts = [], []

    def serve(src):
        try:
            n = 0
            for i in range(40):
                if i % 10 == 0:
                    src.pulse_led(0.05)
                data, cam_t = src.jpeg(75)
                info = inspect_jpeg(data)
                assert info.problems == () and abs(info.timestamp - cam_t) < 0.01
                n += 1
            counts.append(n)
        except Exception as exc:  # noqa: BLE001 - collected and asserted below
            errors.append(exc)

    threads = [threading.Thread(target=serve, args=(src,)) for src in sources for _ in range(2)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert errors == [] and counts == [40] * 8


def test_markers_partly_outside_the_image_are_clipped(scene):
    r = Renderer(scene, noise_sigma=0)
    camera = scene.cameras["cam1"]
    # world X (at Y = Z = 0) whose image lies 2 px left of the image: image right is world -X
    x_out = brentq(lambda x: camera.project([[x, 0.0, 0.0]])[0, 0] + 2.0, 0.0, 1000.0)
    s1 = np.array(PHANTOM_LAYOUT["S1"])
    scene.set_phantom_pose((0, 0, 0), np.array([x_out, 0.0, 0.0]) - s1, t=T0 + 1)
    assert "S1" not in [mid for mid, _, _ in scene.truth("cam1", T0 + 1)]  # centre outside
    img = r.render("cam1", T0 + 1).astype(int) - r.background("cam1")
    v = int(round(camera.project([[x_out, 0.0, 0.0]])[0, 1]))
    assert img[v - 2 : v + 3, 0].max() > 50  # the part inside the image is drawn at the edge
    assert img[v - 2 : v + 3, 6].max() == 0  # and nothing beyond its radius (~6 px)
