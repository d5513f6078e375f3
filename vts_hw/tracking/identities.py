"""Marker identities over time: each frame's 3D points joined to the tracks alive.

Nearest neighbour in 3D with a gate, Hungarian when several compete; a point left over starts
a new id; a track unseen for ``max_gap_s`` ends (docs/decisions/0018-processing.md).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["track_identities"]


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
