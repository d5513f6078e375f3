"""Marker identities online: each instant's 3D points joined to the tracks alive.

The online form of :func:`vts_hw.tracking.identities.track_identities`: nearest neighbour
within ``gate_mm`` (Hungarian when several compete), a point left over starts a new id, a
track unseen for ``max_gap_s`` ends. Also :func:`assign`, the one-to-one assignment of points
to predicted positions used once the reference is known.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["MarkerTracks", "assign"]


def assign(predicted: np.ndarray, points: np.ndarray, gate_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """``(i_pred, i_point)``: one-to-one pairs within ``gate_mm``, least total distance."""
    predicted = np.asarray(predicted, float).reshape(-1, 3)
    points = np.asarray(points, float).reshape(-1, 3)
    if len(predicted) == 0 or len(points) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    D = np.linalg.norm(predicted[:, None, :] - points[None, :, :], axis=2)
    cost = np.where(D <= gate_mm, D, 1e6)
    r, c = linear_sum_assignment(cost)
    ok = cost[r, c] <= gate_mm
    return r[ok], c[ok]


class MarkerTracks:
    def __init__(self, gate_mm: float = 15.0, max_gap_s: float = 1.0):
        self.gate_mm, self.max_gap_s = gate_mm, max_gap_s
        self.ids: list[int] = []
        self.pos = np.zeros((0, 3))
        self.last = np.zeros(0)
        self.next_id = 0

    def update(self, t: float, points: np.ndarray) -> np.ndarray:
        """The id of each point (N,)."""
        points = np.asarray(points, float).reshape(-1, 3)
        alive = (t - self.last) <= self.max_gap_s
        if not alive.all():
            self.ids = [i for i, a in zip(self.ids, alive) if a]
            self.pos, self.last = self.pos[alive], self.last[alive]
        got = np.full(len(points), -1)
        r, c = assign(self.pos, points, self.gate_mm)
        got[c] = np.asarray(self.ids, int)[r] if len(r) else got[c]
        self.pos[r], self.last[r] = points[c], t
        new = np.flatnonzero(got < 0)
        if new.size:
            got[new] = np.arange(self.next_id, self.next_id + new.size)
            self.next_id += new.size
            self.ids += got[new].tolist()
            self.pos = np.vstack([self.pos, points[new]])
            self.last = np.concatenate([self.last, np.full(new.size, t)])
        return got
