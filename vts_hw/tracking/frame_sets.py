"""Frame sets across cameras: one grouping rule, run live or over a recording.

A camera's frame time is its stamp mapped to host time: offline by the camera's clock fit
(:func:`mapped_times`, :mod:`vts_hw.timing.camera_clock`), live by the clock offset measured when
the scan started (:mod:`vts_hw.tracking.live.tracker`); a frame with no stamp has its receipt
time. Only these host times are compared (the cameras' own clocks may differ by seconds).

**The rule** (:class:`FrameGrouper`, docs/decisions/0090). Each camera's frames are taken in the
order it sent them. The oldest first-pending frame of any camera opens a set; the other cameras'
first pending frames, nearest in time first, join it while each is within ``tolerance_s`` of the
mean time of the frames already in it (half a frame period: a frame never joins its partner's
neighbour). The set is decided once every camera has a frame pending -- one that joined, or a
later one that did not -- or is not waited for (below); a set of two cameras or more goes out,
in time order; a frame alone goes into no set and is counted (``unmatched``).

**Waiting** (live only: the live path cannot see the frames still on their way). A camera with
nothing pending may still send a frame for the set: it is waited for while it is not quiet (a
frame from it within ``wait_s``; a camera that has sent nothing yet, within ``wait_s`` of the
first frame of any: the cameras do not all start at once), and by a set of one camera even when quiet (after a gap, one
camera's first frames may come back later than the other's), but never for longer than
``wait_s`` after the set's first frame arrived; then the set goes with the cameras it has.
``wait_s`` is longer than a frame period: on a busy host one camera's frames may arrive a few
hundred milliseconds after the other's, and a set given up too soon is two frames lost
(docs/decisions/0048).

**Offline** (:func:`group_frames`): a recording's frames run through the same object, every
frame there from the start and the recording's end deciding the last sets: the same frames
give the same sets on both paths, whenever the live path did not give up waiting.
:func:`frame_period` is a camera's frame interval.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from vts_hw.errors import DataError
from vts_hw.recording.frames import CameraFrames
from vts_hw.timing.camera_clock import fit_camera_clock

__all__ = ["mapped_times", "Pending", "FrameSet", "FrameGrouper", "group_frames", "frame_period"]

_NO_UV = np.zeros((0, 2))


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
            return (
                cf.host_time - latency_s,
                None,
                [f"{cf.name}: no camera clock fit (too few stamped frames with a receive time); receive times used"],
            )
        return (
            cf.camera_time.copy(),
            None,
            [f"{cf.name}: no host receive times; the camera's own clock used as host time"],
        )
    t = np.atleast_1d(fit.frame_host_times()).copy()
    missing = ~np.isfinite(t)
    if missing.any():
        stamp_only = missing & np.isfinite(cf.camera_time)
        t[stamp_only] = fit.host_time(cf.camera_time[stamp_only])
        recv_only = missing & ~stamp_only
        med = float(np.nanmedian(fit.residuals_s)) if np.isfinite(fit.residuals_s).any() else 0.0
        t[recv_only] = cf.host_time[recv_only] - med - latency_s
    return t, fit, []


@dataclass(slots=True)
class Pending:
    """One camera's frame waiting for its set."""

    camera: int
    time: float  # host s
    arrival: float  # monotonic s it arrived at the tap (offline: unused, 0)
    uv: np.ndarray  # (k, 2) detections (px)
    norm: np.ndarray | None = None  # their normalized (undistorted) coordinates
    capture: float | None = None  # monotonic s it was captured (arrival less its extra delay)
    index: int = -1  # its place in its camera's frames (offline)


@dataclass(slots=True)
class FrameSet:
    time: float  # mean host s of its frames
    uv: list[np.ndarray | None]  # per camera its detections, None: not in the set
    norm: list[np.ndarray | None]  # and their normalized coordinates
    first_arrival: float
    last_arrival: float
    capture: float = 0.0  # monotonic s its frames were captured (mean; see Pending)
    index: list = field(default_factory=list)  # per camera its frame's ``Pending.index``, -1: none

    @property
    def n_cameras(self) -> int:
        return sum(u is not None for u in self.uv)


class FrameGrouper:
    """The grouping rule (module docstring), online: :meth:`add` each camera's frames in the
    order the camera sent them, :meth:`ready` gives the sets decided; ``unmatched`` counts the
    frames that went into no set."""

    def __init__(self, n_cameras: int, tolerance_s: float, wait_s: float, min_cameras: int = 2):
        self.n = n_cameras
        self.tolerance_s, self.wait_s = float(tolerance_s), float(wait_s)
        self.min_cameras = int(min_cameras)
        self.pending: list[deque[Pending]] = [deque() for _ in range(n_cameras)]
        self.last_arrival: list[float | None] = [None] * n_cameras
        self.started: float | None = None  # the first frame's arrival (a camera that has sent
        self.unmatched = 0  # nothing is quiet from then on)

    def add(self, p: Pending) -> None:
        self.pending[p.camera].append(p)
        self.last_arrival[p.camera] = p.arrival
        if self.started is None:
            self.started = p.arrival

    def ready(self, now: float, final: bool = False) -> list[FrameSet]:
        """The sets decided at monotonic ``now``, oldest first. ``final``: no camera sends
        another frame (the end of a recording): every set is decided."""
        out: list[FrameSet] = []
        pending, n, tol, least = self.pending, self.n, self.tolerance_s, self.min_cameras
        while True:
            heads = [(q[0].time, c) for c, q in enumerate(pending) if q]
            if not heads:
                return out
            heads.sort()
            t0, c0 = heads[0]
            members: list[Pending | None] = [None] * n
            got = [pending[c0][0]]
            members[c0] = got[0]
            total, k = t0, 1
            for t, c in heads[1:]:
                if t - total / k > tol:  # later heads are further still
                    break
                members[c] = p = pending[c][0]
                got.append(p)
                total += t
                k += 1
            if len(heads) < n and not final and self._waits(now, got, k < least):
                return out
            for p in got:
                pending[p.camera].popleft()
            if k < least:
                self.unmatched += k
                continue
            arrival = [p.arrival for p in got]
            capture = [p.arrival if p.capture is None else p.capture for p in got]
            out.append(
                FrameSet(
                    total / k,
                    [None if p is None else p.uv for p in members],
                    [None if p is None else p.norm for p in members],
                    min(arrival),
                    max(arrival),
                    sum(capture) / k,
                    [-1 if p is None else p.index for p in members],
                )
            )

    def _waits(self, now: float, got: list[Pending], alone: bool) -> bool:
        """Whether the set of ``got`` waits for a camera with nothing pending: one not quiet
        (a frame from it within ``wait_s``; one that has sent none: within ``wait_s`` of the
        first frame of any), or any when the set is ``alone`` (fewer cameras than it needs), at
        most ``wait_s`` after its first frame arrived."""
        first = min(p.arrival for p in got)
        if now - first >= self.wait_s:
            return False
        started = first if self.started is None else self.started  # None only before any frame came
        return any(
            not q and (alone or now - (started if last is None else last) < self.wait_s)
            for q, last in zip(self.pending, self.last_arrival)
        )


def group_frames(times: list[np.ndarray], tolerance_s: float, min_cameras: int = 2) -> np.ndarray:
    """Frame sets of N cameras over a whole recording: (S, N) frame indices (-1: that camera
    has no frame in the set), in time order. The batch form of :class:`FrameGrouper`: each
    camera's frames with a time, in their order, run through the same rule as the live path
    (the recording's end decides the last sets); frames with NaN times join no set."""
    g = FrameGrouper(len(times), tolerance_s, math.inf, min_cameras)
    for c, t in enumerate(times):
        t = np.asarray(t, float)
        for i, ti in zip(np.flatnonzero(np.isfinite(t)).tolist(), t[np.isfinite(t)].tolist()):
            g.add(Pending(c, ti, 0.0, _NO_UV, None, None, i))
    sets = g.ready(0.0, final=True)
    return np.array([fs.index for fs in sets], int).reshape(-1, len(times))


def frame_period(t: np.ndarray) -> float:
    """The median interval (s) between a camera's frames."""
    d = np.diff(np.sort(t[np.isfinite(t)]))
    d = d[d > 1e-4]
    if d.size == 0:
        raise DataError("too few frames to pair (need at least 2 per camera)")
    return float(np.median(d))
