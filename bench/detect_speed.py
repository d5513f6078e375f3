"""Speed of marker detection relative to JPEG decoding (goals: (decode + detect) / decode <= 1.15
with the reference rig's 5 wall markers, <= 1.25 with the 7-sphere phantom in view, 12 markers).

Renders frames of the reference rig (2 cameras, LED on, 5 wall markers; sensor noise varied
around the rig's 2 grey levels), encodes them as JPEG quality 75, then times, frame by frame
and in turn, ``cv2.imdecode(..., IMREAD_GRAYSCALE)`` alone, ``detect_jpeg`` (the same decode,
then ``detect``) and the same decode then ``candidate_boxes`` (the detector's threshold and
candidate search alone: what any measuring step comes on top of). The medians are compared, so
that the load of a shared machine falls on all alike; other jobs still move the ratios by a few
hundredths from run to run. The same again with the 7-sphere phantom in view (12 markers).
Each case prints its ratio beside its goal, and the detection time beside the time the goal
allows (docs/decisions/0087-detection-speed-floor.md).

Run: ``.venv/bin/python bench/detect_speed.py [--frames 50] [--reps 40]``
"""

from __future__ import annotations

import argparse
import statistics
import time

import cv2
import numpy as np

from vts_hw.sim_devices.render import Renderer, encode
from vts_hw.sim_devices.scene import Scene
from vts_hw.vision.detect import DEFAULT, candidate_boxes, detect_jpeg

GOALS = {False: 1.15, True: 1.25}  # (decode + detect) / decode; key: phantom in view
NOISE = (1.5, 2.0, 2.5)


def make_frames(n_frames: int, phantom: bool, seed: int = 0) -> list[bytes]:
    """``n_frames`` JPEGs (q75) alternating cameras and noise levels."""
    scene = Scene.reference(seed=seed)
    if phantom:
        scene.add_phantom()
    t = scene.start_epoch + 60.0
    for cam in scene.camera_names:
        scene.set_led(cam, True)
    renderers = [Renderer(scene, noise_sigma=s, seed=i) for i, s in enumerate(NOISE)]
    frames = []
    for i in range(n_frames):
        cam = scene.camera_names[i % len(scene.camera_names)]
        frames.append(encode(renderers[(i // 2) % len(NOISE)].render(cam, t), 75))
    return frames


def time_frames(frames: list[bytes], reps: int) -> tuple[float, float, float, float]:
    """Median seconds of decode alone, of decode + detect (:func:`detect_jpeg`) and of decode +
    candidate search (:func:`candidate_boxes`), timed frame by frame and in turn (the order
    rotating, so that none always follows another); and the mean number of blobs per frame."""
    times = ([], [], [])
    found = 0
    clock = time.perf_counter
    orders = ((0, 1, 2), (1, 2, 0), (2, 0, 1))
    for r in range(reps):
        for data in frames:
            for which in orders[r % 3]:
                t0 = clock()
                if which == 1:
                    res = detect_jpeg(data)
                else:
                    gray = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_GRAYSCALE)
                    if which == 2:
                        candidate_boxes(gray, DEFAULT)
                t1 = clock()
                times[which].append(t1 - t0)
                if which == 1 and r == reps - 1:
                    found += len(res.blobs)
    dec, both, cand = (statistics.median(t) for t in times)
    return dec, both, cand, found / len(frames)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=50)
    ap.add_argument("--reps", type=int, default=40)
    args = ap.parse_args(argv)
    for phantom, label in ((False, "reference rig, wall markers"), (True, "with the 7-sphere phantom")):
        frames = make_frames(args.frames, phantom)
        time_frames(frames[:5], 5)  # warm-up (caches of the detector and the allocator)
        dec, both, cand, blobs = time_frames(frames, args.reps)
        ratio, goal = both / dec, GOALS[phantom]
        size = sum(map(len, frames)) / len(frames) / 1000
        print(
            f"{label}: {args.frames} frames x {args.reps} reps, {blobs:.1f} blobs/frame, JPEG {size:.1f} kB on average"
        )
        print(
            f"  decode {dec * 1e3:.3f} ms   decode+detect {both * 1e3:.3f} ms   "
            f"detect {(both - dec) * 1e6:.0f} us (the goal allows {(goal - 1) * dec * 1e6:.0f} us)"
        )
        print(f"  ratio {ratio:.3f}   goal <= {goal}: {'met' if ratio <= goal else 'not met'}")
        print(f"  candidate search alone {(cand - dec) * 1e6:.0f} us, ratio {cand / dec:.3f}")


if __name__ == "__main__":
    main()
