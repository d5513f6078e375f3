"""Marker identities over time: one tracker, run live or over a recording.

:class:`MarkerTracks` is the rule, an online object: each instant's 3D points are joined to the
tracks alive by :func:`assign` (nearest within ``gate_mm`` of a track's last position, the least
total distance when several compete); a point left over starts a new id (ids count from 1); a
track unseen for more than ``max_gap_s`` ends. The live path feeds it one frame set at a time
(:mod:`vts_hw.tracking.live.reference`, with no track end); :func:`track_identities` is the
batch form the offline processing uses: the same object run over a recording's frame sets in
time order, so the same points give the same ids on both paths (docs/decisions/0018-processing.md,
"Identities"; 0090).

:func:`assign` is also the live estimator's assignment of points to the positions its model
predicts.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["assign", "MarkerTracks", "track_identities"]

_NONE = np.zeros(0, int)


def assign(predicted: np.ndarray, points: np.ndarray, gate_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """``(i_pred, i_point)``: one-to-one pairs within ``gate_mm``, least total distance (the
    Hungarian method: the most pairs within the gate, then the least sum), sorted by ``i_pred``."""
    return _pairs(_xyz(predicted), _xyz(points), gate_mm)


def _pairs(predicted: np.ndarray, points: np.ndarray, gate_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`assign` of two (N, 3) float arrays."""
    if len(predicted) == 0 or len(points) == 0:
        return _NONE, _NONE
    diff = predicted[:, None, :] - points[None, :, :]
    d = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))
    cost = np.where(d <= gate_mm, d, 1e9)
    r, c = linear_sum_assignment(cost)
    keep = cost[r, c] <= gate_mm
    return r[keep], c[keep]


def _xyz(a) -> np.ndarray:
    """``a`` as an (N, 3) array of floats (no copy when it is one)."""
    if type(a) is np.ndarray and a.dtype == np.float64 and a.ndim == 2 and a.shape[1] == 3:
        return a
    return np.asarray(a, float).reshape(-1, 3)


class MarkerTracks:
    """The identity tracker (see the module docstring): :meth:`update` with each instant's
    points, in time order, gives their ids."""

    def __init__(self, gate_mm: float = 15.0, max_gap_s: float = 1.0):
        self.gate_mm, self.max_gap_s = float(gate_mm), float(max_gap_s)
        self.ids = np.zeros(0, int)  # the tracks alive: their ids,
        self.pos = np.zeros((0, 3))  # last positions (mm)
        self.last = np.zeros(0)  # and when they were last seen (s)
        self.next_id = 1

    def update(self, t: float, points: np.ndarray) -> np.ndarray:
        """The id of each point (N,) seen at ``t`` (s)."""
        points = _xyz(points)
        if len(self.ids) and t - self.last.min() > self.max_gap_s:
            alive = (t - self.last) <= self.max_gap_s
            self.ids, self.pos, self.last = self.ids[alive], self.pos[alive], self.last[alive]
        got = np.zeros(len(points), int)
        r, c = _pairs(self.pos, points, self.gate_mm)
        if len(r):
            got[c] = self.ids[r]
            self.pos[r] = points[c]
            self.last[r] = t
        if len(r) < len(points):
            new = (got == 0).nonzero()[0]
            got[new] = np.arange(self.next_id, self.next_id + new.size)
            self.next_id += new.size
            self.ids = np.concatenate([self.ids, got[new]])
            self.pos = np.vstack([self.pos, points[new]])
            self.last = np.concatenate([self.last, np.full(new.size, float(t))])
        return got


def track_identities(
    frame_of_point: np.ndarray, times: np.ndarray, points: np.ndarray, gate_mm: float = 15.0, max_gap_s: float = 1.0
) -> np.ndarray:
    """Marker ids (ints from 1) of points (Nx3, mm) grouped by ``frame_of_point`` (sorted),
    frames at ``times`` (s): :class:`MarkerTracks` run over the frames in order."""
    n = len(points)
    ids = np.zeros(n, int)
    if n == 0:
        return ids
    frame_of_point = np.asarray(frame_of_point)
    bounds = np.flatnonzero(np.diff(frame_of_point)) + 1
    starts, ends = np.concatenate([[0], bounds]).tolist(), np.concatenate([bounds, [n]]).tolist()
    tracks = MarkerTracks(gate_mm, max_gap_s)
    t_of = np.asarray(times, float)[frame_of_point[starts]].tolist()
    points, update = _xyz(points), tracks.update
    for s0, s1, t in zip(starts, ends, t_of):
        ids[s0:s1] = update(t, points[s0:s1])
    return ids
