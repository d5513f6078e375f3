"""Precision of marker centroids on simulated frames (goal: SD and error of the mean <= 0.05 px).

For each camera of the reference rig (seeds 0-4), 100 frames of a still scene with the LEDs
on, 2 grey levels of sensor noise, JPEG quality 75: per wall marker, the frame-to-frame SD of
x and y (px) and the error of the mean centroid against the rendered truth (the projection of
the marker's centre). Then the same for the 7-sphere phantom (information). Last, a check of
one design choice, with an independent per-pixel implementation: values below the local
background kept (what ``detect`` does) or clipped to 0.

Run: ``.venv/bin/python bench/detect_precision.py [--frames 100] [--seeds 5]``
"""

from __future__ import annotations

import argparse
import math

import cv2
import numpy as np

from vts_hw.sim_devices.render import Renderer, encode
from vts_hw.sim_devices.scene import Scene
from vts_hw.vision.detect import Blob, DetectorSettings, detect

GOAL = 0.05


def frames(scene: Scene, cam: str, t: float, n: int, seed: int):
    """``n`` noisy JPEG q75 frames of ``cam`` at the fixed instant ``t``, decoded to grey."""
    r = Renderer(scene, seed=seed)
    for _ in range(n):
        yield cv2.imdecode(np.frombuffer(encode(r.render(cam, t), 75), np.uint8), cv2.IMREAD_GRAYSCALE)


def reference_centroid(img: np.ndarray, b: Blob, clip: bool, pad: float) -> tuple[float, float]:
    """Centroid recomputed plainly, per pixel: plane fitted to the border of a square around
    the blob, circular window of radius sqrt(area/pi) + pad, negatives kept or clipped."""
    r = math.sqrt(b.area / math.pi) + pad
    h = int(r) + 4
    x0, y0 = int(round(b.x)) - h, int(round(b.y)) - h
    roi = img[y0 : y0 + 2 * h + 1, x0 : x0 + 2 * h + 1].astype(float)
    yy, xx = np.mgrid[y0 : y0 + 2 * h + 1, x0 : x0 + 2 * h + 1].astype(float)
    ring = (xx == x0) | (xx == x0 + 2 * h) | (yy == y0) | (yy == y0 + 2 * h)
    A = np.stack([np.ones(ring.sum()), xx[ring], yy[ring]], axis=1)
    a, bx, by = np.linalg.lstsq(A, roi[ring], rcond=None)[0]
    w = roi - (a + bx * xx + by * yy)
    if clip:
        w = np.maximum(w, 0.0)
    w = np.where((xx - b.x) ** 2 + (yy - b.y) ** 2 <= r * r, w, 0.0)
    return float((w * xx).sum() / w.sum()), float((w * yy).sum() / w.sum())


def measure(seeds: int, n: int, phantom: bool, variants: bool = False):
    """Rows ``(seed, cam, marker, sd_x, sd_y, err_x, err_y)``; with ``variants``, also the same
    statistics for the reference implementation, negatives kept and clipped."""
    rows, extra = [], {"keep": [], "clip": []}
    pad = DetectorSettings().window_pad
    for seed in range(seeds):
        scene = Scene.reference(seed=seed)
        if phantom:
            scene.add_phantom()
        t = scene.start_epoch + 3600.0
        for cam in scene.camera_names:
            scene.set_led(cam, True)
        for cam in scene.camera_names:
            truth = [(m, u, v) for m, u, v in scene.truth(cam, t) if m.startswith("S") == phantom]
            xy = {m: [] for m, _, _ in truth}
            ref = {k: {m: [] for m, _, _ in truth} for k in extra}
            for img in frames(scene, cam, t, n, seed):
                blobs = detect(img).blobs
                for m, u, v in truth:
                    b = min(blobs, key=lambda q: (q.x - u) ** 2 + (q.y - v) ** 2)
                    assert math.hypot(b.x - u, b.y - v) < 1.0, f"{m} not found"
                    xy[m].append((b.x, b.y))
                    for k in ref if variants else ():
                        ref[k][m].append(reference_centroid(img, b, k == "clip", pad))
            for m, u, v in truth:
                rows.append(stats(seed, cam, m, xy[m], u, v))
                for k in ref if variants else ():
                    extra[k].append(stats(seed, cam, m, ref[k][m], u, v))
    return rows, extra


def stats(seed, cam, m, points, u, v):
    p = np.array(points)
    sd = p.std(axis=0, ddof=1)
    err = p.mean(axis=0) - (u, v)
    return seed, cam, m, sd[0], sd[1], err[0], err[1]


def summary(rows) -> tuple[float, float]:
    """Largest SD and largest |error of the mean| over all rows and both axes."""
    return (max(max(r[3], r[4]) for r in rows), max(max(abs(r[5]), abs(r[6])) for r in rows))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args(argv)

    rows, extra = measure(args.seeds, args.frames, phantom=False, variants=True)
    print(f"wall markers (25 mm disks), {args.frames} frames per camera, JPEG q75, noise 2")
    print("seed cam   marker   sd_x    sd_y    err_x    err_y   (px)")
    for seed, cam, m, sx, sy, ex, ey in rows:
        print(f"{seed:4d} {cam:5s} {m:6s} {sx:7.4f} {sy:7.4f} {ex:+8.4f} {ey:+8.4f}")
    sd, err = summary(rows)
    print(f"max SD {sd:.4f} px, max |error of the mean| {err:.4f} px over {len(rows)} markers")
    print(f"goal <= {GOAL} px: {'met' if sd <= GOAL and err <= GOAL else 'not met'}")

    ph, _ = measure(1, args.frames, phantom=True)
    sd, err = summary(ph)
    print(
        f"\n7-sphere phantom (13 mm spheres, info), seed 0: max SD {sd:.4f} px, "
        f"max |error of the mean| {err:.4f} px over {len(ph)} spheres"
    )

    print("\nbelow-background values, plain per-pixel reference (wall markers):")
    for k, label in (("keep", "kept   "), ("clip", "clipped")):
        sd, err = summary(extra[k])
        rms = math.sqrt(np.mean([r[5] ** 2 + r[6] ** 2 for r in extra[k]]) / 2)
        print(
            f"  {label}: max SD {sd:.4f} px, max |error of the mean| {err:.4f} px, RMS error of the mean {rms:.4f} px"
        )


if __name__ == "__main__":
    main()
