"""The live path's tap on the recording: a bounded queue per camera that drops the oldest.

The recorder hands each frame to :meth:`FrameTap.put` *after* writing it; ``put`` takes a
lock for a deque append (no I/O, no wait for the consumer) and never fails the caller. When
the live worker falls behind, the oldest frame of that camera is dropped from the live path
(and counted) -- never from the recording. Each camera's last arrival tells the live path
which camera has gone quiet. Each frame carries its number in its camera's recording (0, 1, ...:
the order the recorder wrote them, dropped ones counted): what a live pose says it was made from.
"""

from __future__ import annotations

import threading
import time
from collections import deque

__all__ = ["FrameTap"]


class FrameTap:
    def __init__(self, cameras, maxlen: int = 4):
        self.maxlen = int(maxlen)
        self._q: dict[str, deque] = {n: deque() for n in cameras}
        self.received = {n: 0 for n in cameras}
        self.dropped = {n: 0 for n in cameras}
        self.last: dict[str, float | None] = {n: None for n in cameras}  # monotonic s of each camera's last frame
        self.first: float | None = None  # ... of the first frame of any camera
        self._lock = threading.Lock()
        self._ready = threading.Event()

    def put(self, name: str, frame, arrival: float | None = None) -> None:
        """Queue a frame for the live path (cameras not tapped are ignored); ``arrival``:
        monotonic s it arrived (default now)."""
        q = self._q.get(name)
        if q is None:
            return
        with self._lock:
            item = (name, time.monotonic() if arrival is None else arrival, frame, self.received[name])
            self.last[name] = item[1]
            if self.first is None:
                self.first = item[1]
            if len(q) >= self.maxlen:
                q.popleft()
                self.dropped[name] += 1
            q.append(item)
            self.received[name] += 1
        self._ready.set()

    def take(self, timeout: float) -> list:
        """Every queued ``(camera, arrival monotonic s, frame, its number in the camera's
        recording)``, oldest arrival first; waits at most ``timeout`` for one."""
        self._ready.wait(timeout)
        with self._lock:
            self._ready.clear()
            items = [it for q in self._q.values() for it in q]
            for q in self._q.values():
                q.clear()
        items.sort(key=lambda it: it[1])
        return items

    def queued(self) -> dict:
        with self._lock:
            return {n: len(q) for n, q in self._q.items()}

    def wake(self) -> None:
        self._ready.set()
