"""How certain a stereo calibration is, and whether a difference is more than that.

:func:`stereo_covariance` propagates the corner noise through the two steps of
the stereo case of :func:`vts_hw.vision.calibration.calibrate_cameras` (each camera's intrinsics from its own views,
then the stereo rotation and translation with those intrinsics fixed): to first order every
estimate is a linear map of the corner residuals, built from the Jacobians of the reprojection
at the solution (the board poses eliminated by their Schur complements); the residual variance
of each camera's fit scales it. The intrinsics' standard deviations are then those OpenCV's
calibrateCameraExtended reports; the stereo ones include how an uncertain principal point or
focal length leaks into the rotation and translation, which a fit with fixed intrinsics alone
would not show.

:func:`differences`, :func:`compare_pair` and :func:`compare_with_truth` say which parameters moved (from a previous
calibration, or away from a known truth) by more than ``K_SIGMA`` combined standard deviations.
Choices and figures: docs/decisions/0024-calibration-uncertainty.md.
"""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np

from vts_hw.errors import DataError

K_SIGMA = 3.0  # a change beyond this many combined standard deviations is reported
DIST_NAMES = ("k1", "k2", "p1", "p2", "k3")
STEREO_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")  # rotation (deg) then translation (unit)


# ------------------------------------------------------------------------- the covariance
def stereo_covariance(obj, left, right, cam1, cam2, R, T, rvecs, tvecs) -> dict[str, Any]:
    """Standard deviations of a stereo calibration, as stored in the file under 'uncertainty'.

    ``cam1``/``cam2``: (K, d, fitted distortion names, rvecs, tvecs of that camera's own fit);
    ``rvecs``/``tvecs``: each view's board pose in camera 1's frame from the stereo fit. The
    rotation's uncertainty is that of a small rotation ``rx, ry, rz`` (degrees, about camera 2's
    axes) applied to ``R``; ``stereo_cov`` is the 6 × 6 covariance of (rx, ry, rz, tx, ty, tz).
    """
    obj = [np.asarray(X, float).reshape(-1, 3) for X in obj]
    uv = [[np.asarray(c, float).reshape(-1) for c in side] for side in (left, right)]
    cams = [_Camera(*c[:3]) for c in (cam1, cam2)]
    n_v = len(obj)
    sizes = [X.size // 3 * 2 for X in obj]  # coordinates per view and camera
    offs = np.cumsum([0] + [2 * s for s in sizes])  # view i: camera 1 rows, then camera 2 rows
    n_rows = int(offs[-1])
    out: dict[str, Any] = {"k_sigma": K_SIGMA}
    # step 1: each camera's intrinsics = -A_c r over that camera's rows
    n_th = [c.n for c in cams]
    A = np.zeros((sum(n_th), n_rows))
    var = np.zeros(n_rows)
    for ci, (c, fit) in enumerate(zip(cams, (cam1, cam2))):
        rows = [np.arange(offs[i] + ci * sizes[i], offs[i] + (ci + 1) * sizes[i]) for i in range(n_v)]
        blocks = []
        for i in range(n_v):
            v0 = np.r_[np.ravel(fit[3][i]), np.ravel(fit[4][i])]

            def resid(th, v, i=i, c=c, ci=ci):
                K, d = c.matrices(th)
                return cv2.projectPoints(obj[i], v[:3], v[3:], K, d)[0].ravel() - uv[ci][i]

            r0 = resid(c.params, v0)
            blocks.append(
                (
                    r0,
                    _jacobian(lambda th, v0=v0: resid(th, v0), c.params, c.steps()),
                    _jacobian(lambda v, c=c: resid(c.params, v), v0, _pose_steps(v0)),
                )
            )
        infl, rss = _influence(blocks)
        dof = sum(r.size for r, _, _ in blocks) - c.n - 6 * n_v
        if dof <= 0:
            raise DataError("too few corners to estimate the calibration's uncertainty.")
        s2 = rss / dof
        lo = sum(n_th[:ci])
        for i in range(n_v):
            A[lo : lo + c.n, rows[i]] = infl[i]
            var[rows[i]] = s2
        cov_c = s2 * sum(m @ m.T for m in infl)
        out[f"camera{ci + 1}"] = {n: float(math.sqrt(max(cov_c[j, j], 0.0))) for j, n in enumerate(c.names)}
        out[f"sigma_px_camera{ci + 1}"] = math.sqrt(s2)
    # step 2: the stereo parameters with the intrinsics fixed: s = -E (r - J_th A r)
    R = np.asarray(R, float)
    T = np.asarray(T, float).ravel()
    th0 = np.r_[cams[0].params, cams[1].params]
    blocks, J_th = [], np.zeros((n_rows, th0.size))
    for i in range(n_v):
        u = np.r_[uv[0][i], uv[1][i]]
        v0 = np.r_[np.ravel(rvecs[i]), np.ravel(tvecs[i])]

        def pair_resid(th, st, v, i=i, u=u):
            return _project_pair(cams, obj[i], th, st, v, R) - u

        st0 = np.r_[np.zeros(3), T]
        r0 = pair_resid(th0, st0, v0)
        blocks.append(
            (
                r0,
                _jacobian(lambda st, v0=v0: pair_resid(th0, st, v0), st0, _stereo_steps(T)),
                _jacobian(lambda v, st0=st0: pair_resid(th0, st0, v), v0, _pose_steps(v0)),
            )
        )
        J_th[offs[i] : offs[i + 1]] = _jacobian(
            lambda th, st0=st0, v0=v0: pair_resid(th, st0, v0), th0, np.r_[cams[0].steps(), cams[1].steps()]
        )
    E = np.hstack(_influence(blocks)[0])
    M = E - (E @ J_th) @ A
    st = (M * var) @ M.T
    scale = np.r_[np.full(3, 180.0 / math.pi), np.ones(3)]
    st = st * np.outer(scale, scale)
    out["stereo"] = {name: float(math.sqrt(max(st[j, j], 0.0))) for j, name in enumerate(STEREO_NAMES)}
    out["stereo"]["baseline"] = _directional_sd(st[3:, 3:], T)
    out["stereo_cov"] = st.tolist()
    return out


def _influence(blocks):
    """For a least-squares problem of global parameters g and per-view parameters: the matrices
    G_i with δg = -Σ G_i r_i (first order), and the residual sum of squares. ``blocks``: per view
    (residuals r_i, Jacobian wrt g, Jacobian wrt the view's own parameters)."""
    S = 0.0
    parts = []
    rss = 0.0
    for r, Jg, Jv in blocks:
        rss += float(r @ r)
        W = np.linalg.solve(Jv.T @ Jv, Jv.T)  # (6 × rows): the view's own least squares
        P = Jg.T - (Jg.T @ Jv) @ W  # J_gᵀ after the view's parameters are projected out
        S = S + P @ Jg
        parts.append(P)
    S_inv = _inverse(S)
    return [S_inv @ P for P in parts], rss


def _inverse(S):
    """Inverse of a normal matrix whose parameters differ in scale by many orders of magnitude
    (px against k3): equilibrated first, so that a parameter the data hardly determine gets a
    large variance instead of being cut off as in a plain pseudo-inverse."""
    scale = 1.0 / np.sqrt(np.maximum(np.diag(S), 1e-300))
    Sn = S * np.outer(scale, scale)
    try:
        inv = np.linalg.inv(Sn)
    except np.linalg.LinAlgError:
        inv = np.linalg.pinv(Sn, rcond=1e-13)
    return inv * np.outer(scale, scale)


class _Camera:
    """Intrinsics as a parameter vector (fx, fy, cx, cy, then the fitted distortion terms)."""

    def __init__(self, K, d, free):
        self.K = np.asarray(K, float)
        self.d = np.zeros(max(5, np.size(d)))
        self.d[: np.size(d)] = np.ravel(d)
        self.free = [DIST_NAMES.index(f) for f in free]
        self.names = ["fx", "fy", "cx", "cy", *free]
        self.n = len(self.names)
        self.params = np.r_[self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2], self.d[self.free]]

    def matrices(self, p):
        K = np.array([[p[0], 0.0, p[2]], [0.0, p[1], p[3]], [0.0, 0.0, 1.0]])
        d = self.d.copy()
        d[self.free] = p[4:]
        return K, d

    def steps(self):
        return np.r_[np.full(4, 1e-3), np.full(len(self.free), 1e-6)]


def _project_pair(cams, X, th, st, v, R0):
    """Both cameras' pixels of board points X at pose v (camera 1's frame), the stereo pose
    being a small rotation st[:3] applied to R0 and the translation st[3:]."""
    K1, d1 = cams[0].matrices(th[: cams[0].n])
    K2, d2 = cams[1].matrices(th[cams[0].n :])
    R = cv2.Rodrigues(st[:3])[0] @ R0
    Rv = cv2.Rodrigues(v[:3])[0]
    uv1 = cv2.projectPoints(X, v[:3], v[3:], K1, d1)[0]
    uv2 = cv2.projectPoints(X, cv2.Rodrigues(R @ Rv)[0], R @ v[3:] + st[3:], K2, d2)[0]
    return np.r_[uv1.ravel(), uv2.ravel()]


def _pose_steps(v):
    return np.r_[np.full(3, 1e-6), 1e-6 * (1 + np.abs(v[3:]))]


def _stereo_steps(T):
    return np.r_[np.full(3, 1e-7), 1e-6 * (1 + np.abs(T))]


def _jacobian(f, x0, h):
    cols = []
    for j in range(len(x0)):
        e = np.zeros_like(x0)
        e[j] = h[j]
        cols.append((f(x0 + e) - f(x0 - e)) / (2 * h[j]))
    return np.column_stack(cols)


# ------------------------------------------------------------------------- judging a difference
def rotation_vector_deg(rot) -> np.ndarray:
    """The rotation vector (degrees) of a rotation matrix."""
    return np.degrees(cv2.Rodrigues(np.asarray(rot, float))[0].ravel())


def _sd(unc, cam, name):
    if not unc:
        return None
    return unc.get(f"camera{cam}", {}).get(name)


def _directional_sd(cov, vec) -> float:
    """Standard deviation of a 3-vector estimate along the direction of ``vec``."""
    n = float(np.linalg.norm(vec))
    if n == 0:
        return float(np.sqrt(np.trace(cov) / 3))
    u = np.asarray(vec, float) / n
    return float(np.sqrt(max(u @ cov @ u, 0.0)))


def _stereo_block(unc, rows):
    if not unc or "stereo_cov" not in unc:
        return None
    return np.asarray(unc["stereo_cov"], float)[rows, rows]


def differences(new, old, new_unc, old_unc, same_unit: bool = True, old_exact: bool = False) -> list[dict[str, Any]]:
    """Every judged difference new − old with its combined standard deviation.

    Each row: ``parameter`` (``fx1``, ``k1 of camera 2``, ``rotation``, ``translation``), ``change``,
    ``sd`` (sqrt of the sum of both variances; when ``old_unc`` is None, √2 × the new one, as if
    the other were as certain; with ``old_exact`` (a known truth) the new one's alone),
    ``ratio`` = |change| / sd, ``unit``. Parameters the new calibration has no uncertainty for
    (not fitted) are left out.
    """
    if not new_unc:
        return []
    rows = []

    def comb(a, b):
        if old_exact:
            return a
        return math.sqrt(a * a + (b * b if b is not None else a * a))

    def comb_dir(cov_new, cov_old, vec):
        a = _directional_sd(cov_new, vec)
        if old_exact:
            return a
        return math.hypot(a, _directional_sd(cov_new if cov_old is None else cov_old, vec))

    for cam, k_new, k_old, d_new, d_old in ((1, new.K1, old.K1, new.d1, old.d1), (2, new.K2, old.K2, new.d2, old.d2)):
        vals = {
            "fx": (k_new[0, 0], k_old[0, 0]),
            "fy": (k_new[1, 1], k_old[1, 1]),
            "cx": (k_new[0, 2], k_old[0, 2]),
            "cy": (k_new[1, 2], k_old[1, 2]),
        }
        for i, name in enumerate(DIST_NAMES):
            a = float(np.ravel(d_new)[i]) if np.size(d_new) > i else 0.0
            b = float(np.ravel(d_old)[i]) if np.size(d_old) > i else 0.0
            vals[name] = (a, b)
        for name, (a, b) in vals.items():
            sd_new = _sd(new_unc, cam, name)
            if sd_new is None:
                continue
            sd = comb(sd_new, _sd(old_unc, cam, name))
            unit = "px" if name in ("fx", "fy", "cx", "cy") else ""
            label = f"{name}{cam}" if unit else f"{name} of camera {cam}"
            rows.append(_row(label, float(a - b), sd, unit))
    rot = rotation_vector_deg(np.asarray(new.R) @ np.asarray(old.R).T)
    cov_r = _stereo_block(new_unc, slice(0, 3))
    if cov_r is not None:
        sd = comb_dir(cov_r, _stereo_block(old_unc, slice(0, 3)), rot)
        rows.append(_row("rotation", float(np.linalg.norm(rot)), sd, "deg"))
    cov_t = _stereo_block(new_unc, slice(3, 6))
    if same_unit and cov_t is not None:
        dt = np.ravel(new.T) - np.ravel(old.T)
        sd = comb_dir(cov_t, _stereo_block(old_unc, slice(3, 6)), dt)
        rows.append(_row("translation", float(np.linalg.norm(dt)), sd, new.unit))
    return rows


def _row(name, change, sd, unit):
    ratio = abs(change) / sd if sd and sd > 0 else (math.inf if change else 0.0)
    return {"parameter": name, "change": change, "sd": sd, "ratio": ratio, "unit": unit}


def beyond(rows: list[dict[str, Any]], k: float = K_SIGMA) -> list[dict[str, Any]]:
    """The rows whose change exceeds ``k`` combined standard deviations."""
    return [r for r in rows if r["ratio"] > k]


def warning_text(row: dict[str, Any], what: str = "moved", sd_name: str = "combined standard deviation") -> str:
    """One line: 'WARNING: cx1 moved by -18.8 px, 3.4 x its combined standard deviation 5.5 px
    (limit 3)'."""
    u = f" {row['unit']}" if row["unit"] else ""
    return (
        f"WARNING: {row['parameter']} {what} by {row['change']:+.4g}{u}, {row['ratio']:.1f} x its"
        f" {sd_name} {row['sd']:.2g}{u} (limit {K_SIGMA:g})"
    )


def compare_with_truth(calib, truth, names=("cam1", "cam2")) -> dict[str, Any]:
    """How ``calib`` compares with the true cameras ``truth`` (both calibrations whose first two cameras are compared as a pair, the
    same unit): per camera fx, fy, cx, cy, k1 (estimated, true, error, sd), the stereo rotation
    and the baseline; ``judged`` every fitted parameter's error against the fit's own standard
    deviation and ``warnings`` one line for each beyond K_SIGMA of them."""
    unc = calib.uncertainty or {}
    out: dict[str, Any] = {"cameras": {}}
    for i, (name, k_est, k_true, d_est, d_true) in enumerate(
        ((names[0], calib.K1, truth.K1, calib.d1, truth.d1), (names[1], calib.K2, truth.K2, calib.d2, truth.d2)),
        start=1,
    ):
        rows = {}
        items = {
            "fx": (k_est[0, 0], k_true[0, 0]),
            "fy": (k_est[1, 1], k_true[1, 1]),
            "cx": (k_est[0, 2], k_true[0, 2]),
            "cy": (k_est[1, 2], k_true[1, 2]),
            "k1": (np.ravel(d_est)[0], np.ravel(d_true)[0]),
        }
        for key, (est, true) in items.items():
            rows[key] = {
                "estimated": float(est),
                "true": float(true),
                "error": float(est - true),
                "sd": _sd(unc, i, key),
            }
            if key in ("fx", "fy"):
                rows[key]["error_percent"] = 100.0 * rows[key]["error"] / float(true)
        out["cameras"][name] = rows
    rot_err = rotation_vector_deg(np.asarray(calib.R) @ np.asarray(truth.R).T)
    t_true = np.ravel(truth.T)
    base_true = float(np.linalg.norm(t_true))
    base_err = calib.baseline - base_true
    cos = float(np.dot(np.ravel(calib.T), t_true) / (calib.baseline * base_true))
    cov = np.asarray(unc["stereo_cov"]) if "stereo_cov" in unc else None
    out["rotation"] = {
        "estimated_deg": float(np.linalg.norm(rotation_vector_deg(calib.R))),
        "true_deg": float(np.linalg.norm(rotation_vector_deg(truth.R))),
        "error_deg": float(np.linalg.norm(rot_err)),
        "sd_deg": None if cov is None else _directional_sd(cov[:3, :3], rot_err),
    }
    out["baseline"] = {
        "estimated": calib.baseline,
        "true": base_true,
        "error": base_err,
        "error_percent": 100.0 * base_err / base_true,
        "unit": calib.unit,
        "sd": unc.get("stereo", {}).get("baseline"),
        "direction_error_deg": float(np.degrees(np.arccos(min(1.0, cos)))),
    }
    judged = differences(calib, truth, unc, None, old_exact=True)
    out["judged"] = judged
    out["warnings"] = [warning_text(r, "differs from the truth", "standard deviation") for r in beyond(judged)]
    return out


def compare_pair(new, old) -> dict[str, Any]:
    """Change from ``old`` to ``new`` (this minus previous) of their first two cameras as a pair
    (anything with ``K1, d1, K2, d2, R, T, baseline, unit, uncertainty``).

    Focal lengths and principal points in px per camera; ``rotation_deg`` is the angle of the
    rotation R · R_prevᵀ; ``translation`` is |T − T_prev| and ``baseline`` the change of |T|,
    both in ``unit`` (None when the two calibrations use different units). ``judged``: each
    fitted parameter's change against its combined standard deviation (:func:`differences`), and
    ``warnings`` one line for each beyond K_SIGMA of them.
    """
    out: dict[str, Any] = {}
    for cam, (k_new, k_old) in (("1", (new.K1, old.K1)), ("2", (new.K2, old.K2))):
        out[f"fx{cam}"] = float(k_new[0, 0] - k_old[0, 0])
        out[f"fy{cam}"] = float(k_new[1, 1] - k_old[1, 1])
        out[f"cx{cam}"] = float(k_new[0, 2] - k_old[0, 2])
        out[f"cy{cam}"] = float(k_new[1, 2] - k_old[1, 2])
    out["rotation_deg"] = rotation_angle_deg(np.asarray(new.R) @ np.asarray(old.R).T)
    same_unit = new.unit == old.unit
    out["translation"] = float(np.linalg.norm(np.ravel(new.T) - np.ravel(old.T))) if same_unit else None
    out["baseline"] = (new.baseline - old.baseline) if same_unit else None
    out["unit"] = new.unit if same_unit else None
    rows = differences(new, old, new.uncertainty, old.uncertainty, same_unit)
    out["judged"] = rows
    out["previous_has_uncertainty"] = old.uncertainty is not None
    out["warnings"] = [warning_text(r, "moved") for r in beyond(rows)]
    return out


def rotation_angle_deg(rot: np.ndarray) -> float:
    """Angle (degrees) of a rotation matrix, from its Rodrigues vector (precise for small angles)."""
    vec, _ = cv2.Rodrigues(np.asarray(rot, dtype=float))
    return float(np.degrees(np.linalg.norm(vec)))


# ------------------------------------------------------------------------- in the file
def check_pair_uncertainty(path, unc, key: str = "uncertainty") -> dict[str, Any] | None:
    """A pair's ``stereo`` standard deviations and ``stereo_cov`` as a file holds them under
    ``key``, checked (None when absent); DataError naming the file and the key."""
    if unc is None:
        return None

    def bad(sub):
        return DataError(f"{path}: key '{key}.{sub}' must hold finite, non-negative standard deviations.")

    if not isinstance(unc, dict):
        raise bad("*")
    sds = unc.get("stereo")
    if (
        not isinstance(sds, dict)
        or not all(_finite(v) and v >= 0 for v in sds.values())
        or not {"rx", "ry", "rz", "baseline"} <= set(sds)
    ):
        raise bad("stereo")
    return {"stereo": dict(sds), "stereo_cov": _stereo_cov(unc, bad).tolist()}


def _stereo_cov(unc: dict, bad) -> np.ndarray:
    """``unc['stereo_cov']`` as a finite 6 x 6 array; ``bad('stereo_cov')`` raised otherwise."""
    try:
        cov = np.asarray(unc.get("stereo_cov"), dtype=float)
    except (TypeError, ValueError):
        raise bad("stereo_cov") from None
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        raise bad("stereo_cov")
    return cov


def optional_keys(path, data: dict[str, Any]) -> dict[str, Any]:
    """'distortion_model' and 'uncertainty' of a calibration file, checked; files written before
    they existed load with none (the change from them is then judged with the new file's own
    uncertainty only)."""
    out: dict[str, Any] = {}
    model = data.get("distortion_model")
    if model is not None:
        if not isinstance(model, dict) or not all(isinstance(v, dict) for v in model.values()):
            raise DataError(f"{path}: key 'distortion_model' must map camera1/camera2 to their model.")
        out["distortion_model"] = model
    unc = data.get("uncertainty")
    if unc is not None:

        def bad(key):
            return DataError(f"{path}: key 'uncertainty.{key}' must hold finite, non-negative standard deviations.")

        if not isinstance(unc, dict):
            raise bad("*")
        for key in ("camera1", "camera2", "stereo"):
            sds = unc.get(key)
            if not isinstance(sds, dict) or not all(_finite(v) and v >= 0 for v in sds.values()):
                raise bad(key)
        _stereo_cov(unc, bad)
        out["uncertainty"] = unc
    return out


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
