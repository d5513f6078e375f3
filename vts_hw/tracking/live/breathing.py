"""The breathing trace of a band (mm over host time) and its rate, online.

The rate counts breaths in the last ``window_s``: rising crossings of the trace through its
median, with a hysteresis of a quarter of its range (10th to 90th percentile), so that noise
and the wandering baseline do not count; rate = 60 / mean interval between crossings.
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["BreathingTrace", "breathing_rate"]


def breathing_rate(t: np.ndarray, v: np.ndarray, min_range_mm: float = 0.5) -> float:
    """Breaths per minute of the samples ``v`` at times ``t`` (NaN: fewer than two breaths)."""
    t, v = np.asarray(t, float), np.asarray(v, float)
    ok = np.isfinite(v)
    t, v = t[ok], v[ok]
    if len(v) < 10:
        return float("nan")
    lo, mid, hi = np.percentile(v, [10, 50, 90])
    h = 0.25 * (hi - lo)
    if hi - lo < min_range_mm:
        return float("nan")
    # hysteresis, vectorised: the last side (above mid + h, below mid - h) each sample was on;
    # a breath starts where that side turns from below to above
    side = np.where(v > mid + h, 1, np.where(v < mid - h, -1, 0))
    idx = np.flatnonzero(side)
    s = side[idx]
    ups = t[idx[1:][(s[1:] == 1) & (s[:-1] == -1)]]
    if len(ups) < 2:
        return float("nan")
    return float(60.0 / np.mean(np.diff(ups)))


class BreathingTrace:
    """The last ``window_s`` of one band's breathing value (mm)."""

    def __init__(self, window_s: float = 30.0):
        self.window_s = window_s
        self.samples: deque[tuple[float, float]] = deque()

    def add(self, t: float, value: float) -> None:
        self.samples.append((t, value))
        while self.samples and t - self.samples[0][0] > self.window_s:
            self.samples.popleft()

    def values(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.samples:
            return np.zeros(0), np.zeros(0)
        a = np.array(self.samples, float)
        return a[:, 0], a[:, 1]

    def rate_per_min(self) -> float:
        return breathing_rate(*self.values())

    def recent(self, n: int = 40, span_s: float = 10.0) -> list[float]:
        """``n`` values evenly over the last ``span_s`` (for a sparkline); NaN where none."""
        t, v = self.values()
        if len(t) == 0:
            return []
        grid = np.linspace(t[-1] - span_s, t[-1], n)
        out = np.interp(grid, t, v)
        out[grid < t[0]] = np.nan
        return out.tolist()
