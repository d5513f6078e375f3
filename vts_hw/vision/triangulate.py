"""3D marker positions from 2D detections in two or more calibrated cameras.

Cameras follow the OpenCV convention (world -> camera: ``x_c = R @ x_w + t``; pixel
coordinates through ``K`` and the distortion ``dist`` = k1, k2, p1, p2[, k3...]). Any object
with ``K``, ``dist``, ``R`` and ``t`` attributes is accepted (e.g. the simulator's
``CameraModel``); :class:`PinholeCamera` is a minimal one.

* :func:`undistort` — pixels to normalized (ideal, z = 1) image coordinates.
* :func:`match_epipolar` — correspondence between two cameras' detections by the epipolar
  constraint, one-to-one (Hungarian), reporting ambiguous and unmatched points, never guessing.
* :func:`triangulate` — linear DLT on undistorted points, then per-point nonlinear refinement
  of the reprojection error in pixels through the full camera model.

See docs/decisions/0013-triangulation-and-registration.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

# scipy.optimize (0.3 s to load) where it is used: a command that only reads a calibration file
# (calibration_io's PinholeCamera) says a bad input before it loads (tests/integration/test_report_door.py)

__all__ = [
    "PinholeCamera",
    "as_camera",
    "undistort",
    "fundamental_matrix",
    "epipolar_distances",
    "Matches",
    "AmbiguousPoint",
    "match_epipolar",
    "Triangulation",
    "triangulate",
    "reprojection_errors",
    "predicted_covariance",
]

_UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)


@dataclass(frozen=True, eq=False)
class PinholeCamera:
    """A calibrated camera: intrinsics ``K`` (3x3), distortion ``dist`` (OpenCV order) and the
    world -> camera pose ``R`` (3x3), ``t`` (3,), millimetres."""

    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    name: str = ""

    def __post_init__(self):
        object.__setattr__(self, "K", np.asarray(self.K, float).reshape(3, 3))
        object.__setattr__(self, "dist", np.asarray(self.dist, float).ravel())
        object.__setattr__(self, "R", np.asarray(self.R, float).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, float).ravel())

    @property
    def rvec(self) -> np.ndarray:
        return cv2.Rodrigues(self.R)[0].ravel()

    @property
    def center(self) -> np.ndarray:
        """Optical centre in world coordinates."""
        return -self.R.T @ self.t

    def project(self, points_world) -> np.ndarray:
        """Pixel coordinates (Nx2) of world points (Nx3), distortion included."""
        pts = np.asarray(points_world, float).reshape(-1, 1, 3)
        uv, _ = cv2.projectPoints(pts, self.rvec, self.t, self.K, self.dist)
        return uv.reshape(-1, 2)


def as_camera(obj: Any) -> PinholeCamera:
    """A :class:`PinholeCamera` from any object with ``K``, ``dist``, ``R``, ``t`` (itself if one)."""
    if isinstance(obj, PinholeCamera):
        return obj
    return PinholeCamera(obj.K, obj.dist, obj.R, obj.t, str(getattr(obj, "name", "")))


def _pts(pts) -> np.ndarray:
    return np.asarray(pts, float).reshape(-1, 2)


def undistort(cam, pts_px) -> np.ndarray:
    """Normalized image coordinates (Nx2, the ideal pinhole at z = 1) of pixel points (Nx2).

    ``cv2.undistortPoints`` with a tight iteration limit, so that the round trip with
    ``project`` is exact to ~1e-12 for the mild distortion of these lenses.
    """
    cam = as_camera(cam)
    pts = _pts(pts_px)
    if len(pts) == 0:
        return np.zeros((0, 2))
    out = cv2.undistortPoints(pts.reshape(-1, 1, 2), cam.K, cam.dist, None, None, None, _UNDISTORT_CRITERIA)
    return out.reshape(-1, 2)


def _ideal_px(cam: PinholeCamera, pts_px) -> np.ndarray:
    """Undistorted pixel coordinates (distortion removed, ``K`` kept): an ideal pinhole's."""
    n = undistort(cam, pts_px)
    return n @ cam.K[:2, :2].T + cam.K[:2, 2]


def _skew(v) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def fundamental_matrix(cam_a, cam_b) -> np.ndarray:
    """F with ``x_b^T F x_a = 0`` for ideal (undistorted) pixel coordinates of the same point."""
    a, b = as_camera(cam_a), as_camera(cam_b)
    R_ab = b.R @ a.R.T
    t_ab = b.t - R_ab @ a.t
    E = _skew(t_ab) @ R_ab
    F = np.linalg.inv(b.K).T @ E @ np.linalg.inv(a.K)
    return F / np.linalg.norm(F)


def _line_distance(lines: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """|l . x| / |l[:2]| for every line (rows of ``lines``, Nx3) against every point (Mx2): NxM."""
    num = np.abs(lines[:, :2] @ pts.T + lines[:, 2:3])
    return num / np.linalg.norm(lines[:, :2], axis=1, keepdims=True)


def epipolar_distances(cam_a, pts_a, cam_b, pts_b) -> np.ndarray:
    """Symmetric epipolar distance (Na x Nb), pixels: for each pair the larger of the distance
    of b's point to a's epipolar line in image b and of a's point to b's line in image a.
    Computed on undistorted pixel coordinates (distortion removed, each camera's own K)."""
    a, b = as_camera(cam_a), as_camera(cam_b)
    xa, xb = _ideal_px(a, pts_a), _ideal_px(b, pts_b)
    if len(xa) == 0 or len(xb) == 0:
        return np.zeros((len(xa), len(xb)))
    F = fundamental_matrix(a, b)
    ha = np.column_stack([xa, np.ones(len(xa))])
    hb = np.column_stack([xb, np.ones(len(xb))])
    d_in_b = _line_distance(ha @ F.T, xb)  # lines F x_a in image b
    d_in_a = _line_distance(hb @ F, xa).T  # lines F^T x_b in image a
    return np.maximum(d_in_a, d_in_b)


@dataclass(frozen=True)
class AmbiguousPoint:
    """A point withheld from matching: ``side`` ("a" or "b"), its index, the indices of the
    other side's points within the gate (best first) and their epipolar distances (px)."""

    side: str
    index: int
    candidates: tuple[int, ...]
    distances_px: tuple[float, ...]


@dataclass
class Matches:
    """Result of :func:`match_epipolar`.

    ``pairs``: (index in a, index in b) accepted one-to-one matches, with ``distances_px``.
    ``ambiguous``: every point of a group of mutually competing candidates (see
    :func:`match_epipolar`) — none of them is matched. ``unmatched_a`` / ``unmatched_b``:
    points with no candidate within the gate (or left over by the assignment).
    """

    pairs: list[tuple[int, int]] = field(default_factory=list)
    distances_px: list[float] = field(default_factory=list)
    ambiguous: list[AmbiguousPoint] = field(default_factory=list)
    unmatched_a: list[int] = field(default_factory=list)
    unmatched_b: list[int] = field(default_factory=list)

    @property
    def index_a(self) -> np.ndarray:
        return np.array([i for i, _ in self.pairs], dtype=int)

    @property
    def index_b(self) -> np.ndarray:
        return np.array([j for _, j in self.pairs], dtype=int)


def _is_ambiguous(d_sorted: np.ndarray, ratio: float, min_sep_px: float) -> bool:
    """Two or more in-gate distances (sorted) whose best is not clearly better than the next."""
    if len(d_sorted) < 2:
        return False
    best, second = d_sorted[0], d_sorted[1]
    return bool(second < ratio * best or second - best < min_sep_px)


def match_epipolar(
    cam_a, pts_a, cam_b, pts_b, max_px: float = 2.0, ratio: float = 2.0, min_sep_px: float = 0.0
) -> Matches:
    """Match detections of camera a with those of camera b by the epipolar constraint.

    A pair is a candidate when its symmetric epipolar distance (:func:`epipolar_distances`)
    is at most ``max_px``. A point with two or more candidates is *ambiguous* unless its best
    is clearly separated from the runner-up: ``second >= ratio * best`` and
    ``second - best >= min_sep_px``. The default ``min_sep_px = 0`` is the ratio test alone;
    set it to a few times the detection noise (or to ``max_px``: any two in-gate candidates
    are then ambiguous) when the noise is known. The ambiguity spreads over the
    connected group of candidates (the bipartite graph of in-gate pairs): every point of that
    group is reported in ``Matches.ambiguous`` with its candidates and none is matched.
    The other points are assigned one-to-one by the Hungarian method on the distance;
    points with no in-gate partner are reported unmatched.
    """
    a, b = as_camera(cam_a), as_camera(cam_b)
    pa, pb = _pts(pts_a), _pts(pts_b)
    na, nb = len(pa), len(pb)
    sep = float(min_sep_px)
    D = epipolar_distances(a, pa, b, pb)
    gate = D <= max_px

    def candidates(row: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        idx = np.flatnonzero(mask)
        order = np.argsort(row[idx], kind="stable")
        return idx[order], row[idx][order]

    cand_a = [candidates(D[i], gate[i]) for i in range(na)]
    cand_b = [candidates(D[:, j], gate[:, j]) for j in range(nb)]
    seeds = [("a", i) for i in range(na) if _is_ambiguous(cand_a[i][1], ratio, sep)]
    seeds += [("b", j) for j in range(nb) if _is_ambiguous(cand_b[j][1], ratio, sep)]

    # Spread each ambiguity over its connected group of in-gate candidates.
    withheld: set[tuple[str, int]] = set()
    stack = list(seeds)
    while stack:
        node = stack.pop()
        if node in withheld:
            continue
        withheld.add(node)
        side, k = node
        others = cand_a[k][0] if side == "a" else cand_b[k][0]
        other_side = "b" if side == "a" else "a"
        stack.extend((other_side, int(o)) for o in others if (other_side, int(o)) not in withheld)

    out = Matches()
    for side, k in sorted(withheld):
        idx, dist = cand_a[k] if side == "a" else cand_b[k]
        out.ambiguous.append(AmbiguousPoint(side, k, tuple(int(x) for x in idx), tuple(float(x) for x in dist)))

    free_a = [i for i in range(na) if ("a", i) not in withheld]
    free_b = [j for j in range(nb) if ("b", j) not in withheld]
    matched_a: set[int] = set()
    matched_b: set[int] = set()
    if free_a and free_b:
        sub = D[np.ix_(free_a, free_b)]
        big = max_px * 1e6 + 1.0
        cost = np.where(sub <= max_px, sub, big)
        from scipy.optimize import linear_sum_assignment

        rows, cols = linear_sum_assignment(cost)
        for r, c in sorted(zip(rows, cols)):
            if cost[r, c] <= max_px:
                i, j = free_a[r], free_b[c]
                out.pairs.append((i, j))
                out.distances_px.append(float(D[i, j]))
                matched_a.add(i)
                matched_b.add(j)
    out.unmatched_a = [i for i in free_a if i not in matched_a]
    out.unmatched_b = [j for j in free_b if j not in matched_b]
    return out


@dataclass
class Triangulation:
    """Result of :func:`triangulate` (N points).

    ``points``: refined 3D positions (Nx3, mm). ``linear``: the DLT positions before
    refinement. ``rms_px`` / ``linear_rms_px``: per-point reprojection RMS (px) over all
    cameras and both image axes, through the full camera model with distortion.
    ``residuals_px``: per camera, the refined reprojection residuals (Nx2).
    """

    points: np.ndarray
    linear: np.ndarray
    rms_px: np.ndarray
    linear_rms_px: np.ndarray
    residuals_px: list[np.ndarray]

    def __len__(self) -> int:
        return len(self.points)


def _project(cam: PinholeCamera, X: np.ndarray) -> np.ndarray:
    uv, _ = cv2.projectPoints(np.asarray(X, float).reshape(-1, 1, 3), cam.rvec, cam.t, cam.K, cam.dist)
    return uv.reshape(-1, 2)


def reprojection_errors(cams: Sequence, pts: Sequence, points3d) -> list[np.ndarray]:
    """Per camera, the residuals (Nx2, px) of ``project(points3d) - observed``."""
    cams = [as_camera(c) for c in cams]
    return [_project(c, points3d) - _pts(p) for c, p in zip(cams, pts)]


def _rms(residuals: list[np.ndarray]) -> np.ndarray:
    stacked = np.stack(residuals)  # cams x N x 2
    return np.sqrt(np.mean(stacked**2, axis=(0, 2)))


def _dlt(cams: list[PinholeCamera], norm_pts: list[np.ndarray]) -> np.ndarray:
    """Linear triangulation (homogeneous DLT) of normalized image points, any number of cameras.

    World coordinates are centred on the cameras' mean centre and scaled by their mean
    distance to it (1000 mm for a single centre) so that the linear system is well
    conditioned; the result is mapped back.
    """
    centres = np.array([c.center for c in cams])
    origin = centres.mean(axis=0)
    scale = float(np.mean(np.linalg.norm(centres - origin, axis=1))) or 1000.0
    # x_c = R (origin + scale * X') + t  =  scale * (R X' + (R origin + t) / scale)
    Ps = [np.column_stack([c.R, (c.R @ origin + c.t) / scale]) for c in cams]
    n = len(norm_pts[0])
    out = np.empty((n, 3))
    for k in range(n):
        rows = []
        for P, x in zip(Ps, norm_pts):
            u, v = x[k]
            rows.append(u * P[2] - P[0])
            rows.append(v * P[2] - P[1])
        _, _, vt = np.linalg.svd(np.array(rows))
        h = vt[-1]
        out[k] = origin + scale * h[:3] / h[3]
    return out


def triangulate(cams: Sequence, pts: Sequence, refine: bool = True) -> Triangulation:
    """3D points (mm) from their pixel positions in two or more cameras.

    ``cams``: camera objects (K, dist, R, t); ``pts``: for each camera an Nx2 array of pixel
    coordinates, row k of every array being the same point. First the linear DLT on
    undistorted normalized coordinates; then (``refine``) for each point
    ``scipy.optimize.least_squares`` minimising the reprojection error in pixels through the
    full camera model (distortion included), started from the linear solution.
    """
    cams = [as_camera(c) for c in cams]
    pts = [_pts(p) for p in pts]
    if len(cams) < 2 or len(cams) != len(pts):
        raise ValueError("triangulate needs two or more cameras and one Nx2 array per camera")
    n = len(pts[0])
    if any(len(p) != n for p in pts):
        raise ValueError("every camera must give the same number of points")
    if n == 0:
        empty = np.zeros((0, 3))
        return Triangulation(empty, empty, np.zeros(0), np.zeros(0), [np.zeros((0, 2))] * len(cams))
    linear = _dlt(cams, [undistort(c, p) for c, p in zip(cams, pts)])
    lin_res = reprojection_errors(cams, pts, linear)
    refined = linear.copy()
    if refine:
        from scipy.optimize import least_squares

        for k in range(n):
            obs = [p[k] for p in pts]

            def residual(X, obs=obs):
                return np.concatenate([_project(c, X)[0] - o for c, o in zip(cams, obs)])

            sol = least_squares(
                residual, linear[k], method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15, x_scale=np.full(3, 1.0)
            )
            # Keep the linear point if refinement did not help (it never should).
            if np.sum(sol.fun**2) <= np.sum(residual(linear[k]) ** 2):
                refined[k] = sol.x
    res = reprojection_errors(cams, pts, refined)
    return Triangulation(refined, linear, _rms(res), _rms(lin_res), res)


def predicted_covariance(cams: Sequence, points3d, sigma_px: float) -> np.ndarray:
    """First-order covariance (Nx3x3, mm²) of triangulated points for isotropic pixel noise
    ``sigma_px`` in every camera: ``sigma² (JᵀJ)⁻¹`` with J the Jacobian of the stacked
    projections (central differences through the full camera model).

    ``sqrt(trace)`` is the expected 3D RMS error; the eigenvectors show that it lies mostly
    along the viewing direction (depth), where a stereo rig is weakest.
    """
    cams = [as_camera(c) for c in cams]
    X = np.asarray(points3d, float).reshape(-1, 3)
    h = 1e-3  # mm; projections are smooth on this scale
    out = np.empty((len(X), 3, 3))
    for k, x in enumerate(X):
        J = np.empty((2 * len(cams), 3))
        for axis in range(3):
            dx = np.zeros(3)
            dx[axis] = h
            plus = np.concatenate([_project(c, x + dx)[0] for c in cams])
            minus = np.concatenate([_project(c, x - dx)[0] for c in cams])
            J[:, axis] = (plus - minus) / (2 * h)
        out[k] = sigma_px**2 * np.linalg.inv(J.T @ J)
    return out
