"""Markers seen by N calibrated cameras: correspondence across every view, and 3D points.

:func:`match_views` takes each camera's detections (pixels) of one instant and returns
:class:`ViewMatches`: the 3D points (:class:`MultiPoint`, each with the cameras and detections
it was made from, and its reprojection error), the ambiguities (never resolved by a guess) and
the detections no other camera confirms (a marker seen by one camera only is reported, not
invented). The rules (docs/decisions/0031-n-camera-tracking.md):

1. **Every pair of cameras**: the symmetric epipolar distance (undistorted pixels, as
   :func:`vts_hw.vision.triangulate.epipolar_distances`) of every detection pair; a pair within
   ``max_px`` is a candidate.
2. **Each candidate grows into a group**: the pair is triangulated and projected into every
   other camera; the one detection there within ``max_px`` joins (two within the gate: that
   camera stays out of the group -- it cannot say which). Groups are deduplicated, a group
   contained in another is dropped, and every group is triangulated from all its cameras
   (linear on undistorted points, then Gauss-Newton on the pixel reprojection error); a
   camera whose residual is above ``max_px`` leaves the group (one at a time, worst first,
   while at least two remain). Consistency over every pair of the group is then implied:
   all its detections reproject within the gate. A group whose RMS reprojection error is
   above ``max_rms_px`` (0.5 px) makes no point: two detections that merely lie near each
   other's epipolar line (two markers each seen by one camera) rarely fit that well.
3. **Selection**: groups are taken best first -- more cameras first, then lower reprojection
   RMS. A group whose detection is already taken is dropped. A rival group sharing a
   detection (and none already taken), with as many cameras and an RMS not clearly worse (``rival_rms > ratio * rms``
   and ``rival_rms - rms >= min_sep_px`` are needed to be clearly worse), makes both
   *ambiguous*: none of their detections is used.

With two cameras this is :func:`~vts_hw.vision.triangulate.match_epipolar`'s ratio test on
the reprojection RMS instead of the epipolar distance (for two views the two are
proportional); processing keeps its vectorised two-camera path for two cameras.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from vts_hw.vision.triangulate import PinholeCamera, as_camera, fundamental_matrix

__all__ = ["MultiPoint", "Ambiguity", "ViewMatches", "ViewGeometry", "match_views", "triangulate_groups"]

_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)
MAX_RMS_PX = 0.5  # a point's reprojection RMS (per camera, px) above this is no point


@dataclass(frozen=True)
class MultiPoint:
    """One 3D point (mm): ``detections[c]`` is the index of its detection in camera ``c``
    (-1: not used), ``cameras`` their names, ``rms_px`` the RMS reprojection error over them,
    ``residual_px`` per camera (NaN where not used)."""

    xyz: np.ndarray
    detections: tuple[int, ...]
    cameras: tuple[str, ...]
    rms_px: float
    residual_px: tuple[float, ...]

    @property
    def n_cameras(self) -> int:
        return len(self.cameras)


@dataclass(frozen=True)
class Ambiguity:
    """Detections withheld: the competing groups (each a tuple of detection indices per camera,
    -1 where absent) and their reprojection RMS (px)."""

    groups: tuple[tuple[int, ...], ...]
    rms_px: tuple[float, ...]


@dataclass
class ViewMatches:
    """What :func:`match_views` found at one instant."""

    camera_names: list[str]
    points: list[MultiPoint] = field(default_factory=list)
    ambiguous: list[Ambiguity] = field(default_factory=list)
    single: dict[str, list[int]] = field(default_factory=dict)  # detections no camera confirms

    @property
    def xyz(self) -> np.ndarray:
        return np.array([p.xyz for p in self.points]).reshape(-1, 3)


class ViewGeometry:
    """The cameras and what matching needs of every pair, computed once (fundamental matrices)."""

    def __init__(self, cameras: Sequence, names: Sequence[str] | None = None):
        self.cams: list[PinholeCamera] = [as_camera(c) for c in cameras]
        self.names = list(names) if names is not None else [c.name or f"cam{i + 1}" for i, c in enumerate(self.cams)]
        if len(self.cams) < 2 or len(self.names) != len(self.cams):
            raise ValueError("multi-view matching needs two or more cameras, one name each")
        self.pairs = list(itertools.combinations(range(len(self.cams)), 2))
        self.F = {(a, b): fundamental_matrix(self.cams[a], self.cams[b]) for a, b in self.pairs}
        self.rvecs = [c.rvec for c in self.cams]
        centres = np.array([c.center for c in self.cams])
        self.origin = centres.mean(axis=0)
        self.scale = float(np.mean(np.linalg.norm(centres - self.origin, axis=1))) or 1000.0
        # per camera, the 3x4 projection in the conditioned world frame (normalized coordinates)
        self.P = np.array([np.column_stack([c.R, (c.R @ self.origin + c.t) / self.scale]) for c in self.cams])

    def normalize(self, c: int, pts: np.ndarray) -> np.ndarray:
        pts = np.asarray(pts, float).reshape(-1, 2)
        if len(pts) == 0:
            return np.zeros((0, 2))
        cam = self.cams[c]
        return cv2.undistortPoints(pts.reshape(-1, 1, 2), cam.K, cam.dist, None, None, None, _CRITERIA).reshape(-1, 2)

    def project(self, c: int, X: np.ndarray) -> np.ndarray:
        cam = self.cams[c]
        uv, _ = cv2.projectPoints(
            np.ascontiguousarray(X, float).reshape(-1, 1, 3), self.rvecs[c], cam.t, cam.K, cam.dist
        )
        return uv.reshape(-1, 2)


def _linear(geo: ViewGeometry, norm: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """DLT (inhomogeneous, batched 3x3 normal equations) of M points: ``norm`` (M, C, 2)
    normalized coordinates, ``mask`` (M, C) which cameras count."""
    P = geo.P  # (C, 3, 4)
    r1 = norm[:, :, 0:1] * P[None, :, 2] - P[None, :, 0]  # (M, C, 4)
    r2 = norm[:, :, 1:2] * P[None, :, 2] - P[None, :, 1]
    w = mask[:, :, None].astype(float)
    A = np.concatenate([r1 * w, r2 * w], axis=1)  # (M, 2C, 4)
    A3, b = A[:, :, :3], -A[:, :, 3]
    At = A3.transpose(0, 2, 1)
    N = At @ A3
    N = N + (1e-12 * np.trace(N, axis1=1, axis2=2) + 1e-300)[:, None, None] * np.eye(3)
    return geo.origin + geo.scale * np.linalg.solve(N, (At @ b[..., None]))[..., 0]


def _residuals(geo: ViewGeometry, X: np.ndarray, obs: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per point and camera the reprojection residual vector (M, C, 2); 0 where masked out."""
    r = np.zeros(obs.shape)
    for c in range(len(geo.cams)):
        sel = mask[:, c]
        if sel.any():
            r[sel, c] = geo.project(c, X[sel]) - obs[sel, c]
    return r


def triangulate_groups(
    geo: ViewGeometry, obs: np.ndarray, norm: np.ndarray, mask: np.ndarray, iterations: int = 1
) -> tuple[np.ndarray, np.ndarray]:
    """3D points (M, 3) and per-camera residual norms (M, C; NaN where masked) of M points,
    each seen by the cameras of its ``mask`` row (≥ 2): pixels ``obs`` (M, C, 2), normalized
    ``norm`` (M, C, 2). Linear, then ``iterations`` Gauss-Newton steps on the pixel
    reprojection error through the full camera models (numerical Jacobian, all at once)."""
    m = len(obs)
    if m == 0:
        return np.zeros((0, 3)), np.zeros((0, len(geo.cams)))
    X = _linear(geo, norm, mask)
    h = 1e-3
    steps = np.vstack([np.zeros(3), h * np.eye(3)])[:, None, :]  # X, then X moved along x, y, z
    obs4, mask4 = np.tile(obs, (4, 1, 1)), np.tile(mask, (4, 1))
    for _ in range(iterations):
        # the residuals at X and at its three moves in one projection per camera
        r = _residuals(geo, (X[None] + steps).reshape(-1, 3), obs4, mask4).reshape(4, m, -1)
        r0 = r[0]  # (M, 2C)
        J = ((r[1:] - r0) / h).transpose(1, 2, 0)  # (M, 2C, 3)
        JT = J.transpose(0, 2, 1)
        N = JT @ J
        N = N + (1e-12 * np.trace(N, axis1=1, axis2=2) + 1e-300)[:, None, None] * np.eye(3)
        X = X + np.linalg.solve(N, -(JT @ r0[..., None]))[..., 0]
    res = np.linalg.norm(_residuals(geo, X, obs, mask), axis=2)
    return X, np.where(mask, res, np.nan)


def match_views(
    geo: ViewGeometry,
    pts: Sequence,
    max_px: float = 2.0,
    ratio: float = 2.0,
    min_sep_px: float = 0.0,
    norm: Sequence | None = None,
    max_rms_px: float = MAX_RMS_PX,
) -> ViewMatches:
    """Correspondence and 3D points of one instant's detections ``pts`` (per camera Nc x 2
    pixels; ``norm``: their normalized coordinates, if already known). A group whose
    reprojection RMS exceeds ``max_rms_px`` makes no point. See the module doc."""
    C = len(geo.cams)
    pts = [np.asarray(p, float).reshape(-1, 2) for p in pts]
    if len(pts) != C:
        raise ValueError(f"{C} cameras but detections of {len(pts)}")
    norm = (
        [geo.normalize(c, p) for c, p in enumerate(pts)]
        if norm is None
        else [np.asarray(n, float).reshape(-1, 2) for n in norm]
    )
    ideal = [n @ geo.cams[c].K[:2, :2].T + geo.cams[c].K[:2, 2] for c, n in enumerate(norm)]
    out = ViewMatches(list(geo.names))
    hom = [np.column_stack([u, np.ones(len(u))]) for u in ideal]
    # 1. candidate pairs over every pair of cameras
    seeds = []
    for a, b in geo.pairs:
        if len(pts[a]) == 0 or len(pts[b]) == 0:
            continue
        F = geo.F[(a, b)]
        ha, hb = hom[a], hom[b]
        la, lb = ha @ F.T, hb @ F
        d_b = np.abs(la @ hb.T) / np.hypot(la[:, 0], la[:, 1])[:, None]
        d_a = (np.abs(lb @ ha.T) / np.hypot(lb[:, 0], lb[:, 1])[:, None]).T
        ii, jj = np.nonzero(np.maximum(d_a, d_b) <= max_px)
        if len(ii):
            rows = np.full((len(ii), C), -1)
            rows[:, a], rows[:, b] = ii, jj
            seeds.append(rows)
    if seeds:
        groups = _grow(geo, pts, norm, np.vstack(seeds), max_px)
        _select(geo, pts, norm, groups, max_px, ratio, min_sep_px, max_rms_px, out)
    used: list[set[int]] = [set() for _ in range(C)]
    for p in out.points:
        for c, d in enumerate(p.detections):
            if d >= 0:
                used[c].add(d)
    for amb in out.ambiguous:
        for g in amb.groups:
            for c, d in enumerate(g):
                if d >= 0:
                    used[c].add(d)
    out.single = {geo.names[c]: [i for i in range(len(pts[c])) if i not in used[c]] for c in range(C)}
    return out


def _unique_rows(groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(groups, axis=0, return_index=True)`` (rows in lexicographic order, each with
    its first occurrence) through one integer per row: detection indices are small."""
    base = int(groups.max(initial=-1)) + 2
    key = np.zeros(len(groups), np.int64)
    for c in range(groups.shape[1]):  # the first camera the most significant digit
        key = key * base + (groups[:, c] + 1)
    _, first = np.unique(key, return_index=True)
    return groups[first], first


def _gather(pts, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, C, 2) of the detections each group names (zeros where -1), and the mask."""
    M, C = groups.shape
    obs = np.zeros((M, C, 2))
    mask = groups >= 0
    for c in range(C):
        sel = mask[:, c]
        if sel.any():
            obs[sel, c] = pts[c][groups[sel, c]]
    return obs, mask


def _grow(geo, pts, norm, seeds: np.ndarray, max_px: float) -> np.ndarray:
    """Each seed pair triangulated and projected into the other cameras: the one detection
    within ``max_px`` joins. Deduplicated; groups inside another group dropped."""
    C = len(geo.cams)
    obs_n, mask = _gather(norm, seeds)
    X = _linear(geo, obs_n, mask)
    groups = seeds.copy()
    for c in range(C):
        if len(pts[c]) == 0:
            continue
        free = ~mask[:, c]
        if not free.any():
            continue
        uv = geo.project(c, X[free])
        d = np.linalg.norm(uv[:, None, :] - pts[c][None, :, :], axis=2)
        inside = d <= max_px
        one = inside.sum(axis=1) == 1
        rows = np.flatnonzero(free)[one]
        groups[rows, c] = np.argmax(inside[one], axis=1)
    groups = _unique_rows(groups)[0]
    g = groups[:, None, :]
    h = groups[None, :, :]
    inside_other = np.all((g < 0) | (g == h), axis=2) & ~np.all(g == h, axis=2)
    return groups[~inside_other.any(axis=1)]


def _select(geo, pts, norm, groups: np.ndarray, max_px, ratio, min_sep_px, max_rms_px, out: ViewMatches) -> None:
    C = len(geo.cams)
    obs, mask = _gather(pts, groups)
    obs_n, _ = _gather(norm, groups)
    X, res = triangulate_groups(geo, obs, obs_n, mask)
    # a camera whose detection does not fit leaves its group (worst first, >= 2 cameras kept)
    for _ in range(C - 2):
        worst = np.nanargmax(np.where(mask, res, -1.0), axis=1)
        bad = (res[np.arange(len(res)), worst] > max_px) & (mask.sum(axis=1) > 2)
        if not bad.any():
            break
        mask[bad, worst[bad]] = False
        groups[bad, worst[bad]] = -1
        Xb, rb = triangulate_groups(geo, obs[bad], obs_n[bad], mask[bad])
        X[bad], res[bad] = Xb, rb
    fits = np.nanmax(np.where(mask, res, 0.0), axis=1) <= max_px
    groups, X, res, mask = groups[fits], X[fits], res[fits], mask[fits]
    groups, first = _unique_rows(groups)  # the same group twice is one
    X, res, mask = X[first], res[first], mask[first]
    n = mask.sum(axis=1)
    rms = np.sqrt(np.nansum(np.where(mask, res, 0.0) ** 2, axis=1) / np.maximum(n, 1))
    fits = rms <= max_rms_px
    groups, X, res, mask, n, rms = groups[fits], X[fits], res[fits], mask[fits], n[fits], rms[fits]
    order = np.lexsort((rms, -n))
    # for every two groups: whether they share a detection; j a rival of k: as many cameras, a
    # detection shared, not clearly worse than k
    share = np.any((groups[:, None, :] >= 0) & (groups[:, None, :] == groups[None, :, :]), axis=2)
    worse = (rms[None, :] > ratio * rms[:, None]) & (rms[None, :] - rms[:, None] >= min_sep_px)
    rival = share & (n[:, None] == n[None, :]) & ~worse
    np.fill_diagonal(rival, False)
    has_rival = rival.any(axis=1).tolist()
    # the groups each group blocks when taken (those sharing a detection with it, itself included)
    blocks = [np.flatnonzero(row).tolist() if more else [] for row, more in zip(share, share.sum(axis=1) > 1)]
    order_l = order.tolist()
    dropped = [False] * len(groups)
    blocked = [False] * len(groups)  # a detection of it is in a point or an ambiguity already
    gl, rl, resl, ml = groups.tolist(), rms.tolist(), res.tolist(), mask.tolist()
    for k in order_l:
        if dropped[k]:
            continue
        if blocked[k]:
            dropped[k] = True
            continue
        # a rival: none of its detections in a point already
        rivals = [j for j in order_l if rival[k, j] and not dropped[j] and not blocked[j]] if has_rival[k] else []
        if rivals:
            members = [k] + rivals
            out.ambiguous.append(Ambiguity(tuple(tuple(gl[j]) for j in members), tuple(rl[j] for j in members)))
            for j in members:
                dropped[j] = True
                for i in blocks[j]:
                    blocked[i] = True
            continue
        dropped[k] = True
        for i in blocks[k]:
            blocked[i] = True
        cams = tuple(name for name, m in zip(geo.names, ml[k]) if m)
        out.points.append(MultiPoint(X[k].copy(), tuple(gl[k]), cams, rl[k], tuple(resl[k])))
