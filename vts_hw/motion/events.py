"""Body-motion events and motion states from the body's pose.

* **Speed** (:func:`body_speed`): how fast the patient's markers move with the body (the
  largest speed of the reference markers carried by the pose; breathing is not in the pose),
  from differences over ``half_window_s`` either side: no smoothing filter, so an event keeps
  its start.
* **Events** (:func:`find_events`): runs of speed above ``hi`` (the larger of ``min_speed``
  and ``k_hi`` times the speed's robust noise), widened while the speed stays above ``lo``;
  runs closer than ``merge_s`` joined; kept when the pose after differs from the pose before
  (medians over ``settle_s``) by ``event_mm`` (any reference marker) or ``event_deg``.
* **States** (:func:`motion_states`): intervals of similar pose. A state ends at an event whose
  change from the state's pose is over ``state_mm`` (the markers' centroid) or ``state_deg``
  (the boundary at the event's middle), or where the pose has drifted that far for
  ``persist_s`` (a slow creep). Each state's pose: the median over its frames that are not
  moving.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from vts_hw.motion.signal import sample_rate

__all__ = ["MotionEvent", "MotionState", "body_speed", "find_events", "motion_states", "relative_six_dof"]


@dataclass
class MotionEvent:
    t_start: float
    t_end: float
    change: list            # tx, ty, tz mm, rx, ry, rz deg: pose after relative to before
    shift_mm: float         # largest displacement of a reference marker
    angle_deg: float
    centre_mm: float        # displacement of the markers' centroid

    @property
    def t_mid(self) -> float:
        return 0.5 * (self.t_start + self.t_end)

    def to_json(self) -> dict:
        return {"t_start": self.t_start, "t_end": self.t_end, "duration_s": self.t_end - self.t_start,
                "change_6dof": [float(x) for x in self.change], "max_marker_shift_mm": self.shift_mm,
                "centroid_shift_mm": self.centre_mm, "rotation_deg": self.angle_deg}


@dataclass
class MotionState:
    index: int
    t_start: float
    t_end: float
    six_dof: list = field(default_factory=list)    # from the reference
    R: np.ndarray | None = None
    T: np.ndarray | None = None
    frames: int = 0
    moving_frames: int = 0

    def to_json(self) -> dict:
        return {"state": self.index, "t_start": self.t_start, "t_end": self.t_end,
                "six_dof": [float(x) for x in self.six_dof], "frames": self.frames,
                "moving_frames": self.moving_frames}


def _mad_sigma(x):
    x = x[np.isfinite(x)]
    if x.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def body_speed(pose, markers_ref, half_window_s: float = 0.2):
    """(F,) mm/s: the largest speed of the reference markers carried by the pose."""
    t = pose.t
    X = pose.points(markers_ref)                       # (F, K, 3)
    h = max(1, int(round(half_window_s * sample_rate(t))))
    sp = np.full(len(t), np.nan)
    if len(t) > 2 * h:
        d = np.linalg.norm(X[2 * h:] - X[:-2 * h], axis=2).max(axis=1)
        sp[h:-h] = d / (t[2 * h:] - t[:-2 * h])
    return sp


def _median_pose(pose, sel):
    sel = sel & pose.valid
    if not sel.any():
        return None, None
    R = Rotation.from_matrix(pose.R[sel]).mean().as_matrix()
    T = np.median(pose.T[sel], axis=0)
    return R, T


def relative_six_dof(R0, T0, R1, T1):
    """(R1,T1) ∘ (R0,T0)^-1 as tx, ty, tz, rx, ry, rz (deg, extrinsic x-y-z)."""
    R = R1 @ R0.T
    T = T1 - R @ T0
    return np.concatenate([T, Rotation.from_matrix(R).as_euler("xyz", degrees=True)])


def _compare(R0, T0, R1, T1, markers_ref, centre):
    X0 = markers_ref @ R0.T + T0
    X1 = markers_ref @ R1.T + T1
    shift = float(np.linalg.norm(X1 - X0, axis=1).max())
    c = float(np.linalg.norm((R1 @ centre + T1) - (R0 @ centre + T0)))
    ang = float(np.degrees(Rotation.from_matrix(R1 @ R0.T).magnitude()))
    return shift, c, ang


def find_events(pose, markers_ref, *, min_speed: float = 1.0, k_hi: float = 6.0, k_lo: float = 2.5,
                merge_s: float = 0.5, settle_s: float = 1.0, event_mm: float = 1.0, event_deg: float = 0.5,
                min_duration_s: float = 0.1, half_window_s: float = 0.2):
    """(events, speed, moving mask, thresholds dict). See the module."""
    t = pose.t
    sp = body_speed(pose, markers_ref, half_window_s)
    sigma = _mad_sigma(sp)
    med = float(np.nanmedian(sp)) if np.isfinite(sp).any() else 0.0
    hi = max(min_speed, med + k_hi * sigma)
    lo = max(0.4 * min_speed, med + k_lo * sigma)
    above = np.nan_to_num(sp, nan=0.0) > hi
    runs = []
    for a, b in _runs(above):
        while a > 0 and np.nan_to_num(sp[a - 1]) > lo:
            a -= 1
        while b < len(t) and np.nan_to_num(sp[b]) > lo:
            b += 1
        if runs and t[a] - t[runs[-1][1] - 1] < merge_s:
            runs[-1] = (runs[-1][0], max(b, runs[-1][1]))
        else:
            runs.append((a, b))
    events = []
    moving = np.zeros(len(t), bool)
    centre = pose.centre
    for a, b in runs:
        ta, tb = float(t[a]), float(t[b - 1])
        if tb - ta < min_duration_s:
            continue
        before = (t >= ta - settle_s) & (t < ta)
        after = (t > tb) & (t <= tb + settle_s)
        R0, T0 = _median_pose(pose, before)
        R1, T1 = _median_pose(pose, after)
        if R0 is None or R1 is None:
            continue
        shift, c, ang = _compare(R0, T0, R1, T1, markers_ref, centre)
        moving[a:b] = True
        if shift >= event_mm or ang >= event_deg:
            events.append(MotionEvent(ta, tb, relative_six_dof(R0, T0, R1, T1).tolist(), shift, ang, c))
    return events, sp, moving, {"hi_mm_s": hi, "lo_mm_s": lo, "noise_mm_s": sigma}


def _runs(mask):
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(int))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def motion_states(pose, events, moving, markers_ref, *, state_mm: float = 2.0, state_deg: float = 1.0,
                  persist_s: float = 1.0, settle_s: float = 1.0):
    """The motion states (see the module), in time order, covering every frame."""
    t = pose.t
    valid = pose.valid
    centre = pose.centre
    C = pose.points(centre[None])[:, 0]                      # (F, 3) the centroid carried
    ang_ref = lambda R0, k: np.degrees(Rotation.from_matrix(pose.R[k] @ R0.T).magnitude())  # noqa: E731
    bounds = [float(t[0])]
    ref_R, ref_T = _median_pose(pose, (t <= t[0] + settle_s) & ~moving)
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
            R1, T1 = _median_pose(pose, after)
            if R1 is not None:
                _, c, ang = _compare(ref_R, ref_T, R1, T1, markers_ref, centre)
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
                R1, T1 = _median_pose(pose, (t >= t[k0]) & (t <= t[k0] + settle_s) & ~moving)
                ref_R, ref_T = (R1, T1) if R1 is not None else (pose.R[k], pose.T[k])
                over = 0
        k += 1
    bounds.append(float(t[-1]) + 0.5 / fs)
    states = []
    for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        sel = (t >= a) & (t < b)
        R, T = _median_pose(pose, sel & ~moving)
        if R is None:
            R, T = _median_pose(pose, sel)
        six = relative_six_dof(np.eye(3), np.zeros(3), R, T).tolist() if R is not None else [float("nan")] * 6
        states.append(MotionState(i, a, b, six, R, T, int(sel.sum()), int((sel & moving).sum())))
    return states
