"""How an N-camera calibration differs from the previous one, and from a known truth.

:func:`compare_cameras`: per camera (matched by name, else by order) the change of fx, fy, cx,
cy, k1, of its orientation (degrees) and of its position (in the unit) in the reference
camera's frame; each intrinsic change judged against the combined standard deviation as in
decision 0024 (a warning beyond ``K_SIGMA``). :func:`against_truth`: the same figures as
errors against true cameras, and the 3D error of points spread over the field of view,
projected exactly by the true cameras and triangulated with the calibrated ones.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from vts_hw.vision.calibration_io import CameraCalibration
from vts_hw.vision.calibration_uncertainty import K_SIGMA, rotation_angle_deg
from vts_hw.vision.registration import kabsch
from vts_hw.vision.triangulate import triangulate

JUDGED = ("fx", "fy", "cx", "cy", "k1")


def _pairs(new: CameraCalibration, old: CameraCalibration) -> tuple[list[tuple[Any, Any]], str]:
    common = [n for n in new.names if n in old.names]
    if len(common) >= 2:
        return [(new.camera(n), old.camera(n)) for n in common], "name"
    return list(zip(new.camera_fits, old.camera_fits)), "order"


def _values(cam) -> dict[str, float]:
    return {
        "fx": cam.K[0, 0],
        "fy": cam.K[1, 1],
        "cx": cam.K[0, 2],
        "cy": cam.K[1, 2],
        "k1": float(cam.d[0]) if cam.d.size else 0.0,
    }


def _judge(name: str, key: str, change: float, sd_new, sd_old, exact_old: bool) -> dict[str, Any] | None:
    if sd_new is None:
        return None
    sd = sd_new if exact_old else math.hypot(sd_new, sd_old if sd_old is not None else sd_new)
    ratio = abs(change) / sd if sd > 0 else (math.inf if change else 0.0)
    return {
        "parameter": f"{key} of {name}",
        "change": float(change),
        "sd": sd,
        "ratio": ratio,
        "unit": "" if key == "k1" else "px",
    }


def _warning(row: dict[str, Any], what: str, sd_name: str) -> str:
    u = f" {row['unit']}" if row["unit"] else ""
    return (
        f"WARNING: {row['parameter']} {what} by {row['change']:+.4g}{u}, {row['ratio']:.1f} x its"
        f" {sd_name} {row['sd']:.2g}{u} (limit {K_SIGMA:g})"
    )


def compare_cameras(new: CameraCalibration, old: CameraCalibration) -> dict[str, Any]:
    """This minus previous, per camera (see the module docstring)."""
    pairs, matched = _pairs(new, old)
    if old.method.startswith("stereo calibration file"):  # its cameras have no names of their own
        pairs, matched = list(zip(new.camera_fits, old.camera_fits)), "order (a stereo file)"
    same_unit = new.unit == old.unit
    out: dict[str, Any] = {"matched_by": matched, "unit": new.unit if same_unit else None, "cameras": {}}
    judged = []
    for a, b in pairs:
        va, vb = _values(a), _values(b)
        change = {k: float(va[k] - vb[k]) for k in JUDGED}
        row: dict[str, float | None] = {**change, "rotation_deg": rotation_angle_deg(a.R @ b.R.T)}
        row["position"] = float(np.linalg.norm(a.center - b.center)) if same_unit else None
        out["cameras"][a.name] = row
        for k in JUDGED:
            j = _judge(a.name, k, change[k], (a.sd or {}).get(k), (b.sd or {}).get(k), False)
            if j:
                judged.append(j)
    out["judged"] = judged
    out["previous_has_uncertainty"] = all(b.sd for _, b in pairs)
    out["warnings"] = [_warning(r, "moved", "combined standard deviation") for r in judged if r["ratio"] > K_SIGMA]
    return out


def visible(cam, points: np.ndarray) -> np.ndarray:
    """Which points (n × 3, the camera's frame of reference) project inside camera ``cam``'s image."""
    pc = points @ cam.R.T + cam.t
    uv = cam.project(points)
    w, h = cam.image_size
    return (pc[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)


def against_truth(calib: CameraCalibration, truth: CameraCalibration, points: np.ndarray) -> dict[str, Any]:
    """Errors of ``calib`` against the true cameras ``truth`` (the same frame: the reference camera's,
    the same unit), and the 3D error of ``points`` (n × 3 in that frame) seen by two or more true
    cameras: projected exactly by them, triangulated with the calibrated cameras (all that see each)."""
    out: dict[str, Any] = {"cameras": {}}
    judged = []
    for c in calib.camera_fits:
        t = truth.camera(c.name)
        fitted, true = _values(c), _values(t)
        rows: dict[str, Any] = {}
        for k in JUDGED:
            rows[k] = {
                "estimated": float(fitted[k]),
                "true": float(true[k]),
                "error": float(fitted[k] - true[k]),
                "sd": (c.sd or {}).get(k),
            }
            j = _judge(c.name, k, rows[k]["error"], rows[k]["sd"], None, True)
            if j:
                judged.append(j)
        rows["fx"]["error_percent"] = 100 * rows["fx"]["error"] / true["fx"]
        rows["rotation_error_deg"] = rotation_angle_deg(c.R @ t.R.T)
        rows["position_error"] = float(np.linalg.norm(c.center - t.center))
        out["cameras"][c.name] = rows
    pts = np.asarray(points, float).reshape(-1, 3)
    true_cams = [truth.camera(n) for n in calib.names]
    seen = np.array([visible(t, pts) for t in true_cams])  # cameras × points
    est = np.full(pts.shape, np.nan)
    for mask in {tuple(col) for col in seen.T if col.sum() >= 2}:
        idx = np.flatnonzero((seen.T == mask).all(axis=1))
        which = [i for i, m in enumerate(mask) if m]
        tri = triangulate([calib.cameras()[i] for i in which], [true_cams[i].project(pts[idx]) for i in which])
        est[idx] = tri.points
    ok = np.isfinite(est[:, 0])
    err = np.linalg.norm(est[ok] - pts[ok], axis=1)
    fit = kabsch(est[ok], pts[ok]).apply(est[ok]) if ok.sum() >= 3 else est[ok]
    rigid = np.linalg.norm(fit - pts[ok], axis=1)
    out["points_3d"] = {
        "n": int(ok.sum()),
        "n_given": len(pts),
        "unit": calib.unit,
        "cameras_per_point": {str(k): int(np.sum(seen.sum(axis=0)[ok] == k)) for k in range(2, len(true_cams) + 1)},
        "rms": float(np.sqrt(np.mean(err**2))) if ok.any() else None,
        "max": float(err.max()) if ok.any() else None,
        "rms_after_rigid_fit": float(np.sqrt(np.mean(rigid**2))) if ok.any() else None,
    }
    out["judged"] = judged
    out["warnings"] = [
        _warning(r, "differs from the truth", "standard deviation") for r in judged if r["ratio"] > K_SIGMA
    ]
    return out
