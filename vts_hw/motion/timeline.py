"""The scan's time as the motion analysis sees it: every frame time of the scan, with or without
a frame (issue 20; docs/decisions/0046-time-without-frames.md).

The tracks hold only the frame sets that were recorded. A camera that skipped a second of
frames, a ``.mjpeg`` cut short, a scan whose first seconds are missing: none of these leave a
row, and an analysis over the rows alone calls the rest of the scan "100 % covered".
:func:`on_grid` puts the series on the scan's frame grid instead: each jump between frame sets of
more than 1.5 frame periods gets rows at the frame period with no markers, and so do the start
and the end of the scan's ``span`` (what the recording's index and manifest say it covers,
:mod:`vts_hw.recording.extent`) beyond the first and last frame set. Every row then stands for
one frame period of the scan, so shares of rows are shares of its time.

:class:`Timeline` keeps which rows had frames and says, with the pose's validity, what time is
known: :meth:`Timeline.coverage` (pose known, without frames, with fewer than 3 markers, in how
many stretches) and :meth:`Timeline.unknown` (the stretches, for tables and plots).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vts_hw.motion.markers import MarkerSeries

__all__ = ["Timeline", "on_grid", "runs", "seen_runs", "MAX_HOLE_S"]

MAX_HOLE_S = 0.2  # a hole this short inside seen time hides no breath and no move's shape


def runs(mask) -> list[tuple[int, int]]:
    """``[(start, stop))`` index runs where ``mask`` is True."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(int))
    return list(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist()))


def seen_runs(valid, period: float, max_hole_s: float = MAX_HOLE_S) -> list[tuple[int, int]]:
    """Runs of ``valid`` rows joined across holes of at most ``max_hole_s`` (a frame or a few
    missing): the stretches of time seen, each starting and ending on a valid row."""
    valid = np.asarray(valid, bool)
    out: list[tuple[int, int]] = []
    for a, b in runs(valid):
        if out and (a - out[-1][1]) * period <= max_hole_s + 1e-9:
            out[-1] = (out[-1][0], b)
        else:
            out.append((a, b))
    return out


@dataclass
class Timeline:
    """``t`` (F,) the scan's frame times (series clock); ``frames`` (F,) a frame set was
    recorded at ``t[f]``; ``period`` s; ``missing``: sentences on what the recording lacks."""

    t: np.ndarray
    frames: np.ndarray
    period: float
    missing: list = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        """The scan's duration: one frame period per row."""
        return float(len(self.t) * self.period)

    def seconds(self, mask) -> float:
        return float(np.count_nonzero(mask) * self.period)

    def unknown(self, valid) -> list[dict]:
        """The stretches without a pose, in time order: ``t_start``, ``t_end`` (the rows' times
        widened by half a period: the time they stand for), ``seconds``, ``why`` (``no frames``,
        ``fewer than 3 markers``, or ``no frames / fewer than 3 markers`` when both)."""
        out = []
        for a, b in runs(~np.asarray(valid, bool)):
            nf = bool((~self.frames[a:b]).any())
            fm = bool(self.frames[a:b].any())
            why = "no frames / fewer than 3 markers" if nf and fm else ("no frames" if nf else "fewer than 3 markers")
            out.append(
                {
                    "t_start": float(self.t[a] - self.period / 2),
                    "t_end": float(self.t[b - 1] + self.period / 2),
                    "seconds": float((b - a) * self.period),
                    "why": why,
                    "rows": (a, b),
                }
            )
        return out

    def coverage(self, valid) -> dict:
        """Time with a pose against the scan's duration, and the rest by cause."""
        valid = np.asarray(valid, bool)
        nf = ~self.frames
        few = self.frames & ~valid
        gaps = runs(nf)
        return {
            "duration_s": self.duration_s,
            "pose_s": self.seconds(valid),
            "share": float(valid.mean()) if len(valid) else 0.0,
            "no_frames_s": self.seconds(nf),
            "no_frames_gaps": len(gaps),
            "longest_gap_s": max(((b - a) * self.period for a, b in gaps), default=0.0),
            "few_markers_s": self.seconds(few),
            "few_markers_stretches": len(runs(few)),
        }


def _grid_times(t, period, start, end):
    """The frame times ``t`` with rows inserted in every jump over 1.5 periods and before/after
    them back to ``start`` / on to ``end``; and the mask of the original rows."""
    parts, real = [], []
    if start is not None and start < t[0] - 0.5 * period:
        k = int(round((t[0] - start) / period))
        parts.append(t[0] - period * np.arange(k, 0, -1))
        real.append(np.zeros(k, bool))
    d = np.diff(t)
    cut = np.flatnonzero(d > 1.5 * period)
    prev = 0
    for i in cut:
        parts.append(t[prev : i + 1])
        real.append(np.ones(i + 1 - prev, bool))
        n = int(round(d[i] / period)) - 1
        if n > 0:
            parts.append(t[i] + d[i] * np.arange(1, n + 1) / (n + 1))
            real.append(np.zeros(n, bool))
        prev = i + 1
    parts.append(t[prev:])
    real.append(np.ones(len(t) - prev, bool))
    if end is not None and end > t[-1] + 0.5 * period:
        k = int(round((end - t[-1]) / period))
        parts.append(t[-1] + period * np.arange(1, k + 1))
        real.append(np.zeros(k, bool))
    return np.concatenate(parts), np.concatenate(real)


def on_grid(series: MarkerSeries, span: tuple | None = None, missing=()) -> tuple[MarkerSeries, Timeline]:
    """The series with a row (no markers) for every frame time of the scan without a frame set
    (see the module), and its :class:`Timeline`. ``span``: (first, last) frame time the
    recording should hold, on the series' clock (None: the first and last frame set)."""
    t = np.asarray(series.t, float)
    d = np.diff(t)
    d = d[np.isfinite(d) & (d > 0)]
    period = float(np.median(d)) if d.size else 0.04
    start, end = (None, None) if span is None else span
    grid, real = _grid_times(t, period, start, end)
    F = len(grid)
    P = np.full((F,) + series.P.shape[1:], np.nan)
    P[real] = series.P
    cams = None
    if series.cameras is not None:
        cams = np.zeros((F,) + series.cameras.shape[1:], series.cameras.dtype)
        cams[real] = series.cameras
    out = MarkerSeries(
        grid, P, series.ids, series.clock, series.frame, cams, list(series.camera_names), list(series.camera_sets)
    )
    return out, Timeline(grid, real, period, list(missing))
