"""The camera clock model: each camera's own clock mapped to host time (offset and skew).

Every frame of a recording has two times (vts_hw/recording/folder.py, docs/design.md "clocks"):

* ``camera_time`` — the camera's own clock, stamped in the JPEG when the image was taken,
  truncated to the camera's tick (10 ms, ``tick_s``): UTC epoch seconds *of the camera*;
* ``host_time`` — the host's clock (UTC epoch seconds) when the recorder received the frame:
  always *later* than the exposure, by a network and processing delay that jitters and now
  and then is large (a stalled connection delays every frame behind it).

The relation is linear over a recording: ``host = camera + a + k * (camera - ref)``. Since the
delay is one-sided, every point ``(camera_time, host_time)`` lies on or above that line, and
the points with the least delay lie just above it: the line is the **lower envelope** of the
points. :func:`fit_camera_clock` solves the linear programme "minimise the sum of the
residuals ``host - line`` subject to every residual ≥ 0" exactly: its solution is the edge of
the points' lower convex hull that spans their mean camera time. Late frames (jitter,
outliers of hundreds of ms) cannot pull the line; they only get large residuals.

The stamps' truncation to the tick: a camera exposes its frames on a regular grid of its
own clock, so :func:`dequantise` first estimates each frame's camera time from the stamps
(the upper edge of the narrowest strip holding them against the frame number); the host fit
is then made against those estimates. Where the stamps' phase within the tick stays fixed
(25 fps = 40 ms = 4 ticks, over a short recording) this changes nothing and the fixed phase
is absorbed by the envelope; where it sweeps the tick (a long scan with skew) it removes an
error of up to one tick (10 ms) that the envelope of the raw stamps would leave. Frames
that do not fit a regular grid (irregular timing, a clock jump) keep their raw stamps.

What the mapped time means (docs/decisions/0018-processing.md):
:meth:`ClockFit.frame_host_times` is, for each frame, the host time at which it *would have
arrived with the least delay seen*, minus ``latency_s`` (a known minimum delay, default 0):
its exposure time plus the least delay that is not known. ``skew_ppm`` is only as good as the
stamps can show: a skew moves a fixed-phase stamp only when the phase crosses a tick, so a
short recording's skew is uncertain by about ``skew_resolution_ppm`` (one tick over its
span), while the mapped times of its own frames are not.

``uncertainty_s`` is a block jackknife (the recording cut into ``blocks`` contiguous parts,
each left out in turn) of the mapped time at the first, middle and last frame: the
envelope's own statistical uncertainty, not the least delay (which no fit can see).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vts_hw.errors import DataError
from vts_hw.recording.folder import read_index

__all__ = ["ClockFit", "fit_camera_clock", "fit_recording_clocks", "lower_envelope", "dequantise"]

TICK_S = 0.01
LATE_S = 0.05  # a frame this much above the envelope counts as "late" in the summary
#: the most a camera's clock runs off the host's: quartz (tens of ppm) slewed by NTP (at most
#: 500 ppm), doubled. A steeper envelope is not a clock but frames arriving later and later (a
#: host or a simulator falling behind, never catching up): the frames then do not measure the
#: rate, the fit takes the host's (docs/decisions/0061-camera-clock-rate-bound.md), says so
#: (``rate_measured`` False) and counts a plausible rate's error over the span in its uncertainty
MAX_RATE = 1e-3
#: the rate assumed unknown by that much when the frames do not measure it
PRIOR_RATE = 1e-4


def lower_envelope(x: np.ndarray, y: np.ndarray, max_slope: float | None = None) -> tuple[float, float]:
    """``(a, k)`` of the line ``y = a + k * x`` below every point that minimises the sum of
    the vertical gaps (an exact LP solution): the lower convex hull's edge spanning mean(x).
    With ``max_slope``: a solution steeper than that is no clock's rate but a delay growing
    over the recording (see MAX_RATE), and the points do not tell the rate: ``k = 0`` (the
    host's own rate, which a quartz clock keeps to tens of ppm) through the lowest point.

    ``x`` should be centred near 0 for conditioning. One distinct ``x``: a flat line through
    the lowest point.
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    if x.size == 0:
        raise ValueError("no points")
    order = np.lexsort((y, x))
    xs, ys = x[order], y[order]
    # keep the lowest y per distinct x (the others can never touch the envelope)
    first = np.ones(len(xs), bool)
    first[1:] = xs[1:] != xs[:-1]
    xs, ys = xs[first], ys[first]
    if len(xs) == 1:
        return float(ys[0]), 0.0
    hx, hy = _lower_hull(xs, ys)
    xm = float(x.mean())
    j = int(np.searchsorted(hx, xm, side="right")) - 1
    j = min(max(j, 0), len(hx) - 2)
    k = (hy[j + 1] - hy[j]) / (hx[j + 1] - hx[j])
    a = hy[j] - k * hx[j]
    if max_slope is not None and abs(k) > max_slope:
        k, a = 0.0, float(np.min(hy))
    return float(a), float(k)


def _lower_hull(xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices of the lower convex hull, left to right, of points sorted by x (distinct x).

    Qhull (C) finds the hull; Andrew's monotone chain (Python) is the fallback for a few
    points or a degenerate (collinear) set."""
    if len(xs) > 16:
        try:
            from scipy.spatial import ConvexHull

            # Scaled to unit ranges so that Qhull's tolerances mean the same for any input.
            sx = (xs - xs[0]) / max(xs[-1] - xs[0], 1e-300)
            yr = ys.max() - ys.min()
            sy = (ys - ys.min()) / (yr if yr > 0 else 1.0)
            v = ConvexHull(np.column_stack([sx, sy])).vertices  # counter-clockwise
            i0 = int(np.flatnonzero(v == 0)[0]) if (v == 0).any() else None
            n = len(xs)
            if i0 is not None and (v == n - 1).any():
                ring = np.roll(v, -i0)  # from the leftmost point, counter-clockwise: the bottom
                end = int(np.flatnonzero(ring == n - 1)[0])
                idx = ring[: end + 1]
                if np.all(np.diff(idx) > 0):
                    return xs[idx], ys[idx]
        except Exception:  # noqa: BLE001 - Qhull's degenerate-input errors: use the fallback
            pass
    hull: list[int] = []
    for i in range(len(xs)):  # Andrew's monotone chain, lower half
        while len(hull) >= 2:
            o, p = hull[-2], hull[-1]
            cross = (xs[p] - xs[o]) * (ys[i] - ys[o]) - (ys[p] - ys[o]) * (xs[i] - xs[o])
            if cross <= 0:
                hull.pop()
            else:
                break
        hull.append(i)
    return xs[hull], ys[hull]


@dataclass
class ClockFit:
    """The fitted map of one camera's clock to host time (seconds throughout).

    ``host = camera + intercept_s + rate * (camera - ref_camera_time) - latency_s``.
    ``residuals_s``: per input frame, host receive time minus the envelope (≥ 0; NaN for a
    frame without a camera time). ``uncertainty_s``: jackknife standard error of the mapped
    time over the recording's span (see the module docstring). ``frame_camera_time``: per
    input frame, the camera time the fit used (the stamp de-quantised when ``dequantised``).
    """

    ref_camera_time: float
    intercept_s: float
    rate: float
    latency_s: float = 0.0
    tick_s: float = TICK_S
    n_frames: int = 0
    n_used: int = 0
    first_camera_time: float = math.nan
    last_camera_time: float = math.nan
    uncertainty_s: float = math.nan
    residuals_s: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    frame_camera_time: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    dequantised: bool = False
    rate_measured: bool = True

    def frame_host_times(self) -> np.ndarray:
        """Mapped host time (s) of every input frame (NaN for a frame without a stamp): the
        map applied to the frame's camera time as estimated from the stamps' regular grid
        (the stamps themselves when they did not fit one)."""
        return np.asarray(self.host_time(self.frame_camera_time), float)

    # -------------------------------------------------------------- mapping
    def host_time(self, camera_time):
        """Host time (UTC epoch s) of a camera time (the camera's epoch s); arrays welcome.
        For the frames of the fit use :meth:`frame_host_times` (their de-quantised times)."""
        c = np.asarray(camera_time, float)
        out = c + (self.intercept_s - self.latency_s) + self.rate * (c - self.ref_camera_time)
        return float(out) if out.ndim == 0 else out

    def camera_time(self, host_time):
        """The inverse of :meth:`host_time`."""
        h = np.asarray(host_time, float)
        c = (h - self.intercept_s + self.latency_s + self.rate * self.ref_camera_time) / (1.0 + self.rate)
        return float(c) if c.ndim == 0 else c

    # -------------------------------------------------------------- figures
    @property
    def offset_s(self) -> float:
        """Camera minus host time at ``ref_camera_time`` (the CameraClock convention)."""
        return -(self.intercept_s - self.latency_s)

    @property
    def skew_ppm(self) -> float:
        """How fast the camera's clock runs against the host's, ppm (CameraClock convention:
        ``camera = host + offset + skew * 1e-6 * (host - ref)``)."""
        return (1.0 / (1.0 + self.rate) - 1.0) * 1e6

    @property
    def skew_resolution_ppm(self) -> float:
        """One tick over the recording's span (ppm): at worst, how well the stamps show a
        skew. Frames locked to the tick show none until their phase crosses a tick boundary,
        so a short recording's skew may be off by about this much (the mapped times of its
        own frames are not: the envelope follows the stamps)."""
        span = self.last_camera_time - self.first_camera_time
        return self.tick_s / span * 1e6 if span > 0 else math.inf

    def summary(self) -> dict:
        """JSON-ready figures: offset, skew, residual statistics, uncertainty."""
        r = self.residuals_s[np.isfinite(self.residuals_s)]
        q = (lambda p: float(np.percentile(r, p))) if r.size else (lambda p: None)
        fin = lambda v: float(v) if math.isfinite(v) else None  # noqa: E731 - strict JSON
        return {
            "offset_s": self.offset_s,
            "skew_ppm": self.skew_ppm,
            "ref_camera_time": self.ref_camera_time,
            "intercept_s": self.intercept_s,
            "rate": self.rate,
            "latency_s": self.latency_s,
            "tick_s": self.tick_s,
            "frames": self.n_frames,
            "frames_used": self.n_used,
            "first_camera_time": fin(self.first_camera_time),
            "last_camera_time": fin(self.last_camera_time),
            "uncertainty_s": fin(self.uncertainty_s),
            "skew_resolution_ppm": fin(self.skew_resolution_ppm),
            "residual_median_s": q(50),
            "residual_p95_s": q(95),
            "residual_max_s": float(r.max()) if r.size else None,
            "late_frames": int((r > LATE_S).sum()),
            "dequantised": self.dequantised,
            "rate_measured": self.rate_measured,
        }

    @classmethod
    def from_summary(cls, d: dict) -> ClockFit:
        """Rebuild the map (not the residuals) from :meth:`summary`."""
        return cls(
            d["ref_camera_time"],
            d["intercept_s"],
            d["rate"],
            d.get("latency_s", 0.0),
            d.get("tick_s", TICK_S),
            d.get("frames", 0),
            d.get("frames_used", 0),
            _nan(d.get("first_camera_time")),
            _nan(d.get("last_camera_time")),
            _nan(d.get("uncertainty_s")),
            rate_measured=d.get("rate_measured", True),
        )


def _nan(v) -> float:
    return math.nan if v is None else float(v)


def fit_camera_clock(
    camera_times,
    host_times,
    latency_s: float = 0.0,
    tick_s: float = TICK_S,
    blocks: int = 10,
    dequantise_stamps: bool = True,
) -> ClockFit:
    """Fit the camera → host map of one camera from its frames' times (see the module doc).

    ``camera_times``: the JPEG stamps (camera epoch s; None/NaN where a frame had none);
    ``host_times``: the host receive times (host epoch s). ``latency_s``: a known minimum
    delay from exposure to receipt, subtracted from the mapped times.
    ``dequantise_stamps``: first estimate the frames' camera times from the stamps' regular
    grid (:func:`dequantise`); the fit is then against those. Raises :class:`DataError` when
    fewer than 2 frames have both times.
    """
    c_all = np.array([np.nan if v is None else v for v in camera_times], float)
    h_all = np.array([np.nan if v is None else v for v in host_times], float)
    if c_all.shape != h_all.shape:
        raise ValueError("camera_times and host_times must have the same length")
    ok = np.isfinite(c_all) & np.isfinite(h_all)
    c, h = c_all[ok], h_all[ok]
    if c.size < 2:
        raise DataError(
            f"the camera clock fit needs at least 2 frames with both a camera time and a host time, got {c.size}"
        )
    est = dequantise(c, tick_s) if dequantise_stamps else None
    if est is not None:
        c = est
    ref = float(np.round(np.median(c), 2))
    x = c - ref
    y = h - c
    a, k = lower_envelope(x, y)
    measured = abs(k) <= MAX_RATE
    if not measured:  # a delay growing to the end, not a clock: see MAX_RATE
        a, k = lower_envelope(x, y, MAX_RATE)
    res = np.full(c_all.shape, np.nan)
    res[ok] = y - (a + k * x)
    frame_c = np.full(c_all.shape, np.nan)
    frame_c[ok] = c
    fit = ClockFit(
        ref,
        a,
        k,
        float(latency_s),
        float(tick_s),
        int(c_all.size),
        int(c.size),
        float(c.min()),
        float(c.max()),
        math.nan,
        res,
        frame_c,
        est is not None,
    )
    fit.uncertainty_s = _jackknife(x, y, a, k, blocks)
    if not measured:
        fit.rate_measured = False
        span_err = PRIOR_RATE * float(c.max() - c.min())
        fit.uncertainty_s = span_err if not math.isfinite(fit.uncertainty_s) else max(fit.uncertainty_s, span_err)
    return fit


def dequantise(stamps: np.ndarray, tick_s: float = TICK_S, tolerance_s: float = 0.002):
    """Camera times of regularly timed frames from their truncated stamps, or None.

    A camera exposes its frames on a regular grid of its own clock, ``c0 + P * k``; each stamp
    is that time truncated to the tick, so ``c - tick < stamp <= c``. The frame numbers ``k``
    come from the stamp intervals (a dropped frame skips a number). The line is the
    *narrowest strip* holding every point ``(k, stamp)`` (the minimax, or Chebyshev, line:
    its slope is that of an edge of the points' upper or lower convex hull), and the
    estimate is the strip's upper edge. Where the stamps' phase within the tick sweeps the
    whole tick (a frame period that is not a whole number of ticks, or a long recording with
    skew) the strip is one tick wide and its upper edge is the frames' true camera times;
    where the phase is fixed the strip has no width and the estimate is the stamps
    themselves (the fixed phase is then absorbed by the host fit).
    None — use the stamps as they are — when the strip is wider than ``tick_s + tolerance_s``
    (irregular frame times, a camera clock that jumped).
    """
    s = np.asarray(stamps, float)
    if s.size < 8:
        return None
    d = np.diff(s)
    if (d <= 0).any():
        return None
    period = float(np.median(d))
    for _ in range(3):  # frame numbers, then the period they imply, twice more
        k = np.concatenate([[0.0], np.cumsum(np.maximum(np.rint(d / period), 1.0))])
        period = float(np.polyfit(k, s, 1)[0])
    s0 = s[0]
    y = s - s0 - period * k  # small numbers: the stamps' departure from the nominal grid
    lx, ly = _lower_hull(k, y)
    ux, uy = _lower_hull(k, -y)
    uy = -uy
    slopes = np.concatenate([np.diff(ly) / np.diff(lx), np.diff(uy) / np.diff(ux), [0.0]])
    top = (uy[None, :] - slopes[:, None] * ux[None, :]).max(axis=1)
    bottom = (ly[None, :] - slopes[:, None] * lx[None, :]).min(axis=1)
    width = top - bottom
    best = int(np.argmin(width))
    if width[best] > tick_s + tolerance_s:
        return None
    return s0 + period * k + slopes[best] * k + top[best]


def _jackknife(x, y, a, k, blocks: int) -> float:
    """Jackknife standard error of the envelope at the first, middle and last point."""
    n = len(x)
    blocks = min(int(blocks), n // 2)
    if blocks < 2:
        return math.nan
    probe = np.array([x.min(), 0.5 * (x.min() + x.max()), x.max()])
    edges = np.linspace(0, n, blocks + 1).astype(int)
    preds = []
    for b in range(blocks):
        keep = np.ones(n, bool)
        keep[edges[b] : edges[b + 1]] = False
        if len(np.unique(x[keep])) < 2:
            continue
        ab, kb = lower_envelope(x[keep], y[keep], MAX_RATE)
        preds.append(ab + kb * probe)
    if len(preds) < 2:
        return math.nan
    p = np.array(preds)
    m = len(p)
    se = np.sqrt((m - 1) / m * ((p - p.mean(axis=0)) ** 2).sum(axis=0))
    return float(se.max())


def fit_recording_clocks(folder, latency_s: float = 0.0) -> dict[str, ClockFit]:
    """:func:`fit_camera_clock` for every camera of a recording folder (from its indexes)."""

    folder = Path(folder)
    out = {}
    for idx in sorted(folder.glob("*.index.csv")):
        name = idx.name[: -len(".index.csv")]
        rows = read_index(idx)
        out[name] = fit_camera_clock([r.camera_time for r in rows], [r.host_time for r in rows], latency_s)
    if not out:
        raise DataError(f"{folder}: no camera indexes (*.index.csv) in this folder")
    return out
