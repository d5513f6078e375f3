"""Motion states: intervals of similar pose, and the time each one really covers.

* :func:`motion_states`: a state ends at an event whose change from the state's pose is over
  ``state_mm`` (the markers' centroid) or ``state_deg`` (the boundary at the event's middle),
  or where the pose has drifted that far for ``persist_s`` (a slow creep). Each state's pose:
  the median over its frames that are not moving. The states' spans tile the scan.
* :func:`cover_states`: the time a state **covers** is its time with a pose. Time without a
  pose (no frames, fewer than 3 markers) is covered by no state, unless it is **bridged**: it
  lasts at most ``bridge_s``, lies inside one state away from every event, and the pose on
  both sides agrees within ``event_mm`` at every reference marker and ``event_deg`` (medians
  over ``settle_s`` either side): nothing the analysis could have seen happened there. Any
  other unknown time is listed as such (``subsets.json``'s ``unknown_s``), never given to a state
  (docs/decisions/0046-time-without-frames.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from vts_hw.motion.events import compare_poses, median_pose, relative_six_dof
from vts_hw.motion.signal import sample_rate
from vts_hw.motion.timeline import runs

__all__ = ["MotionState", "motion_states", "cover_states", "BRIDGE_S"]

BRIDGE_S = 2.0


@dataclass
class MotionState:
    index: int
    t_start: float
    t_end: float
    six_dof: list = field(default_factory=list)  # from the reference
    R: np.ndarray | None = None
    T: np.ndarray | None = None
    frames: int = 0
    moving_frames: int = 0
    intervals: list = field(default_factory=list)  # [start, end) the state covers (see cover_states)
    unknown_s: float = 0.0  # time of its span it does not cover

    def to_json(self, t0: float = 0.0) -> dict:
        return {
            "state": self.index,
            "t_start": self.t_start - t0,
            "t_end": self.t_end - t0,
            "intervals_s": [[a - t0, b - t0] for a, b in self.intervals],
            "unknown_s": self.unknown_s,
            "six_dof": [float(x) for x in self.six_dof],
            "frames": self.frames,
            "moving_frames": self.moving_frames,
        }


def motion_states(
    pose,
    events,
    moving,
    markers_ref,
    *,
    state_mm: float = 2.0,
    state_deg: float = 1.0,
    persist_s: float = 1.0,
    settle_s: float = 1.0,
):
    """The motion states (see the module), in time order, their spans tiling every row."""
    t = pose.t
    valid = pose.valid
    centre = pose.centre
    C = pose.points(centre[None])[:, 0]  # (F, 3) the centroid carried
    ang_ref = lambda R0, k: np.degrees(Rotation.from_matrix(pose.R[k] @ R0.T).magnitude())  # noqa: E731
    bounds = [float(t[0])]
    t_first = float(t[valid][0]) if valid.any() else float(t[0])
    ref_R, ref_T = median_pose(pose, (t <= t_first + settle_s) & ~moving)
    if ref_R is None:
        ref_R, ref_T = np.eye(3), np.zeros(3)
    ev_iter = iter(sorted(events, key=lambda e: e.t_start))
    ev = next(ev_iter, None)
    fs = sample_rate(t)
    n_persist = max(1, int(round(persist_s * fs)))
    over = 0
    k = 0
    while k < len(t):
        if ev is not None and t[k] >= ev.t_start:
            after = (t > ev.t_end) & (t <= ev.t_end + settle_s) & ~moving
            R1, T1 = median_pose(pose, after)
            if R1 is not None:
                _, c, ang = compare_poses(ref_R, ref_T, R1, T1, markers_ref, centre)
                if c > state_mm or ang > state_deg:
                    bounds.append(ev.t_mid)
                    ref_R, ref_T = R1, T1
            k = int(np.searchsorted(t, ev.t_end, side="right"))
            ev = next(ev_iter, None)
            over = 0
            continue
        if valid[k] and not moving[k]:
            c = float(np.linalg.norm(C[k] - (ref_R @ centre + ref_T)))
            far = c > state_mm or ang_ref(ref_R, k) > state_deg
            over = over + 1 if far else 0
            if over >= n_persist:
                k0 = k - n_persist + 1
                bounds.append(float(t[k0]))
                R1, T1 = median_pose(pose, (t >= t[k0]) & (t <= t[k0] + settle_s) & ~moving)
                ref_R, ref_T = (R1, T1) if R1 is not None else (pose.R[k], pose.T[k])
                over = 0
        k += 1
    bounds.append(float(t[-1]) + 0.5 / fs)
    states = []
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        sel = (t >= a) & (t < b)
        R, T = median_pose(pose, sel & ~moving)
        if R is None:
            R, T = median_pose(pose, sel)
        six = relative_six_dof(np.eye(3), np.zeros(3), R, T).tolist() if R is not None else [float("nan")] * 6
        states.append(MotionState(i, a, b, six, R, T, int((sel & valid).sum()), int((sel & moving).sum())))
    return states


def state_rows(states, t) -> np.ndarray:
    """(F,) the state whose span holds each row."""
    out = np.full(len(t), -1)
    for s in states:
        out[(t >= s.t_start) & (t < s.t_end)] = s.index
    return out


def cover_states(
    states,
    pose,
    moving,
    markers_ref,
    period: float,
    *,
    event_mm: float = 1.0,
    event_deg: float = 0.5,
    bridge_s: float = BRIDGE_S,
    settle_s: float = 1.0,
):
    """Fill each state's ``intervals`` and ``unknown_s`` (see the module). Returns ``(covered,
    bridged)``: (F,) the rows some state covers, and the bridged stretches as [start, end) s."""
    t = pose.t
    valid = pose.valid
    rows = state_rows(states, t)
    covered = valid.copy()
    bridged = []
    F = len(t)
    for a, b in runs(~valid):
        if a == 0 or b == F or (b - a) * period > bridge_s + 1e-9 or rows[a - 1] != rows[b]:
            continue
        if moving[max(0, a - 1) : min(F, b + 1)].any():
            continue
        R0, T0 = median_pose(pose, (t >= t[a - 1] - settle_s) & (t < t[a]))
        R1, T1 = median_pose(pose, (t > t[b - 1]) & (t <= t[b] + settle_s))
        if R0 is None or R1 is None:
            continue
        shift, _, ang = compare_poses(R0, T0, R1, T1, markers_ref, pose.centre)
        if shift < event_mm and ang < event_deg:
            covered[a:b] = True
            bridged.append([float(t[a] - period / 2), float(t[b - 1] + period / 2)])
    for s in states:
        sel = covered & (rows == s.index)
        s.intervals = [
            [max(float(t[a] - period / 2), s.t_start), min(float(t[b - 1] + period / 2), s.t_end)] for a, b in runs(sel)
        ]
        s.unknown_s = float(np.count_nonzero((rows == s.index) & ~covered) * period)
    return covered, bridged
