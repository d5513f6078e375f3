"""The worker side of processing: one chunk of frame sets decoded, detected, matched, triangulated.

Runs in worker processes (or in the caller with ``workers=1``); the state (cameras, settings,
paths of the ``.mjpeg`` files) is installed once per worker by :func:`_init_worker`. Two
cameras go through the vectorised stereo path (the whole chunk matched at once, the rules of
:func:`vts_hw.vision.triangulate.match_epipolar`, and :func:`triangulate_fast`); three or more
through :func:`vts_hw.vision.multiview.match_views`, frame by frame. See
docs/decisions/0018-processing.md and 0031-n-camera-tracking.md.
"""

from __future__ import annotations

import os
from typing import Any

import cv2
import numpy as np

from vts_hw.lifeline import die_with
from vts_hw.vision.detect import DetectorSettings, detect
from vts_hw.vision.multiview import ViewGeometry, match_views
from vts_hw.vision.triangulate import PinholeCamera, fundamental_matrix, match_epipolar

__all__ = ["triangulate_fast"]


# ------------------------------------------------------------------ stereo triangulation
def _project_many(cam: PinholeCamera, X: np.ndarray) -> np.ndarray:
    uv, _ = cv2.projectPoints(np.ascontiguousarray(X, float).reshape(-1, 1, 3), cam.rvec, cam.t, cam.K, cam.dist)
    return uv.reshape(-1, 2)


def _damped(N: np.ndarray) -> np.ndarray:
    """Batched 3x3 normal matrices with 1e-12 of their trace added to the diagonal: no
    effect on a well-posed point, no LinAlgError (for the whole chunk) on a degenerate one."""
    return N + (1e-12 * np.trace(N, axis1=1, axis2=2))[:, None, None] * np.eye(3)


def triangulate_fast(
    cam_a: PinholeCamera,
    cam_b: PinholeCamera,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    norm_a: np.ndarray | None = None,
    norm_b: np.ndarray | None = None,
    iterations: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """3D points (Mx3, mm) and reprojection RMS (M, px) of M point pairs (pixels, Mx2 each),
    vectorised: linear triangulation (DLT, inhomogeneous least squares) on normalized
    (undistorted) coordinates — given, or computed here — then ``iterations`` Gauss-Newton
    steps on the pixel reprojection error through the full camera models (numerical
    Jacobian, all points at once). One step reaches :func:`vts_hw.vision.triangulate.triangulate`'s
    optimum to ~1e-7 mm (the linear solution alone is within ~1 µm at 0.05 px noise)."""
    pa, pb = np.asarray(pts_a, float).reshape(-1, 2), np.asarray(pts_b, float).reshape(-1, 2)
    m = len(pa)
    if m == 0:
        return np.zeros((0, 3)), np.zeros(0)
    if norm_a is None:
        norm_a = cv2.undistortPoints(pa.reshape(-1, 1, 2), cam_a.K, cam_a.dist).reshape(-1, 2)
    if norm_b is None:
        norm_b = cv2.undistortPoints(pb.reshape(-1, 1, 2), cam_b.K, cam_b.dist).reshape(-1, 2)
    origin = 0.5 * (cam_a.center + cam_b.center)
    scale = float(np.linalg.norm(cam_a.center - origin)) or 1000.0
    rows = []
    for cam, x in ((cam_a, norm_a), (cam_b, norm_b)):
        P = np.column_stack([cam.R, (cam.R @ origin + cam.t) / scale])
        rows.append(x[:, 0:1] * P[2] - P[0])
        rows.append(x[:, 1:2] * P[2] - P[1])
    A = np.stack(rows, axis=1)  # (m, 4, 4): A @ (X', 1) = 0 in the conditioned frame
    # Least squares with the homogeneous coordinate fixed to 1 (points are never at infinity
    # here): batched 3x3 normal equations, several times cheaper than a batched SVD; the
    # Gauss-Newton step below takes the result to the reprojection optimum either way.
    A3, b = A[:, :, :3], -A[:, :, 3]
    At = A3.transpose(0, 2, 1)
    X = origin + scale * np.linalg.solve(_damped(At @ A3), (At @ b[..., None]))[..., 0]
    obs = np.concatenate([pa, pb], axis=1)  # (m, 4)
    step = 1e-3
    offsets = np.vstack([np.zeros(3), np.eye(3) * step])  # base and +h per axis

    def residuals_and_jacobian(X):
        Xs = (X[:, None, :] + offsets[None]).reshape(-1, 3)  # (m*4, 3)
        pr = np.concatenate([_project_many(cam_a, Xs), _project_many(cam_b, Xs)], axis=1)
        pr = pr.reshape(m, 4, 4)  # point, (base, dx, dy, dz), (ua, va, ub, vb)
        r = pr[:, 0] - obs
        J = (pr[:, 1:] - pr[:, :1]).transpose(0, 2, 1) / step  # (m, 4 residuals, 3)
        return r, J

    for _ in range(iterations):
        r, J = residuals_and_jacobian(X)
        JT = J.transpose(0, 2, 1)
        dX = np.linalg.solve(_damped(JT @ J), -(JT @ r[..., None]))[..., 0]
        X = X + dX
    r = np.concatenate([_project_many(cam_a, X), _project_many(cam_b, X)], axis=1) - obs
    return X, np.sqrt(np.mean(r**2, axis=1))


# ------------------------------------------------------------------ worker side
_W: dict[str, Any] = {}


def _init_worker(state: dict, threads: int | None = 1) -> None:
    """Per worker: OpenCV single-threaded, the cameras and settings kept as globals; a worker
    of a pool (``state["command_pid"]``) ends when the command does (vts_hw.lifeline)."""
    if state.get("command_pid") and state["command_pid"] != os.getpid():
        die_with(state["command_pid"])
    if threads is not None:
        cv2.setNumThreads(threads)
    _W.clear()
    _W.update(state)
    cams = state["cams"]
    if len(cams) == 2:
        _W["F"] = fundamental_matrix(cams[0], cams[1])
    else:
        _W["geo"] = ViewGeometry(cams, state["names"])


def _read_span(path: str, offsets: np.ndarray, lengths: np.ndarray) -> list[np.ndarray | None]:
    """The JPEGs at ``offsets`` (one read of the span they cover); None for bytes missing;
    an empty array where the offset is negative (no frame of this camera in the set)."""
    if len(offsets) == 0:
        return []
    here = offsets >= 0
    if not here.any():
        return [np.zeros(0, np.uint8)] * len(offsets)
    start = int(offsets[here].min())
    end = int((offsets + lengths)[here].max())
    with open(path, "rb") as f:
        f.seek(start)
        data = f.read(end - start)
    buf = np.frombuffer(data, np.uint8)
    out: list[np.ndarray | None] = []
    for o, n in zip(offsets.tolist(), lengths.tolist()):
        if o < 0:
            out.append(np.zeros(0, np.uint8))
            continue
        a = o - start
        out.append(buf[a : a + n] if a + n <= len(buf) else None)
    return out


def _detect_frames(path: str, offsets, lengths, settings: DetectorSettings):
    """Per frame the blob centroids (k x 2 float array), or None when undecodable."""
    out: list[np.ndarray | None] = []
    for jpeg in _read_span(path, offsets, lengths):
        if jpeg is not None and len(jpeg) == 0:
            out.append(np.zeros((0, 2)))  # this camera has no frame in the set
            continue
        gray = cv2.imdecode(jpeg, cv2.IMREAD_GRAYSCALE) if jpeg is not None else None
        if gray is None:
            out.append(None)
            continue
        blobs = detect(gray, settings).blobs
        out.append(np.array([(b.x, b.y) for b in blobs], float).reshape(-1, 2))
    return out


def _ideal(cam: PinholeCamera, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalized and ideal-pixel (undistorted, K kept) coordinates of pixel points."""
    if len(pts) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    n = cv2.undistortPoints(
        pts.reshape(-1, 1, 2),
        cam.K,
        cam.dist,
        None,
        None,
        None,
        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14),
    ).reshape(-1, 2)
    return n, n @ cam.K[:2, :2].T + cam.K[:2, 2]


def _match_chunk(F, s, cams, flat, n: int, per_side: bool = False):
    """Epipolar matches of every frame pair of a chunk at once.

    ``flat``: per camera ``(pixels, normalized, ideal pixels, starts)`` of all the chunk's
    points, frame k's points at ``starts[k]:starts[k + 1]``. The symmetric epipolar distance
    (as ``epipolar_distances``) of every same-frame combination is computed in one go; in a
    frame where no point has two in-gate candidates nothing can be ambiguous and the matches
    are the in-gate pairs (``match_epipolar`` would say the same); any other frame goes to
    ``match_epipolar`` itself. Returns ``(index a, index b, frame k)`` sorted by frame and
    index a, and the ambiguous points per frame (``per_side``: per frame and camera, (n, 2)).
    """
    (pa, _, xa, sa), (pb, _, xb, sb) = flat
    na, nb = np.diff(sa), np.diff(sb)
    fa = np.repeat(np.arange(n), na)  # frame of each point of a
    rep = nb[fa]  # same-frame b points per a point
    ia = np.repeat(np.arange(len(xa)), rep)
    first = np.repeat(np.cumsum(rep) - rep, rep)
    ib = np.repeat(sb[:-1][fa], rep) + (np.arange(len(ia)) - first)
    ambiguous = np.zeros((n, 2), int)
    if len(ia) == 0:
        return ia, ib, fa[ia], ambiguous if per_side else ambiguous.sum(axis=1)
    ha = np.column_stack([xa, np.ones(len(xa))])
    hb = np.column_stack([xb, np.ones(len(xb))])
    la = ha @ F.T  # each a point's epipolar line in image b
    lb = hb @ F  # each b point's line in image a
    la /= np.hypot(la[:, 0], la[:, 1])[:, None]
    lb /= np.hypot(lb[:, 0], lb[:, 1])[:, None]
    d_b = np.abs(np.einsum("ij,ij->i", la[ia], hb[ib]))
    d_a = np.abs(np.einsum("ij,ij->i", lb[ib], ha[ia]))
    gate = np.maximum(d_a, d_b) <= s.max_px
    busy_a = np.bincount(ia[gate], minlength=len(xa)) > 1
    busy_b = np.bincount(ib[gate], minlength=len(xb)) > 1
    fb = np.repeat(np.arange(n), nb)
    hard = np.zeros(n, bool)
    hard[fa[busy_a]] = True
    hard[fb[busy_b]] = True
    keep = gate & ~hard[fa[ia]]
    out_a, out_b = [ia[keep]], [ib[keep]]
    for k in np.flatnonzero(hard).tolist():
        m = match_epipolar(
            cams[0], pa[sa[k] : sa[k + 1]], cams[1], pb[sb[k] : sb[k + 1]], s.max_px, s.ratio, s.min_sep_px
        )
        ambiguous[k] = [sum(p.side == s for p in m.ambiguous) for s in "ab"]
        if m.pairs:
            pr = np.array(m.pairs, int)
            out_a.append(sa[k] + pr[:, 0])
            out_b.append(sb[k] + pr[:, 1])
    ma, mb = np.concatenate(out_a), np.concatenate(out_b)
    order = np.argsort(ma, kind="stable")  # a's points are stored frame by frame
    ma, mb = ma[order], mb[order]
    return ma, mb, fa[ma], ambiguous if per_side else ambiguous.sum(axis=1)


def _process_chunk(task):
    """Worker: detect, match, triangulate one chunk of frame sets (see processing's doc).

    Returns ``(k0, set of each point, xyz, rms_px, uv (M, 2C; NaN where a camera was not
    used), blobs per set and camera (-1: no frame), undecodable (bool), ambiguous detections
    per set and camera, detections no other camera confirmed per set and camera)``."""
    k0, spans = task
    s = _W["settings"]
    cams = _W["cams"]
    C = len(cams)
    dets = [_detect_frames(_W["paths"][c], off, ln, s.detector) for c, (off, ln) in enumerate(spans)]
    n = len(dets[0])
    counts = np.zeros((n, C), int)
    failed = np.zeros((n, C), bool)
    flat = []
    for c, det in enumerate(dets):  # undistort every point of the chunk at once, per camera
        sizes = [0 if d is None else len(d) for d in det]
        counts[:, c] = np.where(spans[c][0] < 0, -1, sizes)
        failed[:, c] = [d is None for d in det]
        allp = np.concatenate([d for d in det if d is not None] + [np.zeros((0, 2))])
        norm, ideal = _ideal(cams[c], allp)
        flat.append((allp, norm, ideal, np.concatenate([[0], np.cumsum(sizes)]).astype(int)))
    if C == 2:
        return _stereo(k0, s, cams, flat, n, counts, failed)
    return _multiview(k0, s, flat, n, counts, failed)


def _stereo(k0, s, cams, flat, n, counts, failed):
    ia, ib, fk, ambiguous = _match_chunk(_W["F"], s, cams, flat, n, per_side=True)
    if len(ia):
        X, rms = triangulate_fast(cams[0], cams[1], flat[0][0][ia], flat[1][0][ib], flat[0][1][ia], flat[1][1][ib])
        uv = np.concatenate([flat[0][0][ia], flat[1][0][ib]], axis=1)
        fit = rms <= s.max_rms_px  # a pair that fits this badly is no point (as N views)
        X, rms, uv, fk = X[fit], rms[fit], uv[fit], fk[fit]
        pair = k0 + fk
    else:
        X, rms, uv, pair = np.zeros((0, 3)), np.zeros(0), np.zeros((0, 4)), np.zeros(0, int)
    matched = np.bincount(fk, minlength=n)[:, None] if len(fk) else np.zeros((n, 1), int)
    single = np.maximum(counts, 0) - matched - ambiguous
    return k0, pair, X, rms, uv, counts, failed, ambiguous, single


def _multiview(k0, s, flat, n, counts, failed):
    geo = _W["geo"]
    C = len(flat)
    ambiguous = np.zeros((n, C), int)
    single = np.zeros((n, C), int)
    pair, X, rms, uv = [], [], [], []
    for k in range(n):
        pts = [f[0][f[3][k] : f[3][k + 1]] for f in flat]
        norm = [f[1][f[3][k] : f[3][k + 1]] for f in flat]
        m = match_views(geo, pts, s.max_px, s.ratio, s.views_min_sep_px, norm=norm, max_rms_px=s.max_rms_px)
        for amb in m.ambiguous:
            for c in range(C):
                ambiguous[k, c] += len({g[c] for g in amb.groups if g[c] >= 0})
        single[k] = [len(m.single[name]) for name in geo.names]
        for p in m.points:
            row = np.full(2 * C, np.nan)
            for c, d in enumerate(p.detections):
                if d >= 0:
                    row[2 * c : 2 * c + 2] = pts[c][d]
            pair.append(k0 + k)
            X.append(p.xyz)
            rms.append(p.rms_px)
            uv.append(row)
    return (
        k0,
        np.array(pair, int),
        np.array(X).reshape(-1, 3),
        np.array(rms, float),
        np.array(uv).reshape(-1, 2 * C),
        counts,
        failed,
        ambiguous,
        single,
    )
