"""The N-camera calibration of the simulated room against its true cameras, 2 and 4 cameras (issue 11).

For each seed and camera count: the views of `vts calibrate cameras --sim --cameras N` (the board
held towards pairs of cameras, rendered, JPEG, noise), the corners found, the calibration timed
(corners to result: intrinsics, chained poses, bundle adjustment, uncertainties). Printed per
camera count: the 3D RMS of 400 points spread over the field of view (exact projections,
triangulated with the calibration, in camera 1's frame, and after the best rigid fit, which is
what the VTS → SPECT mapping leaves), the per-camera errors (|fx| %, |cx|, |cy| px, |k1|, the
camera's rotation in degrees and position in mm relative to camera 1), median / largest over
cameras and seeds, and the calibration time. All measured in this one run.
See docs/decisions/0030-n-camera-calibration.md.

Run: ``.venv/bin/python bench/n_calibration.py [--seeds 2] [--poses 8]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from vts_hw.procedures.calibration_images import find_all_corners
from vts_hw.sim_devices.scenarios.calibration_views import cameras_against_truth, sim_camera_views
from vts_hw.vision.calibration import calibrate_cameras

CAMERA_FIGURES = ("fx %", "cx px", "cy px", "k1", "rotation deg", "position mm")


def one(seed: int, n_cameras: int, poses: int) -> dict[str, list[float]]:
    images, truth, info = sim_camera_views(seed, n_cameras, poses)
    corners, sizes, skipped = find_all_corners(images, (9, 6))
    t0 = time.perf_counter()
    calib = calibrate_cameras(corners, sizes, square=50.0, unit="mm", skipped=skipped)
    took = time.perf_counter() - t0
    t = cameras_against_truth(calib, truth, info["fov_points"])
    out: dict[str, list[float]] = {k: [] for k in CAMERA_FIGURES}
    for name, rows in t["cameras"].items():
        out["fx %"].append(abs(rows["fx"]["error_percent"]))
        out["cx px"].append(abs(rows["cx"]["error"]))
        out["cy px"].append(abs(rows["cy"]["error"]))
        out["k1"].append(abs(rows["k1"]["error"]))
        if name != calib.reference:
            out["rotation deg"].append(rows["rotation_error_deg"])
            out["position mm"].append(rows["position_error"])
    p = t["points_3d"]
    out["3D RMS mm"] = [p["rms"]]
    out["3D RMS rigid mm"] = [p["rms_after_rigid_fit"]]
    out["seconds"] = [took]
    out["views"] = [len(calib.per_view)]
    out["rms px"] = [calib.rms]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=2, help="simulated rigs (seeds 0..N-1)")
    ap.add_argument("--poses", type=int, default=8, help="board poses per chosen pair of cameras")
    args = ap.parse_args()
    res = {}
    for n in (2, 4):
        acc: dict[str, list[float]] = {}
        for seed in range(args.seeds):
            for k, v in one(seed, n, args.poses).items():
                acc.setdefault(k, []).extend(v)
        res[n] = acc
    print(
        f"simulated room, {args.seeds} seed(s), {args.poses} poses per pair of cameras:"
        " median / largest over cameras and seeds"
    )
    print(f"{'figure':18s} {'2 cameras':>22s} {'4 cameras':>22s}")
    for k in ("views", "rms px", "3D RMS mm", "3D RMS rigid mm", *CAMERA_FIGURES, "seconds"):
        cells = []
        for n in (2, 4):
            a = np.array(res[n][k])
            cells.append(f"{np.median(a):10.4g} / {a.max():9.4g}")
        print(f"{k:18s} {cells[0]:>22s} {cells[1]:>22s}")
    print(
        "3D RMS: 400 points in ±250 x ±150 x ±250 mm about the FOV centre, in camera 1's frame;"
        " seconds: corners to calibration"
    )


if __name__ == "__main__":
    main()
