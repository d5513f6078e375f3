"""The stereo calibration of the simulated rig against its true cameras (issue 10).

For each seed: 20 rendered checkerboard views of the reference rig (as `vts calibrate stereo
--sim`), calibrated with OpenCV's five distortion terms and with the lens model `auto` chooses;
printed per model, over both cameras and all seeds, the median and largest |error| of cx, cy,
fx, k1, the stereo rotation, and the 3D RMS error of 300 points in a 300 mm cube about the field
of view's centre (their exact projections triangulated with the calibration, in camera 1's
frame, and after the best rigid fit, which is what the VTS → SPECT mapping leaves), the largest
error in standard deviations of the fit, and the ratio auto / five terms of each figure.
See docs/decisions/0024-calibration-uncertainty.md.

Run: ``.venv/bin/python bench/calibration_sim.py [--seeds 4] [--poses 20]``
"""

from __future__ import annotations

import argparse

import numpy as np

from vts_hw.sim_devices.scenarios.calibration_views import sim_views
from vts_hw.sim_devices.scene import Scene
from vts_hw.vision.calibration import calibrate_stereo
from vts_hw.vision.calibration_uncertainty import compare_with_truth
from vts_hw.vision.registration import kabsch
from vts_hw.vision.triangulate import triangulate

FIGURES = ("cx px", "cy px", "fx px", "k1", "rotation deg", "3D RMS mm", "3D RMS rigid mm")


def score(seed: int, poses: int, model: str) -> dict[str, list[float]]:
    pairs, names, truth = sim_views(seed, poses)
    cal = calibrate_stereo(pairs, square=50.0, unit="mm", names=names, distortion=model)
    t = compare_with_truth(cal, truth)
    out = {k: [] for k in FIGURES}
    for rows in t["cameras"].values():
        for key in ("cx", "cy", "fx", "k1"):
            out[f"{key} px" if key != "k1" else "k1"].append(abs(rows[key]["error"]))
    out["rotation deg"].append(t["rotation"]["error_deg"])
    scene = Scene.reference(seed, start_epoch=0.0)
    c1, c2 = scene.cameras["cam1"], scene.cameras["cam2"]
    pts = np.random.default_rng(99).uniform(-150, 150, (300, 3))
    true1 = c1.to_camera(pts)
    tri = triangulate(cal.cameras(), [c1.project(pts), c2.project(pts)]).points
    out["3D RMS mm"].append(float(np.sqrt(np.mean(np.sum((tri - true1) ** 2, axis=1)))))
    fit = kabsch(tri, true1).apply(tri)
    out["3D RMS rigid mm"].append(float(np.sqrt(np.mean(np.sum((fit - true1) ** 2, axis=1)))))
    out["sigmas"] = [max(r["ratio"] for r in t["judged"])]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=4, help="simulated rigs (seeds 0..N-1)")
    ap.add_argument("--poses", type=int, default=20, help="rendered board poses per calibration")
    args = ap.parse_args()
    res = {}
    for model in ("opencv", "auto"):
        acc: dict[str, list[float]] = {}
        for seed in range(args.seeds):
            for k, v in score(seed, args.poses, model).items():
                acc.setdefault(k, []).extend(v)
        res[model] = acc
    print(f"simulated rig, {args.seeds} seeds, {args.poses} poses: |error| median / max")
    print(f"{'figure':18s} {'five terms':>20s} {'auto':>20s} {'ratio of max':>13s}")
    for k in FIGURES:
        a, b = np.array(res["opencv"][k]), np.array(res["auto"][k])
        print(
            f"{k:18s} {np.median(a):9.4g} / {a.max():8.4g} {np.median(b):9.4g} / {b.max():8.4g}"
            f" {b.max() / a.max():13.2f}"
        )
    for model in ("opencv", "auto"):
        print(f"largest error / its standard deviation ({model}): {max(res[model]['sigmas']):.2f}")


if __name__ == "__main__":
    main()
