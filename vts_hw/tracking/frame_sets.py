"""A recording's frames mapped to host time and grouped into frame sets across cameras.

:func:`mapped_times` maps each frame's stamp (:class:`~vts_hw.recording.frames.CameraFrames`) to
host time through the camera's clock fit (:mod:`vts_hw.timing.camera_clock`); :func:`pair_frames`
pairs two cameras' frames by mapped time and :func:`group_frames` does it for any number of
cameras (docs/decisions/0018-processing.md, "Pairing"; 0031 for N cameras); :func:`frame_period`
is a camera's frame interval.
"""

from __future__ import annotations

import numpy as np

from vts_hw.errors import DataError
from vts_hw.recording.frames import CameraFrames
from vts_hw.timing.camera_clock import fit_camera_clock

__all__ = ["mapped_times", "pair_frames", "group_frames", "frame_period"]


def mapped_times(cf: CameraFrames, latency_s: float):
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


def group_frames(times: list[np.ndarray], tolerance_s: float, min_cameras: int = 2) -> np.ndarray:
    """Frame sets of N cameras: (S, N) frame indices (-1: that camera has no frame in the set),
    in time order. Camera 0's frames start the sets; each further camera's frames join the set
    nearest in time (its mean mapped time so far) within ``tolerance_s``, one-to-one
    (:func:`pair_frames`), and a frame that joins none starts a set of its own. Sets with fewer
    than ``min_cameras`` frames are left out. With two cameras the sets are exactly
    ``pair_frames(times[0], times[1], tolerance_s)``."""
    n_cams = len(times)
    if n_cams == 2 and min_cameras == 2:
        return np.column_stack(pair_frames(times[0], times[1], tolerance_s)).reshape(-1, 2)
    t0 = np.asarray(times[0], float)
    sets = np.full((len(t0), n_cams), -1, int)
    sets[:, 0] = np.arange(len(t0))
    tsum, tcount = np.where(np.isfinite(t0), t0, 0.0), np.isfinite(t0).astype(float)
    for c in range(1, n_cams):
        tc = np.asarray(times[c], float)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = np.where(tcount > 0, tsum / np.maximum(tcount, 1), np.nan)
        i_set, i_c = pair_frames(mean, tc, tolerance_s)
        sets[i_set, c] = i_c
        tsum[i_set] += tc[i_c]
        tcount[i_set] += 1
        alone = np.setdiff1d(np.flatnonzero(np.isfinite(tc)), i_c)
        if alone.size:
            extra = np.full((alone.size, n_cams), -1, int)
            extra[:, c] = alone
            sets = np.vstack([sets, extra])
            tsum = np.concatenate([tsum, tc[alone]])
            tcount = np.concatenate([tcount, np.ones(alone.size)])
    keep = (sets >= 0).sum(axis=1) >= min_cameras
    sets, tsum, tcount = sets[keep], tsum[keep], tcount[keep]
    order = np.argsort(tsum / np.maximum(tcount, 1), kind="stable")
    return sets[order]


def frame_period(t: np.ndarray) -> float:
    """The median interval (s) between a camera's frames."""
    d = np.diff(np.sort(t[np.isfinite(t)]))
    d = d[d > 1e-4]
    if d.size == 0:
        raise DataError("too few frames to pair (need at least 2 per camera)")
    return float(np.median(d))
