"""Body-motion events from the body's pose, with time without a pose kept unknown.

* **Speed** (:func:`body_speed`): how fast the patient's markers move with the body (the
  largest speed of the reference markers carried by the pose; breathing is not in the pose),
  from the poses ``half_window_s`` either side -- the whole window within the stretch of seen
  time the frame is in (holes of a few frames are stepped over; a gap is not): no smoothing
  filter, so an event keeps its start, and no speed is made up across time without a pose, nor
  from the frames at a gap's edge (NaN there).
* **Events** (:func:`find_events`): runs of speed above ``hi`` (the larger of ``min_speed``
  and ``k_hi`` times the speed's robust noise), widened while the speed stays above ``lo``;
  runs closer than ``merge_s``, or with only unknown time between them, joined; kept when the
  pose after differs from the pose before (medians over ``settle_s``) by ``event_mm`` (any
  reference marker) or ``event_deg``. A run that begins (ends) where the pose is unknown has
  its start (end) **bounded**: the move began somewhere between the last pose seen still
  before that stretch and the first seen moving after it (``start_bounds``), and the event
  spans the whole bound. A pose that differs across a stretch without a pose, with no motion
  seen on either side (its poses from frames not seen moving, at least 0.2 s each side), is an
  event inside it: start and end bounded by the stretch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from vts_hw.motion.signal import sample_rate
from vts_hw.motion.timeline import MAX_HOLE_S, runs, seen_runs

__all__ = ["MotionEvent", "body_speed", "find_events", "relative_six_dof", "median_pose", "compare_poses"]


@dataclass
class MotionEvent:
    t_start: float
    t_end: float
    change: list  # tx, ty, tz mm, rx, ry, rz deg: pose after relative to before
    shift_mm: float  # largest displacement of a reference marker
    angle_deg: float
    centre_mm: float  # displacement of the markers' centroid
    start_bounds: tuple | None = None  # (earliest, latest) when the start fell in unknown time
    end_bounds: tuple | None = None
    start_why: str = "no pose"  # why the start is bounded: "no pose", "noisy pose"

    @property
    def t_mid(self) -> float:
        return 0.5 * (self.t_start + self.t_end)

    @property
    def start_known(self) -> str:
        return "measured" if self.start_bounds is None else "bounded"

    def to_json(self, t0: float = 0.0) -> dict:
        b = lambda x: None if x is None else [float(x[0]) - t0, float(x[1]) - t0]  # noqa: E731
        return {
            "t_start": self.t_start - t0,
            "t_end": self.t_end - t0,
            "duration_s": self.t_end - self.t_start,
            "start": self.start_known,
            "start_bounds_s": b(self.start_bounds),
            "start_bounded_why": None
            if self.start_bounds is None
            else (
                "in time without a pose"
                if self.start_why == "no pose"
                else "the pose too noisy there to time it (its speed's jitter as high as the move's)"
            ),
            "end": "measured" if self.end_bounds is None else "bounded",
            "end_bounds_s": b(self.end_bounds),
            "change_6dof": [float(x) for x in self.change],
            "max_marker_shift_mm": self.shift_mm,
            "centroid_shift_mm": self.centre_mm,
            "rotation_deg": self.angle_deg,
        }


def _mad_sigma(x):
    x = x[np.isfinite(x)]
    if x.size == 0:
        return 0.0
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def body_speed(pose, markers_ref, half_window_s: float = 0.2, min_span_s: float = 0.3):
    """(F,) mm/s: the largest speed of the reference markers carried by the pose (see the
    module); NaN without a pose, or where the window of ``half_window_s`` either side does not
    lie in the frame's stretch of seen time (holes of a few frames are stepped over, as long as
    ``min_span_s`` of it is left)."""
    t = pose.t
    X = pose.points(markers_ref)  # (F, K, 3)
    valid = pose.valid
    F = len(t)
    sp = np.full(F, np.nan)
    if F < 2 or not valid.any():
        return sp
    fs = sample_rate(t)
    h = max(1, int(round(half_window_s * fs)))
    idx = np.arange(F)
    prev_ok = np.maximum.accumulate(np.where(valid, idx, -1))  # last valid <= k
    next_ok = np.minimum.accumulate(np.where(valid, idx, F)[::-1])[::-1]  # first valid >= k
    for a, b in seen_runs(valid, 1.0 / fs, MAX_HOLE_S):
        k = np.arange(a + h, b - h)  # the whole window inside the stretch: a frame at a
        if k.size == 0:  # gap's edge (its pose fitted from fewer markers,
            continue  # views not time-aligned) never makes a speed
        lo = next_ok[k - h]
        hi = prev_ok[k + h]
        dt = t[hi] - t[lo]
        good = valid[k] & (dt >= min_span_s)
        d = np.linalg.norm(X[hi[good]] - X[lo[good]], axis=2).max(axis=1)
        sp[k[good]] = d / dt[good]
    return sp


def median_pose(pose, sel):
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


def compare_poses(R0, T0, R1, T1, markers_ref, centre):
    """(largest marker shift mm, centroid shift mm, turn deg) from pose 0 to pose 1."""
    X0 = markers_ref @ R0.T + T0
    X1 = markers_ref @ R1.T + T1
    shift = float(np.linalg.norm(X1 - X0, axis=1).max())
    c = float(np.linalg.norm((R1 @ centre + T1) - (R0 @ centre + T0)))
    ang = float(np.degrees(Rotation.from_matrix(R1 @ R0.T).magnitude()))
    return shift, c, ang


def _known_before(sp, k):
    """The last index before ``k`` with a known speed (-1: none)."""
    j = np.flatnonzero(np.isfinite(sp[:k]))
    return int(j[-1]) if j.size else -1


def _known_after(sp, k):
    j = np.flatnonzero(np.isfinite(sp[k:]))
    return int(k + j[0]) if j.size else -1


def _step_over_holes(sp, period):
    """``sp`` with each run of unknown speed of at most MAX_HOLE_S between two known ones given
    the larger of those two (the speed cannot drop and rise again unseen in a frame or two)."""
    sp = sp.copy()
    known = np.isfinite(sp)
    for a, b in runs(~known):
        if a > 0 and b < len(sp) and (b - a) * period <= MAX_HOLE_S + 1e-9:
            sp[a:b] = max(sp[a - 1], sp[b])
    return sp


def _local_noise(t, sp, window_s: float, step: int = 5, least: int = 25):
    """(median, robust sigma) of the speed known within ``window_s`` of each frame (computed
    every ``step`` frames, held between); 0 where fewer than ``least`` speeds are known (the
    scan's own thresholds then hold)."""
    F = len(t)
    med, sig = np.zeros(F), np.zeros(F)
    ok = np.isfinite(sp)
    for k in range(0, F, step):
        w = ok & (np.abs(t - t[k]) <= window_s)
        if w.sum() >= least:
            x = sp[w]
            m = float(np.median(x))
            med[k : k + step], sig[k : k + step] = m, 1.4826 * float(np.median(np.abs(x - m)))
    return med, sig


def find_events(
    pose,
    markers_ref,
    *,
    min_speed: float = 1.0,
    k_hi: float = 6.0,
    k_lo: float = 2.5,
    merge_s: float = 0.5,
    settle_s: float = 1.0,
    event_mm: float = 1.0,
    event_deg: float = 0.5,
    min_duration_s: float = 0.1,
    half_window_s: float = 0.2,
    noise_window_s: float = 5.0,
):
    """(events, speed, moving mask, thresholds dict). See the module."""
    t = pose.t
    sp = body_speed(pose, markers_ref, half_window_s)
    sigma = _mad_sigma(sp)
    med = float(np.nanmedian(sp)) if np.isfinite(sp).any() else 0.0
    hi = max(min_speed, med + k_hi * sigma)
    lo = max(0.4 * min_speed, med + k_lo * sigma)
    F = len(t)
    period = 1.0 / sample_rate(t)
    # where the pose is noisier than the scan's (fewer markers, a worse fit), the thresholds
    # rise with the speed's noise around that frame: its jitter would pass the scan's own
    l_med, l_sig = _local_noise(t, sp, noise_window_s)
    hi_f = np.maximum(hi, l_med + k_hi * l_sig)
    lo_f = np.maximum(lo, l_med + k_lo * l_sig)
    measured = sp
    sp = _step_over_holes(sp, period)  # a missing frame or two is no unknown time
    known = np.isfinite(sp)
    x = np.nan_to_num(sp, nan=0.0)

    def spans_of(above, low, lo_i=0, hi_i=F):
        """Runs of ``above`` widened while the speed stays over ``low``, within [lo_i, hi_i);
        runs closer than merge_s, or with only unknown time between, joined."""
        out = []
        for a, b in runs(above[lo_i:hi_i]):
            a, b = a + lo_i, b + lo_i
            while a > lo_i and x[a - 1] > low[a - 1]:
                a -= 1
            while b < hi_i and x[b] > low[b]:
                b += 1
            if out and (t[a] - t[out[-1][1] - 1] < merge_s or not known[out[-1][1] : a].any()):
                out[-1] = (out[-1][0], max(b, out[-1][1]))
            else:
                out.append((a, b))
        return out

    # runs over the scan's thresholds; where the pose is noisier there, only the parts over the
    # thresholds of its own noise (jitter chained by the merging put a start seconds early); a
    # run nowhere over them stays whole, for the pose change across it to judge (a small move)
    spans: list = []
    noisy: set = set()
    for a, b in spans_of(x > hi, np.full(F, lo)):
        inner = spans_of(x > hi_f, lo_f, a, b)
        spans += inner if inner else [(a, b)]
        if not inner and (hi_f[a:b] > hi + 1e-9).any():
            noisy.add((a, b))  # its start cannot be told from the jitter: bounded (by its peak)
    events = []
    moving = np.zeros(F, bool)
    centre = pose.centre

    def judge(i0, i1, ta, tb, start_b=None, end_b=None, jump=False):
        """An event from ``ta`` to ``tb`` when the pose up to row ``i0`` (medians over settle_s)
        and from row ``i1`` differ by event_mm or event_deg."""
        before = (t >= t[i0] - settle_s) & (t <= t[i0])
        after = (t >= t[i1]) & (t <= t[i1] + settle_s)
        if jump:  # no frame seen moving on either side (a stretch
            still = ~(np.nan_to_num(sp) > lo_f) & ~moving  # too short for a speed counts)
            before, after = before & still & pose.valid, after & still & pose.valid
            if min(before.sum(), after.sum()) * period < 0.2:
                return None
        R0, T0 = median_pose(pose, before)
        R1, T1 = median_pose(pose, after)
        if R0 is None or R1 is None:
            return None
        shift, c, ang = compare_poses(R0, T0, R1, T1, markers_ref, centre)
        kept = shift >= event_mm or ang >= event_deg
        if kept or not jump:
            moving[(t >= ta) & (t <= tb)] = True
        if kept:
            if start_b is not None and start_b[1] > tb:
                start_b = (start_b[0], tb)  # a move starts before it ends
            return MotionEvent(ta, tb, relative_six_dof(R0, T0, R1, T1).tolist(), shift, ang, c, start_b, end_b)
        return None

    # a frame's speed spans +-half_window_s: a move may have begun that much before the last frame
    # seen still, and the first frame seen moving may be that much early: bounds are widened so
    h = half_window_s
    touched = np.zeros(F, bool)
    for a, b in spans:
        if a == 0 or b == F:
            continue  # no pose before (after) it to compare with
        start_b = end_b = None
        i0, i1 = a - 1, b
        if not known[a - 1]:  # it began in time without a pose
            i0 = _known_before(sp, a)
            if i0 < 0:
                continue
            start_b = (float(t[i0]) - h, float(t[a]) + h)
        if not known[b]:  # it ended in time without a pose
            i1 = _known_after(sp, b)
            if i1 < 0:
                continue
            end_b = (float(t[b - 1]) - h, float(t[i1]) + h)
        touched[i0 : i1 + 1] = True
        if t[b - 1] - t[a] < min_duration_s and start_b is None and end_b is None:
            continue
        why = "no pose"
        if start_b is None and (a, b) in noisy:  # begun by its fastest frame, at the latest
            start_b, why = (float(t[a]) - h, float(t[a + int(np.argmax(x[a:b]))]) + h), "noisy pose"
        e = judge(
            i0, i1, start_b[0] if start_b else float(t[a]), end_b[1] if end_b else float(t[b - 1]), start_b, end_b
        )
        if e is not None:
            e.start_why = why
            events.append(e)
    # a pose that changed across time without a pose, with no motion seen at its edges
    for a, b in runs(~pose.valid):
        if a == 0 or b == F or (b - a) * period <= MAX_HOLE_S + 1e-9 or touched[a - 1 : b + 1].any():
            continue  # (a move takes longer than a hole of a few frames)
        bound = (float(t[a - 1]) - h, float(t[b]) + h)
        e = judge(a - 1, b, bound[0], bound[1], bound, bound, jump=True)
        if e is not None:
            events.append(e)
    events.sort(key=lambda e: e.t_start)
    raised = hi_f > hi + 1e-9
    return (
        events,
        measured,
        moving,
        {
            "hi_mm_s": hi,
            "lo_mm_s": lo,
            "noise_mm_s": sigma,
            "hi_max_mm_s": float(hi_f.max()) if F else hi,
            "raised_s": float(raised.sum() * period),
        },
    )
