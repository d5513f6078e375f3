"""Process a recording folder: decode, detect, match and triangulate every frame, on every core.

:func:`process_recording` turns a recording folder (vts_hw/recording/folder.py) of a stereo pair into
:class:`~vts_hw.recording.tracks.Tracks`: marker positions (mm) over host time with identities.

1. **Clocks.** Each camera's clock is fitted to host time from its index
   (:mod:`vts_hw.timing.camera_clock`); every frame gets a *mapped host time* from its JPEG stamp
   (a frame without a stamp: its receive time minus the median delay).
2. **Pairing.** Each frame of the first camera is paired with the second camera's frame
   nearest in mapped host time, if within half a frame period (one-to-one, the closer wins).
   Frames left over are reported (``Tracks.unpaired``) and not decoded. The cameras' own
   clocks may differ by seconds: only mapped host times are compared.
3. **Per chunk of pairs, in worker processes** (``workers`` = every core by default): the
   JPEGs are read from the ``.mjpeg`` files by the byte offsets of the index (one read per
   camera per chunk: no JPEG bytes go through pipes), decoded at full resolution
   (``cv2.imdecode``, grey), detected (:func:`vts_hw.vision.detect.detect`), matched by the epipolar
   constraint (the rules of :func:`vts_hw.vision.triangulate.match_epipolar`; a fast path when
   every point has at most one candidate), and triangulated all at once: a linear solution on
   undistorted points, then one Gauss-Newton step on the reprojection error in pixels through
   the full camera model (``cv2.projectPoints``), vectorised over the chunk's points.
   OpenCV's own threads are set to 1 in the workers (no oversubscription).
4. **Identities** (main process, in time order): nearest-neighbour assignment (Hungarian) of
   each pair's points to the tracks alive, within ``gate_mm``; a point left over starts a new
   marker id; a track unseen for ``max_gap_s`` ends.

Clocks: every ``host_time`` here is the host's UTC epoch seconds as mapped from the cameras'
stamps (see camera_clock for what the mapping means: exposure plus the least delay).
Units: mm, px, s. See docs/decisions/0018-processing.md and docs/trajectory-format.md.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from vts_hw.timing.camera_clock import ClockFit, fit_camera_clock
from vts_hw.vision.detect import DEFAULT as DEFAULT_DETECTOR, DetectorSettings, detect
from vts_hw.errors import DataError
from vts_hw.recording.folder import load_manifest, read_index
from vts_hw.recording.tracks import TRACKS_FORMAT, Tracks
from vts_hw.vision.triangulate import Camera, as_camera, fundamental_matrix, match_epipolar

__all__ = ["Tracks", "ProcessSettings", "process_recording", "cameras_from_calibration",
           "pair_frames", "triangulate_fast", "track_identities", "CameraFrames",
           "load_camera_frames", "TRACKS_FORMAT"]


@dataclass(frozen=True)
class ProcessSettings:
    """Parameters of :func:`process_recording`.

    ``max_px``, ``ratio``, ``min_sep_px``: epipolar matching (see ``match_epipolar``).
    ``pair_fraction``: frames pair when their mapped host times differ by at most this
    fraction of the frame period. ``gate_mm``: tracking gate (mm) from a track's last
    position. ``max_gap_s``: a track not seen for this long ends (a later point gets a new id).
    ``latency_s``: known minimum exposure-to-receipt delay, subtracted from mapped times.
    ``chunk_pairs``: pairs per worker task (None: chosen from the pair count and workers).
    """

    max_px: float = 2.0
    ratio: float = 2.0
    min_sep_px: float = 0.0
    pair_fraction: float = 0.5
    gate_mm: float = 15.0
    max_gap_s: float = 1.0
    latency_s: float = 0.0
    chunk_pairs: int | None = None
    detector: DetectorSettings = DEFAULT_DETECTOR


# ------------------------------------------------------------------ inputs
def cameras_from_calibration(calib, names: Sequence[str] = ("cam1", "cam2")) -> dict[str, Camera]:
    """Two :class:`Camera` objects from a :class:`~vts_hw.vision.calibration_io.StereoCalibration`
    (the VTS frame is camera 1's frame; T in the calibration's unit, mm for a real one)."""
    if getattr(calib, "unit", "mm") != "mm":
        raise DataError(f"the stereo calibration's translation is in {calib.unit!r}, not mm: "
                        "calibrate with the checkerboard's square size to get tracks in mm")
    from vts_hw.vision.calibration_io import stereo_cameras
    return {c.name: c for c in stereo_cameras(calib, names)}


def _camera_dict(cameras, available: Sequence[str]) -> dict[str, Camera]:
    if hasattr(cameras, "K1") and hasattr(cameras, "R"):
        return cameras_from_calibration(cameras, list(available)[:2])
    if isinstance(cameras, dict):
        return {str(k): as_camera(v) for k, v in cameras.items()}
    cams = [as_camera(c) for c in cameras]
    names = [c.name for c in cams]
    if not all(names) or len(set(names)) != len(names):
        names = list(available)[:len(cams)]
    return dict(zip(names, cams))


@dataclass
class CameraFrames:
    """One camera's indexed frames as arrays (frames past the end of the ``.mjpeg`` dropped).

    ``camera_time`` NaN where a frame had no stamp; ``host_time`` is the *receive* time."""

    name: str
    mjpeg: Path
    frame: np.ndarray
    offset: np.ndarray
    length: np.ndarray
    camera_time: np.ndarray
    host_time: np.ndarray
    beyond_end: int = 0


def load_camera_frames(folder: Path, name: str) -> CameraFrames:
    idx, mj = folder / f"{name}.index.csv", folder / f"{name}.mjpeg"
    if not idx.exists() or not mj.exists():
        raise DataError(f"{folder}: camera {name!r} has no {idx.name} and {mj.name}")
    rows = read_index(idx)
    size = mj.stat().st_size
    nan = math.nan
    arr = np.array([(r.frame, r.offset, r.length,
                     nan if r.camera_time is None else r.camera_time,
                     nan if r.host_time is None else r.host_time) for r in rows],
                   float).reshape(-1, 5)
    inside = arr[:, 1] + arr[:, 2] <= size
    arr = arr[inside]
    return CameraFrames(name, mj, arr[:, 0].astype(np.int64), arr[:, 1].astype(np.int64),
                        arr[:, 2].astype(np.int64), arr[:, 3], arr[:, 4], int((~inside).sum()))


def _mapped_times(cf: CameraFrames, latency_s: float):
    """``(mapped host times, ClockFit or None, warnings)`` of one camera's frames.

    A frame with a stamp but no receive time (a recovered index) is mapped from its stamp;
    one with no stamp gets its receive time less the median delay. A camera with fewer than
    2 frames having both times cannot be fitted: its receive times are used (or, with none,
    its own clock as it is), with a warning."""
    try:
        fit = fit_camera_clock(cf.camera_time, cf.host_time, latency_s)
    except DataError:
        if np.isfinite(cf.host_time).sum() >= 2:
            return cf.host_time - latency_s, None, [
                f"{cf.name}: no camera clock fit (too few stamped frames with a receive time); "
                "receive times used"]
        return cf.camera_time.copy(), None, [
            f"{cf.name}: no host receive times; the camera's own clock used as host time"]
    t = np.atleast_1d(fit.frame_host_times()).copy()
    missing = ~np.isfinite(t)
    if missing.any():
        stamp_only = missing & np.isfinite(cf.camera_time)
        t[stamp_only] = fit.host_time(cf.camera_time[stamp_only])
        recv_only = missing & ~stamp_only
        med = float(np.nanmedian(fit.residuals_s)) if np.isfinite(fit.residuals_s).any() else 0.0
        t[recv_only] = cf.host_time[recv_only] - med - latency_s
    return t, fit, []


# ------------------------------------------------------------------ pairing
def pair_frames(t_a: np.ndarray, t_b: np.ndarray, tolerance_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs ``(ia, ib)`` of frames whose times (s) differ by at most ``tolerance_s``:
    each frame of a with b's nearest, one-to-one (when two frames of a want the same frame
    of b the closer wins). Sorted by ``ia``. Frames with NaN times never pair."""
    t_a, t_b = np.asarray(t_a, float), np.asarray(t_b, float)
    ok_b = np.flatnonzero(np.isfinite(t_b))
    if len(t_a) == 0 or ok_b.size == 0:
        return np.zeros(0, int), np.zeros(0, int)
    order = ok_b[np.argsort(t_b[ok_b], kind="stable")]
    tb = t_b[order]
    j = np.searchsorted(tb, t_a)
    lo, hi = np.clip(j - 1, 0, len(tb) - 1), np.clip(j, 0, len(tb) - 1)
    with np.errstate(invalid="ignore"):
        pick = np.where(np.abs(t_a - tb[lo]) <= np.abs(t_a - tb[hi]), lo, hi)
        dt = np.abs(t_a - tb[pick])
        ok = dt <= tolerance_s
    ia = np.flatnonzero(ok)
    ib = order[pick[ok]]
    # one-to-one: for each b keep the closest a
    by = np.lexsort((dt[ia], ib))
    keep = np.ones(len(by), bool)
    keep[1:] = ib[by][1:] != ib[by][:-1]
    sel = np.sort(by[keep])
    return ia[sel], ib[sel]


# ------------------------------------------------------------------ triangulation
def _project_many(cam: Camera, X: np.ndarray) -> np.ndarray:
    uv, _ = cv2.projectPoints(np.ascontiguousarray(X, float).reshape(-1, 1, 3), cam.rvec, cam.t,
                              cam.K, cam.dist)
    return uv.reshape(-1, 2)


def _damped(N: np.ndarray) -> np.ndarray:
    """Batched 3x3 normal matrices with 1e-12 of their trace added to the diagonal: no
    effect on a well-posed point, no LinAlgError (for the whole chunk) on a degenerate one."""
    return N + (1e-12 * np.trace(N, axis1=1, axis2=2))[:, None, None] * np.eye(3)


def triangulate_fast(cam_a: Camera, cam_b: Camera, pts_a: np.ndarray, pts_b: np.ndarray,
                     norm_a: np.ndarray | None = None, norm_b: np.ndarray | None = None,
                     iterations: int = 1) -> tuple[np.ndarray, np.ndarray]:
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
    return X, np.sqrt(np.mean(r ** 2, axis=1))


# ------------------------------------------------------------------ worker side
_W: dict[str, Any] = {}


def _init_worker(state: dict, threads: int | None = 1) -> None:
    """Per worker: OpenCV single-threaded, the cameras and settings kept as globals."""
    if threads is not None:
        cv2.setNumThreads(threads)
    _W.clear()
    _W.update(state)
    ca, cb = state["cams"]
    _W["F"] = fundamental_matrix(ca, cb)


def _read_span(path: str, offsets: np.ndarray, lengths: np.ndarray) -> list:
    """The JPEGs at ``offsets`` (one read of the span they cover); None for bytes missing."""
    if len(offsets) == 0:
        return []
    start = int(offsets.min())
    end = int((offsets + lengths).max())
    with open(path, "rb") as f:
        f.seek(start)
        data = f.read(end - start)
    buf = np.frombuffer(data, np.uint8)
    out = []
    for o, n in zip(offsets.tolist(), lengths.tolist()):
        a = o - start
        out.append(buf[a:a + n] if a + n <= len(buf) else None)
    return out


def _detect_frames(path: str, offsets, lengths, settings: DetectorSettings):
    """Per frame the blob centroids (k x 2 float array), or None when undecodable."""
    out = []
    for jpeg in _read_span(path, offsets, lengths):
        gray = cv2.imdecode(jpeg, cv2.IMREAD_GRAYSCALE) if jpeg is not None else None
        if gray is None:
            out.append(None)
            continue
        blobs = detect(gray, settings).blobs
        out.append(np.array([(b.x, b.y) for b in blobs], float).reshape(-1, 2))
    return out


def _ideal(cam: Camera, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalized and ideal-pixel (undistorted, K kept) coordinates of pixel points."""
    if len(pts) == 0:
        return np.zeros((0, 2)), np.zeros((0, 2))
    n = cv2.undistortPoints(pts.reshape(-1, 1, 2), cam.K, cam.dist, None, None, None,
                            (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14)).reshape(-1, 2)
    return n, n @ cam.K[:2, :2].T + cam.K[:2, 2]


def _match_chunk(F, s: ProcessSettings, cams, flat, n: int):
    """Epipolar matches of every frame pair of a chunk at once.

    ``flat``: per camera ``(pixels, normalized, ideal pixels, starts)`` of all the chunk's
    points, frame k's points at ``starts[k]:starts[k + 1]``. The symmetric epipolar distance
    (as ``epipolar_distances``) of every same-frame combination is computed in one go; in a
    frame where no point has two in-gate candidates nothing can be ambiguous and the matches
    are the in-gate pairs (``match_epipolar`` would say the same); any other frame goes to
    ``match_epipolar`` itself. Returns ``(index a, index b, frame k)`` sorted by frame and
    index a, and the ambiguous points per frame.
    """
    (pa, _, xa, sa), (pb, _, xb, sb) = flat
    na, nb = np.diff(sa), np.diff(sb)
    fa = np.repeat(np.arange(n), na)  # frame of each point of a
    rep = nb[fa]                       # same-frame b points per a point
    ia = np.repeat(np.arange(len(xa)), rep)
    first = np.repeat(np.cumsum(rep) - rep, rep)
    ib = np.repeat(sb[:-1][fa], rep) + (np.arange(len(ia)) - first)
    ambiguous = np.zeros(n, int)
    if len(ia) == 0:
        return ia, ib, fa[ia], ambiguous
    ha = np.column_stack([xa, np.ones(len(xa))])
    hb = np.column_stack([xb, np.ones(len(xb))])
    la = ha @ F.T  # each a point's epipolar line in image b
    lb = hb @ F    # each b point's line in image a
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
        m = match_epipolar(cams[0], pa[sa[k]:sa[k + 1]], cams[1], pb[sb[k]:sb[k + 1]],
                           s.max_px, s.ratio, s.min_sep_px)
        ambiguous[k] = len(m.ambiguous)
        if m.pairs:
            pr = np.array(m.pairs, int)
            out_a.append(sa[k] + pr[:, 0])
            out_b.append(sb[k] + pr[:, 1])
    ma, mb = np.concatenate(out_a), np.concatenate(out_b)
    order = np.argsort(ma, kind="stable")  # a's points are stored frame by frame
    ma, mb = ma[order], mb[order]
    return ma, mb, fa[ma], ambiguous


def _process_chunk(task):
    """Worker: detect, match, triangulate one chunk of frame pairs (see the module doc)."""
    k0, (off_a, len_a), (off_b, len_b) = task
    s: ProcessSettings = _W["settings"]
    cams = _W["cams"]
    det_a = _detect_frames(_W["paths"][0], off_a, len_a, s.detector)
    det_b = _detect_frames(_W["paths"][1], off_b, len_b, s.detector)
    n = len(det_a)
    counts = np.zeros((n, 2), int)
    failed = np.zeros((n, 2), bool)
    # undistort every point of the chunk at once, per camera
    flat = []
    for c, det in enumerate((det_a, det_b)):
        sizes = [0 if d is None else len(d) for d in det]
        counts[:, c] = sizes
        failed[:, c] = [d is None for d in det]
        allp = np.concatenate([d for d in det if d is not None] + [np.zeros((0, 2))])
        norm, ideal = _ideal(cams[c], allp)
        flat.append((allp, norm, ideal, np.concatenate([[0], np.cumsum(sizes)]).astype(int)))
    ia, ib, fk, ambiguous = _match_chunk(_W["F"], s, cams, flat, n)
    if len(ia):
        X, rms = triangulate_fast(cams[0], cams[1], flat[0][0][ia], flat[1][0][ib],
                                  flat[0][1][ia], flat[1][1][ib])
        uv = np.concatenate([flat[0][0][ia], flat[1][0][ib]], axis=1)
        pair = k0 + fk
    else:
        X, rms, uv, pair = np.zeros((0, 3)), np.zeros(0), np.zeros((0, 4)), np.zeros(0, int)
    return k0, pair, X, rms, uv, counts, failed, ambiguous


# ------------------------------------------------------------------ identities
def track_identities(frame_of_point: np.ndarray, times: np.ndarray, points: np.ndarray,
                     gate_mm: float = 15.0, max_gap_s: float = 1.0) -> np.ndarray:
    """Marker ids (ints from 1) for points (Nx3, mm) grouped by ``frame_of_point`` (sorted),
    frames at ``times`` (s): nearest-neighbour assignment to the live tracks within
    ``gate_mm`` (Hungarian on the distance), a new id for a point left over; a track not
    seen for more than ``max_gap_s`` ends."""
    n = len(points)
    ids = np.zeros(n, int)
    if n == 0:
        return ids
    bounds = np.flatnonzero(np.diff(frame_of_point)) + 1
    starts = np.concatenate([[0], bounds])
    ends = np.concatenate([bounds, [n]])
    live_id: list[int] = []
    live_pos = np.zeros((0, 3))
    live_t = np.zeros(0)
    next_id = 1
    for s0, s1 in zip(starts.tolist(), ends.tolist()):
        t = times[frame_of_point[s0]]
        P = points[s0:s1]
        if len(live_id):
            alive = (t - live_t) <= max_gap_s
            if not alive.all():
                live_id = [i for i, a in zip(live_id, alive) if a]
                live_pos, live_t = live_pos[alive], live_t[alive]
        got = np.zeros(len(P), int)
        if len(live_id):
            D = np.linalg.norm(live_pos[:, None, :] - P[None, :, :], axis=2)
            if len(live_id) == 1 or len(P) == 1:
                # one side single: nearest within the gate
                if len(live_id) == 1:
                    j = int(np.argmin(D[0]))
                    if D[0, j] <= gate_mm:
                        got[j] = live_id[0]
                        live_pos[0], live_t[0] = P[j], t
                else:
                    i = int(np.argmin(D[:, 0]))
                    if D[i, 0] <= gate_mm:
                        got[0] = live_id[i]
                        live_pos[i], live_t[i] = P[0], t
            else:
                cost = np.where(D <= gate_mm, D, 1e9)
                r, c = linear_sum_assignment(cost)
                for i, j in zip(r.tolist(), c.tolist()):
                    if cost[i, j] <= gate_mm:
                        got[j] = live_id[i]
                        live_pos[i], live_t[i] = P[j], t
        new = np.flatnonzero(got == 0)
        if new.size:
            got[new] = np.arange(next_id, next_id + new.size)
            next_id += new.size
            live_id.extend(got[new].tolist())
            live_pos = np.vstack([live_pos, P[new]])
            live_t = np.concatenate([live_t, np.full(new.size, t)])
        ids[s0:s1] = got
    return ids


# ------------------------------------------------------------------ entry point
def _manifest_cameras(folder: Path) -> list[str]:
    m = load_manifest(folder, missing_ok=True)  # a bad manifest is a DataError naming it
    names = list(m.get("cameras", {})) if m is not None else []
    found = sorted(p.name[: -len(".index.csv")] for p in folder.glob("*.index.csv"))
    return [n for n in names if n in found] + [n for n in found if n not in names]


def process_recording(folder, cameras, workers: int | None = None, mapping=None,
                      host_to_spect: Callable | None = None,
                      settings: ProcessSettings | None = None,
                      progress: Callable[[int, int], None] | None = None,
                      clock_fits: dict[str, ClockFit] | None = None) -> Tracks:
    """Marker tracks of a recording folder of a stereo pair (see the module docstring).

    ``cameras``: the calibrated cameras — a dict name → camera (K, dist, R, t: any object
    ``as_camera`` takes), a list of two (named like the recording's cameras, else taken in
    the recording's order), or a ``StereoCalibration`` (the VTS frame is then camera 1's).
    ``workers``: processes (default ``os.cpu_count()``; 1 runs in this process).
    ``mapping``: a VTS → SPECT rigid transform (``RigidTransform`` or anything with
    ``apply``), adding SPECT-frame positions. ``host_to_spect``: host epoch s → SPECT time,
    adding a SPECT time column. ``progress(done_pairs, total_pairs)`` after each chunk.
    ``clock_fits``: camera clock fits to use instead of fitting them here.
    """
    s = settings or ProcessSettings()
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: not a recording folder")
    available = _manifest_cameras(folder)
    cams = _camera_dict(cameras, available)
    names = [n for n in cams if n in available][:2]
    if len(names) < 2:
        raise DataError(f"{folder}: the recording has cameras {', '.join(available) or 'none'}, "
                        f"but calibrated cameras are {', '.join(cams)}: two must be in both")
    frames = [load_camera_frames(folder, n) for n in names]
    times, fits, warnings = [], {}, []
    for cf in frames:
        if clock_fits and cf.name in clock_fits:
            fit = clock_fits[cf.name]
            t = np.asarray(fit.host_time(cf.camera_time), float)
            t = np.where(np.isfinite(t), t, cf.host_time)
        else:
            t, fit, warn = _mapped_times(cf, s.latency_s)
            warnings += warn
        times.append(t)
        fits[cf.name] = fit
    period = _frame_period(times[0])
    ia, ib = pair_frames(times[0], times[1], s.pair_fraction * period)
    n_pairs = len(ia)
    workers = max(1, int(workers or os.cpu_count() or 1))
    chunk = s.chunk_pairs or int(min(400, max(40, math.ceil(n_pairs / (workers * 6)))))
    tasks = [(k, (frames[0].offset[ia[k:k + chunk]], frames[0].length[ia[k:k + chunk]]),
              (frames[1].offset[ib[k:k + chunk]], frames[1].length[ib[k:k + chunk]]))
             for k in range(0, n_pairs, chunk)]
    state = {"cams": [cams[n] for n in names], "settings": s,
             "paths": [str(cf.mjpeg) for cf in frames]}
    results = []
    done = 0
    if workers == 1 or len(tasks) <= 1:
        before = cv2.getNumThreads()
        _init_worker(state, 1)
        try:
            for task in tasks:
                results.append(_process_chunk(task))
                done += len(task[1][0])
                if progress:
                    progress(done, n_pairs)
        finally:
            cv2.setNumThreads(before)
    else:
        with ProcessPoolExecutor(min(workers, len(tasks)), mp_context=_pool_context(),
                                 initializer=_init_worker, initargs=(state, 1)) as pool:
            for res in pool.map(_process_chunk, tasks):
                results.append(res)
                done += int(res[5].shape[0])
                if progress:
                    progress(done, n_pairs)
    return _assemble(folder, names, frames, times, fits, ia, ib, results, s, mapping,
                     host_to_spect, period, cams, warnings)


def _pool_context():
    """Workers come from a fork server (its own clean process, with this module imported once),
    never by forking this process: a caller with threads (HTTP servers, recorders, OpenCV's
    pool) may hold a lock at the moment of a fork, and the forked worker would wait on it for
    ever. Where there is no fork server, spawn."""
    import multiprocessing as mp
    if "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload([__name__])
        return ctx
    return mp.get_context("spawn")


def _frame_period(t: np.ndarray) -> float:
    d = np.diff(np.sort(t[np.isfinite(t)]))
    d = d[d > 1e-4]
    if d.size == 0:
        raise DataError("too few frames to pair (need at least 2 per camera)")
    return float(np.median(d))


def _assemble(folder, names, frames, times, fits, ia, ib, results, s, mapping, host_to_spect,
              period, cams, warnings) -> Tracks:
    n_pairs = len(ia)
    results.sort(key=lambda r: r[0])
    cat = (lambda i, shape: np.concatenate([r[i] for r in results])
           if results else np.zeros(shape))
    pair = cat(1, (0,)).astype(int)
    X = cat(2, (0, 3))
    rms = cat(3, (0,))
    uv = cat(4, (0, 4))
    counts = cat(5, (0, 2)).astype(int)
    failed = cat(6, (0, 2)).astype(bool)
    ambiguous = cat(7, (0,)).astype(int)
    host = 0.5 * (times[0][ia] + times[1][ib])
    ids = track_identities(pair, host, X, s.gate_mm, s.max_gap_s)
    cam_time = np.column_stack([frames[0].camera_time[ia], frames[1].camera_time[ib]])
    cam_frame = np.column_stack([frames[0].frame[ia], frames[1].frame[ib]])
    unpaired = {}
    for c, (cf, used) in enumerate(zip(frames, (ia, ib))):
        mask = np.ones(len(cf.frame), bool)
        mask[used] = False
        unpaired[cf.name] = cf.frame[mask]
    meta = {
        "recording": str(folder),
        "cameras": names,
        "clock_fits": {n: None if fits[n] is None else fits[n].summary() for n in names},
        "warnings": list(warnings),
        "frame_period_s": period,
        "pair_tolerance_s": s.pair_fraction * period,
        "pair_time_difference_max_s": float(np.max(np.abs(times[0][ia] - times[1][ib])))
        if n_pairs else None,
        "frames": {cf.name: int(len(cf.frame)) for cf in frames},
        "frames_beyond_end_of_mjpeg": {cf.name: cf.beyond_end for cf in frames},
        "paired_frames": int(n_pairs),
        "unpaired_frames": {k: int(len(v)) for k, v in unpaired.items()},
        "undecodable_frames": {names[c]: int(failed[:, c].sum()) for c in range(2)},
        "blobs_per_frame_mean": {names[c]: float(counts[:, c].mean()) if n_pairs else None
                                 for c in range(2)},
        "ambiguous_points": int(ambiguous.sum()),
        "markers": int(ids.max()) if len(ids) else 0,
        "settings": {"max_px": s.max_px, "ratio": s.ratio, "min_sep_px": s.min_sep_px,
                     "pair_fraction": s.pair_fraction, "gate_mm": s.gate_mm,
                     "max_gap_s": s.max_gap_s, "latency_s": s.latency_s},
        "calibration": {n: {"K": cams[n].K.tolist(), "dist": cams[n].dist.tolist(),
                            "R": cams[n].R.tolist(), "t": cams[n].t.tolist()} for n in names},
    }
    tracks = Tracks(host_time=host, camera_names=names, camera_time=cam_time,
                    camera_frame=cam_frame, n_blobs=counts, point_frame=pair, marker=ids,
                    xyz=X, reproj_px=rms, uv=uv, unpaired=unpaired, meta=meta)
    if mapping is not None or host_to_spect is not None:
        tracks = tracks.with_spect(mapping, host_to_spect)
    return tracks
