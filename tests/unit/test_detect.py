"""Marker detection against the simulator's ground truth, and on real Axis frames."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from vts_hw.sim_devices.render import Renderer, encode, polygon_centroid, polygon_coverage
from vts_hw.sim_devices.scene import Scene
from vts_hw.vision.detect import (
    Blob,
    DetectionResult,
    DetectorSettings,
    auto_threshold,
    candidate_boxes,
    detect,
    detect_jpeg,
)

T_OFFSET = 100.0  # seconds after the scene's start


def rig(seed: int = 0, phantom: bool = False, led: bool = True):
    """A reference scene (LEDs as asked), its renderer and the instant to render."""
    scene = Scene.reference(seed=seed)
    if phantom:
        scene.add_phantom()
    for cam in scene.camera_names:
        scene.set_led(cam, led)
    return scene, Renderer(scene, seed=seed), scene.start_epoch + T_OFFSET


def jpeg_frame(renderer: Renderer, cam: str, t: float, quality: int = 75) -> np.ndarray:
    """A noisy frame as the camera would send it: JPEG-encoded, decoded to grey."""
    return cv2.imdecode(np.frombuffer(encode(renderer.render(cam, t), quality), np.uint8), cv2.IMREAD_GRAYSCALE)


def match(blobs: list[Blob], truth, tol: float = 1.0) -> dict[str, Blob]:
    """Truth id -> the blob within ``tol`` px of it (each truth at most once)."""
    out = {}
    for marker_id, u, v in truth:
        near = [b for b in blobs if np.hypot(b.x - u, b.y - v) < tol]
        if len(near) == 1:
            out[marker_id] = near[0]
    return out


@pytest.mark.parametrize("cam", ["cam1", "cam2"])
def test_wall_markers_found_without_strays(cam):
    scene, r, t = rig()
    res = detect(jpeg_frame(r, cam, t))
    truth = scene.truth(cam, t)
    assert isinstance(res, DetectionResult)
    assert len(truth) == 5
    assert len(res.blobs) == 5 and res.rejected == []
    assert set(match(res.blobs, truth, 0.3)) == {m for m, _, _ in truth}
    assert [(b.y, b.x) for b in res.blobs] == sorted((b.y, b.x) for b in res.blobs)
    for b in res.blobs:  # 25 mm disks, about 20 px, 200 grey levels above the wall
        assert 250 < b.area < 420
        assert b.roundness > 0.9
        assert 180 < b.peak < 255  # a maximum: noise and JPEG ringing add to it
        assert 0.8 < b.sum / (200 * b.area) < 1.2


@pytest.mark.parametrize("seed,cam", [(0, "cam1"), (0, "cam2"), (3, "cam1")])
def test_centroids_match_truth_and_are_stable(seed, cam):
    """JPEG q75, 2 grey levels of noise: mean error and frame-to-frame SD <= 0.05 px."""
    scene, r, t = rig(seed)
    truth = scene.truth(cam, t)
    xy = {m: [] for m, _, _ in truth}
    for _ in range(10):
        found = match(detect(jpeg_frame(r, cam, t)).blobs, truth, 0.5)
        assert set(found) == set(xy)
        for m, b in found.items():
            xy[m].append((b.x, b.y))
    for m, u, v in truth:
        p = np.array(xy[m])
        assert np.all(np.abs(p.mean(axis=0) - (u, v)) <= 0.05), (m, p.mean(axis=0), (u, v))
        assert np.all(p.std(axis=0, ddof=1) <= 0.05), (m, p.std(axis=0, ddof=1))


def test_led_off_frame_has_no_blobs():
    scene, r, t = rig(led=False)
    for cam in scene.camera_names:
        res = detect(jpeg_frame(r, cam, t))
        assert res.blobs == [] and res.rejected == []
        assert res.threshold >= res.background + 40


def test_noise_only_frame_has_no_blobs():
    rng = np.random.default_rng(1)
    for level, sigma in ((20, 2.0), (5, 1.0), (60, 6.0)):
        img = np.clip(rng.normal(level, sigma, (480, 640)), 0, 255).astype(np.uint8)
        res = detect(img)
        assert res.blobs == [] and res.rejected == [], (level, sigma)
        assert res.threshold > level + 6 * sigma


def test_threshold_automatic_and_configured():
    scene, r, t = rig()
    img = jpeg_frame(r, "cam1", t)
    auto = detect(img)
    assert auto_threshold(img) == (auto.threshold, auto.background)
    assert 15 <= auto.background <= 25  # the wall is dim, about 20
    assert auto.background + 40 <= auto.threshold < 120
    high = detect(img, DetectorSettings(threshold=150))
    assert high.threshold == 150
    assert len(high.blobs) == 5
    truth = scene.truth("cam1", t)
    a, h = match(auto.blobs, truth, 0.3), match(high.blobs, truth, 0.3)
    for m in a:  # fewer pixels above a higher threshold; the window and centroid barely move
        assert h[m].area < a[m].area
        assert abs(h[m].x - a[m].x) < 0.03 and abs(h[m].y - a[m].y) < 0.03
    assert detect(img, DetectorSettings(threshold=240)).blobs == []


def test_stray_bright_line_is_rejected_for_roundness():
    scene, r, t = rig()
    img = jpeg_frame(r, "cam1", t)
    cv2.rectangle(img, (250, 240), (330, 246), 230, thickness=-1)  # 81 x 7 px, a reflection
    res = detect(img)
    assert len(res.blobs) == 5
    assert len(match(res.blobs, scene.truth("cam1", t), 0.1)) == 5
    assert [reason for _, reason in res.rejected] == ["roundness"]
    stray = res.rejected[0][0]
    assert stray.roundness < 0.2 and abs(stray.x - 290) < 1 and abs(stray.y - 243) < 1


def test_small_speck_is_rejected_for_area():
    scene, r, t = rig()
    img = jpeg_frame(r, "cam1", t)
    img[300:303, 100:103] = 230  # 9 px
    res = detect(img)
    assert len(res.blobs) == 5
    assert [reason for _, reason in res.rejected] == ["area"]


def test_marker_cut_by_the_image_border():
    """Rolled so that two wall disks straddle the right edge (their other halves wrap to the
    left edge): no crash, nothing cut is accepted, the others still measure right."""
    scene, r, t = rig()
    shift = 84
    img = np.roll(jpeg_frame(r, "cam1", t), shift, axis=1)
    truth = [(m, u + shift, v) for m, u, v in scene.truth("cam1", t)]
    inside = [(m, u, v) for m, u, v in truth if u < 640 - 15]
    res = detect(img)
    assert set(match(res.blobs, inside, 0.1)) == {m for m, _, _ in inside}
    assert len(res.blobs) == len(inside) == 3
    assert res.rejected and {reason for _, reason in res.rejected} == {"border"}
    assert detect(img[:, :300]).blobs is not None  # cropped frames too


def add_disk(img: np.ndarray, cx: float, cy: float, radius: float, level: float = 200.0):
    """Add an exactly rasterised disk (the simulator's coverage) to a float image."""
    a = np.linspace(0, 2 * np.pi, 96, endpoint=False)
    poly = np.stack([cx + radius * np.cos(a), cy + radius * np.sin(a)], axis=1)
    x0, y0 = int(cx - radius) - 2, int(cy - radius) - 2
    n = int(2 * radius) + 5
    img[y0 : y0 + n, x0 : x0 + n] += level * polygon_coverage(poly, x0, y0, n, n)
    return polygon_centroid(poly)


def test_close_markers_measured_apart():
    """Two disks 5 px apart (edge to edge): each one's ROI holds part of the other; each is
    measured with the other masked out, as if alone."""
    rng = np.random.default_rng(2)
    alone = rng.normal(20, 2, (480, 640))
    c1 = add_disk(alone, 300.3, 200.6, 10.0)
    pair = alone.copy()
    c2 = add_disk(pair, 325.6, 201.2, 10.0)
    ref = detect(np.clip(np.rint(alone), 0, 255).astype(np.uint8)).blobs
    res = detect(np.clip(np.rint(pair), 0, 255).astype(np.uint8))
    assert len(ref) == 1 and len(res.blobs) == 2 and res.rejected == []
    first, second = sorted(res.blobs, key=lambda b: b.x)
    assert abs(first.x - ref[0].x) < 0.03 and abs(first.y - ref[0].y) < 0.03
    for b, c in ((first, c1), (second, c2)):
        assert abs(b.x - c[0]) < 0.05 and abs(b.y - c[1]) < 0.05


def test_roundness_of_an_ellipse():
    img = np.full((200, 200), 20, np.uint8)
    cv2.ellipse(img, (100, 100), (20, 10), 30, 0, 360, 220, -1, cv2.LINE_AA)
    res = detect(img, DetectorSettings(min_roundness=0.3))
    assert len(res.blobs) == 1
    assert res.blobs[0].roundness == pytest.approx(0.5, abs=0.03)
    assert detect(img).rejected[0][1] == "roundness"


@pytest.mark.parametrize("cam", ["cam1", "cam2"])
def test_phantom_spheres_found(cam):
    scene, r, t = rig(phantom=True)
    truth = scene.truth(cam, t)
    img = jpeg_frame(r, cam, t)
    res = detect(img)
    assert len(truth) == 12
    assert len(res.blobs) == 12 and res.rejected == []
    found = match(res.blobs, truth, 0.1)
    assert set(found) == {m for m, _, _ in truth}
    for m in ("S1", "S2", "S3", "S4", "S5", "S6", "S7"):  # 13 mm spheres, about 12 px
        assert 70 < found[m].area < 160 and found[m].roundness > 0.85
    # The first stage alone (what bench/detect_speed.py times as the floor): detect's threshold,
    # one box per marker, each marker's centre inside its box's extent at full resolution (0006).
    thr, median, boxes = candidate_boxes(img)
    assert (thr, median) == (res.threshold, res.background) and len(boxes) == 12
    step = DetectorSettings().step
    for _, u, v in truth:
        assert (
            sum((x - 1) * step < u < (x + w) * step and (y - 1) * step < v < (y + h) * step for x, y, w, h in boxes)
            == 1
        )


def test_detect_jpeg_decodes_then_detects():
    scene, r, t = rig()
    data = encode(r.render("cam2", t), 75)
    direct = detect(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE))
    assert detect_jpeg(data) == direct
    with pytest.raises(ValueError):
        detect_jpeg(b"not a jpeg")


def test_bad_input_is_refused():
    with pytest.raises(ValueError):
        detect(np.zeros((480, 640), np.float32))
    with pytest.raises(ValueError):
        detect(np.zeros((480, 640, 3), np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        candidate_boxes(np.zeros((480, 640), np.float32))
    with pytest.raises(ValueError):
        DetectorSettings(step=0)


@pytest.mark.parametrize("shape", [(1, 1), (9, 13), (40, 40), (17, 500)])
def test_tiny_and_odd_frames(shape):
    """No crash on frames smaller than an ROI, all dark, all white or full of speckle."""
    rng = np.random.default_rng(3)
    for img in (np.zeros(shape, np.uint8), np.full(shape, 255, np.uint8), rng.integers(0, 256, shape).astype(np.uint8)):
        res = detect(img)
        assert res.blobs == [] or all(isinstance(b, Blob) for b in res.blobs)


@pytest.mark.parametrize("name", ["tst.jpg", "00000000.jpg"])
def test_real_axis_frames(axis_frames, name):
    """Real camera frames (a room, no LED markers): detection runs and reports what it saw."""
    img = cv2.imdecode(np.fromfile(axis_frames / name, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert img is not None
    res = detect(img)
    assert isinstance(res, DetectionResult)
    assert 0 < res.background < res.threshold <= 255
    assert all(isinstance(b, Blob) for b in res.blobs)
    assert all(isinstance(reason, str) for _, reason in res.rejected)
    assert isinstance(detect_jpeg((axis_frames / name).read_bytes()), DetectionResult)
