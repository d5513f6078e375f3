"""Every camera's view of a marker brought to one instant before it is triangulated.

The cameras of a rig are not triggered together: in a frame set, each camera's exposure is up to
half a frame period (20 ms at 25 fps) off the set's time. A marker moving at 50 mm/s has moved
1 mm in that time, and triangulating views of different instants puts the point off its path
(docs/decisions/0037-frame-time-alignment.md). Once the points have identities, each camera's
pixel centroid of a marker is interpolated along that marker's own track in that camera to the
frame set's time (the mean of its cameras' mapped exposure times), from the camera's frames just
before and just after; then the point is triangulated again from the aligned views. A view with
no frame of the same marker on the other side within ``max_gap_s`` is left as it was, and so
is a point whose views are all within ``min_dt_s`` of the set's time.
"""

from __future__ import annotations

import numpy as np

from vts_hw.vision.multiview import ViewGeometry, triangulate_groups

__all__ = ["align_views"]


def _interpolate(t: np.ndarray, uv: np.ndarray, target: np.ndarray, max_gap_s: float):
    """``uv`` (n, 2) sampled at sorted times ``t`` (n,), at ``target`` (m,): linear between the
    samples around each target when both exist and are at most ``max_gap_s`` apart; NaN else.
    (A cubic through two more samples was tried: no better on the simulated patient.)"""
    j = np.searchsorted(t, target, side="right")
    lo, hi = j - 1, j
    ok = (lo >= 0) & (hi < len(t))
    out = np.full((len(target), 2), np.nan)
    if not ok.any():
        return out
    lo, hi, tg = lo[ok], hi[ok], target[ok]
    span = t[hi] - t[lo]
    good = (span > 0) & (span <= max_gap_s)
    w = np.where(good, (tg - t[lo]) / np.where(span > 0, span, 1.0), np.nan)[:, None]
    out[np.flatnonzero(ok)] = uv[lo] + w * (uv[hi] - uv[lo])
    return out


def align_views(
    geo: ViewGeometry,
    point_frame: np.ndarray,
    marker: np.ndarray,
    uv: np.ndarray,
    view_time: np.ndarray,
    set_time: np.ndarray,
    max_gap_s: float,
    min_dt_s: float = 2e-4,
):
    """``(xyz, rms_px, uv_aligned, aligned_views)`` of every point after alignment.

    ``uv`` (N, 2C) pixels per point (NaN where a camera did not see it), ``view_time`` (F, C)
    each camera's mapped exposure time per frame set, ``set_time`` (F,) the sets' times,
    ``point_frame``/``marker`` (N,) each point's set and identity. Points none of whose views
    moved keep their old position (the caller's); the returned ``xyz`` is NaN there."""
    n, C = len(uv), len(geo.cams)
    uv_new = uv.copy()
    aligned = np.zeros((n, C), bool)
    if n == 0:
        return np.zeros((0, 3)), np.zeros(0), uv_new, 0
    target = set_time[point_frame]
    for c in range(C):
        seen = np.flatnonzero(~np.isnan(uv[:, 2 * c]))
        if seen.size == 0:
            continue
        t_view = view_time[point_frame[seen], c]
        off = np.abs(t_view - target[seen]) > min_dt_s
        for m in np.unique(marker[seen[off]]):
            mine = seen[marker[seen] == m]
            tm = view_time[point_frame[mine], c]
            order = np.argsort(tm, kind="stable")
            mine, tm = mine[order], tm[order]
            want = np.abs(tm - target[mine]) > min_dt_s
            if not want.any():
                continue
            val = _interpolate(tm, uv[mine, 2 * c : 2 * c + 2], target[mine[want]], max_gap_s)
            got = ~np.isnan(val[:, 0])
            rows = mine[want][got]
            uv_new[rows, 2 * c : 2 * c + 2] = val[got]
            aligned[rows, c] = True
    redo = np.flatnonzero(aligned.any(axis=1))
    xyz = np.full((n, 3), np.nan)
    rms = np.full(n, np.nan)
    if redo.size:
        obs = uv_new[redo].reshape(-1, C, 2)
        mask = ~np.isnan(obs[:, :, 0])
        norm = np.zeros_like(obs)
        for c in range(C):
            sel = mask[:, c]
            if sel.any():
                norm[sel, c] = geo.normalize(c, obs[sel, c])
        X, res = triangulate_groups(geo, np.nan_to_num(obs), norm, mask, iterations=2)
        xyz[redo] = X
        rms[redo] = np.sqrt(np.nanmean(res**2, axis=1))
    return xyz, rms, uv_new, int(aligned.sum())
