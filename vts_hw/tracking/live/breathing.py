"""The breathing trace of a band (mm over host time) and its rate, online.

The rate is the offline analysis' (:mod:`vts_hw.motion.cycles`, decision 0089): the last
``window_s`` of the trace, put on the grid of its frame period (a frame set's row; time without
one is time without a pose, never filled), run through :func:`~vts_hw.motion.cycles.find_breaths`
and :func:`~vts_hw.motion.cycles.breathing_figures` -- the same breaths seen whole, the same
status (measured, bounded, unknown, none) and range. So the live rate and the recording's agree
on the same signal. The figures are worked out again at most every ``every_s`` of trace time (a
snapshot may be asked for many times a second).
"""

from __future__ import annotations

from collections import deque

import numpy as np

from vts_hw.motion.cycles import BreathingFigures, breathing_figures, find_breaths, signal_noise

__all__ = ["BreathingTrace", "breathing_rate", "trace_grid"]

MIN_SAMPLES = 20  # samples a window needs before a rate is looked for


def trace_grid(t, v) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Samples ``v`` at times ``t`` (in order) on the grid of their frame period: ``(times,
    values, valid, period)``, a row per period from the first sample to the last, each sample on
    a row of its own, ``valid`` False where none fell (a frame set lost, or no fit): those rows
    are NaN."""
    t, v = np.asarray(t, float), np.asarray(v, float)
    ok = np.isfinite(t) & np.isfinite(v)
    t, v = t[ok], v[ok]
    if len(t) < 2:
        return np.zeros(0), np.zeros(0), np.zeros(0, bool), 0.0
    d = np.diff(t)
    period = float(np.median(d[d > 0])) if (d > 0).any() else 0.0
    if period <= 0:
        return np.zeros(0), np.zeros(0), np.zeros(0, bool), 0.0
    # each sample's row counted from the one before it (the step rounded: a few ms of jitter
    # never adds up), then the period fitted to all of them
    rows = np.concatenate([[0], np.cumsum(np.maximum(np.round(d / period), 1))]).astype(int)
    if rows[-1] > 0:
        period = float(np.polyfit(rows, t, 1)[0])
    grid = t[0] + period * np.arange(rows[-1] + 1)
    vals = np.full(len(grid), np.nan)
    vals[rows] = v
    return grid, vals, np.isfinite(vals), period


def figures_of(t, v) -> BreathingFigures:
    """The breathing figures of the samples ``v`` at times ``t``: the offline analysis' own."""
    grid, vals, valid, period = trace_grid(t, v)
    if valid.sum() < MIN_SAMPLES:
        return BreathingFigures("unknown", f"rate unknown: {int(valid.sum())} samples, a rate needs breaths seen whole")
    br = find_breaths(grid, vals, valid, period)
    return breathing_figures(br, period, len(grid) * period, signal_noise(vals, valid))


def breathing_rate(t: np.ndarray, v: np.ndarray) -> float:
    """Breaths per minute of the samples ``v`` at times ``t`` (the figures' rate, measured or
    bounded; NaN when unknown or no breathing)."""
    f = figures_of(t, v)
    return float(f.rate_per_min) if f.rate_per_min is not None else float("nan")


class BreathingTrace:
    """The last ``window_s`` of one band's breathing value (mm)."""

    def __init__(self, window_s: float = 30.0, every_s: float = 1.0):
        self.window_s = window_s
        self.every_s = every_s
        self.samples: deque[tuple[float, float]] = deque()
        self._figures: BreathingFigures | None = None
        self._at: float | None = None

    def add(self, t: float, value: float) -> None:
        self.samples.append((t, value))
        while self.samples and t - self.samples[0][0] > self.window_s:
            self.samples.popleft()

    def values(self) -> tuple[np.ndarray, np.ndarray]:
        if not self.samples:
            return np.zeros(0), np.zeros(0)
        a = np.array(self.samples, float)
        return a[:, 0], a[:, 1]

    def due(self) -> bool:
        """Whether the figures are to be worked out again: none yet, or ``every_s`` of samples
        came since (or the clock went back)."""
        last = self.samples[-1][0] if self.samples else None
        return (
            self._figures is None
            or last is None
            or self._at is None
            or last - self._at >= self.every_s
            or last < self._at
        )

    def refresh(self) -> None:
        """Work the figures out again, if :meth:`due`."""
        if self.due():
            self._figures, self._at = figures_of(*self.values()), (self.samples[-1][0] if self.samples else None)

    def figures(self, fresh: bool = True) -> BreathingFigures | None:
        """The window's breathing figures (worked out again once ``every_s`` of samples came).
        ``fresh=False``: the last worked out, as they are (None before the first): for the live
        path, which refreshes them after a frame set's estimate, off that set's latency."""
        if fresh:
            self.refresh()
        return self._figures

    def last(self) -> float:
        """The newest value (NaN when none)."""
        return self.samples[-1][1] if self.samples else float("nan")

    def rate_per_min(self) -> float:
        f = self.figures()
        return float(f.rate_per_min) if f is not None and f.rate_per_min is not None else float("nan")

    def recent(self, n: int = 40, span_s: float = 10.0) -> list[float]:
        """``n`` values evenly over the last ``span_s`` (for a sparkline); NaN where none."""
        if not self.samples:
            return []
        end = self.samples[-1][0] - span_s
        tail = []  # the samples of the span (and the one before it), newest first
        for sample in reversed(self.samples):
            tail.append(sample)
            if sample[0] < end:
                break
        a = np.array(tail[::-1], float)
        t, v = a[:, 0], a[:, 1]
        grid = np.linspace(t[-1] - span_s, t[-1], n)
        out = np.interp(grid, t, v)
        out[grid < t[0]] = np.nan
        return out.tolist()
