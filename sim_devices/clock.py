"""Clocks for the simulated world: real time, or a virtual time that can run fast and jump.

Every simulated device asks a :class:`SimClock` for "now" (host UTC epoch seconds as the
simulated world sees it) instead of calling :func:`time.time` itself. Tests and accelerated QA
runs hand in a :class:`VirtualClock`, which can run faster than real time and can jump forward
by days or months at once (to let camera drift accumulate) without anybody waiting for it.
"""

from __future__ import annotations

import math
import threading
import time


class SimClock:
    """What the simulated world needs of a clock. Subclasses implement both methods."""

    def now(self) -> float:
        """Host UTC epoch seconds, as the simulated world sees them."""
        raise NotImplementedError

    def sleep(self, seconds: float) -> None:
        """Wait for ``seconds`` of *simulated* time."""
        raise NotImplementedError


class RealClock(SimClock):
    """The wall clock: ``now()`` is :func:`time.time`, ``sleep`` is :func:`time.sleep`."""

    def now(self) -> float:
        return time.time()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds)


class VirtualClock(SimClock):
    """Simulated time that starts at ``start_epoch`` and runs ``rate`` times faster than real time.

    ``now() = start_epoch + rate * (real seconds since construction) + sum of advance() jumps``.
    :meth:`advance` jumps forward at once (e.g. 30 days of camera drift in an accelerated QA
    run); :meth:`sleep` waits ``seconds / rate`` real seconds. Safe to share between threads.
    """

    def __init__(self, start_epoch: float | None = None, rate: float = 1.0):
        if not (math.isfinite(rate) and rate > 0):  # nan and inf too: every time would be nan
            raise ValueError(f"VirtualClock rate must be a finite number greater than 0, not {rate!r}")
        self._start = time.time() if start_epoch is None else float(start_epoch)
        self._rate = float(rate)
        self._mono0 = time.monotonic()
        self._jumps = 0.0
        self._lock = threading.Lock()

    @property
    def rate(self) -> float:
        return self._rate

    def now(self) -> float:
        with self._lock:
            return self._start + self._rate * (time.monotonic() - self._mono0) + self._jumps

    def advance(self, seconds: float) -> float:
        """Jump forward by ``seconds`` of simulated time at once; returns the new ``now()``."""
        if seconds < 0:
            raise ValueError("a VirtualClock only moves forward")
        with self._lock:
            self._jumps += float(seconds)
        return self.now()

    def sleep(self, seconds: float) -> None:
        if seconds > 0:
            time.sleep(seconds / self._rate)
