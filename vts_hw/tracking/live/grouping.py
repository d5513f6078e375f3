"""Frame sets across cameras, online: each camera's detections joined by host time.

A camera's frame time is its own stamp mapped to host time (stamp minus the camera's clock
offset, measured when the scan started), or its receipt time when it has no stamp. The
oldest pending frame opens a set; each other camera's pending frame nearest in time within
``tolerance_s`` joins. A set goes out as soon as every camera has joined, or -- when some
camera has nothing for it -- once that camera has sent a later frame, or has sent nothing for
``wait_s`` (a camera gone quiet is not waited for by a set of two or more cameras: they make
points without it), or ``wait_s`` has passed since the set's first frame arrived (then with
the cameras it has: two or more make points; fewer are counted as unmatched). ``wait_s`` is longer than a frame period: on a busy host one camera's
frames may arrive a few hundred milliseconds after the other's, and a set given up too soon
is two frames lost (docs/decisions/0048).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Pending", "FrameSet", "FrameGrouper"]


@dataclass
class Pending:
    camera: int
    time: float              # host s
    arrival: float           # monotonic s it arrived at the tap
    uv: np.ndarray           # (k, 2) detections (px)
    norm: np.ndarray | None = None   # their normalized (undistorted) coordinates
    capture: float | None = None     # monotonic s it was captured (arrival less its extra delay)


@dataclass
class FrameSet:
    time: float                      # mean host s of its frames
    uv: list[np.ndarray | None]      # per camera its detections, None: not in the set
    norm: list[np.ndarray | None]    # and their normalized coordinates
    first_arrival: float
    last_arrival: float
    capture: float = 0.0             # monotonic s its frames were captured (mean; see Pending)

    @property
    def n_cameras(self) -> int:
        return sum(u is not None for u in self.uv)


class FrameGrouper:
    def __init__(self, n_cameras: int, tolerance_s: float, wait_s: float):
        self.n = n_cameras
        self.tolerance_s, self.wait_s = tolerance_s, wait_s
        self.pending: list[list[Pending]] = [[] for _ in range(n_cameras)]
        self.last_arrival: list[float | None] = [None] * n_cameras
        self.unmatched = 0

    def add(self, p: Pending) -> None:
        self.pending[p.camera].append(p)
        self.last_arrival[p.camera] = p.arrival

    def ready(self, now: float) -> list[FrameSet]:
        """The sets complete (or given up waiting for) at monotonic ``now``, oldest first."""
        out = []
        while True:
            heads = [(q[0].time, c) for c, q in enumerate(self.pending) if q]
            if not heads:
                return out
            t0, c0 = min(heads)
            members: list[Pending | None] = [None] * self.n
            may_come = []                    # cameras that may still send a frame for this set
            for c, q in enumerate(self.pending):
                near = [p for p in q if abs(p.time - t0) <= self.tolerance_s]
                if near:
                    members[c] = min(near, key=lambda p: abs(p.time - t0))
                elif not any(p.time > t0 + self.tolerance_s for p in q):
                    may_come.append(c)
            # a quiet camera is waited for only by a set that is nothing without it (one camera:
            # after a gap, one camera's first frames may come back later than the other's)
            alone = sum(p is not None for p in members) < 2
            waiting = any(alone or (self.last_arrival[c] is not None and now - self.last_arrival[c] < self.wait_s)
                          for c in may_come)
            first = min(p.arrival for p in members if p is not None)
            if waiting and now - first < self.wait_s:
                return out
            for c, p in enumerate(members):
                if p is not None:
                    q = self.pending[c]
                    # frames of this camera older than its member never join a set
                    k = q.index(p)
                    self.unmatched += k
                    del q[:k + 1]
            got = [p for p in members if p is not None]
            if len(got) < 2:
                self.unmatched += len(got)
                continue
            out.append(FrameSet(float(np.mean([p.time for p in got])),
                                [None if p is None else p.uv for p in members],
                                [None if p is None else p.norm for p in members],
                                first, max(p.arrival for p in got),
                                float(np.mean([p.arrival if p.capture is None else p.capture for p in got]))))
