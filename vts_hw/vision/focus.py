"""How sharp a marker's edge is: its width in pixels, as the 10-90 % rise of a Gaussian edge.

A marker (a sphere or a flat disk) is round; around its centroid every pixel's grey level is a
sample of one radial profile at the pixel's distance from the centre. :func:`edge_profile`
bins those samples (``bin_px`` wide, so the profile is sampled more finely than the pixels,
as the slanted-edge method does for a straight edge) and reads the marker's outer edge off
the averaged profile: its slope (the line spread) is steepest at the edge (``radius_px``);
from there outwards the slope falls to half its peak within ``1.18 s`` for an edge blurred by
a Gaussian of standard deviation ``s``. That outer half width, times ``2.5631 / 1.1774``, is the
**edge width**: the 10-90 % rise width the edge would have (``2.56 s``).

Only the edge's outer side is read: inside it a sphere is shaded (darker towards its rim, as a
real one under a ring light and the simulated one are), and a 10-90 % rise taken across that
shading measures the shading, not the focus. The width is a distance between points of the
slope taken relative to its own peak, so the brightness of the LED, the gain and the background
cancel out: a marker twice as bright has the same edge width (docs/decisions/0068-aim-and-focus.md).
A Gaussian blur ``s`` gives about ``2.56 * sqrt(s² + 0.16)`` px (the 0.16: the pixel's own
width); a marker in focus measures about 1 px. ``step`` (grey levels from the background
beyond the edge to the profile's top) and ``background`` come with it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["EdgeProfile", "edge_profile", "GAUSS_10_90"]

GAUSS_10_90 = 2.5631  # the 10-90 % width of a Gaussian-blurred step, in standard deviations
HALF_WIDTH = 1.1774  # the half width at half maximum of a Gaussian, in standard deviations
_SMOOTH = np.array([0.25, 0.5, 0.25])


@dataclass(frozen=True)
class EdgeProfile:
    """One marker's edge: ``width_px`` (10-90 % rise), ``radius_px`` (to the 50 % level),
    ``step`` (grey levels from the background to the shoulder), ``background`` (grey level)."""

    x: float
    y: float
    radius_px: float
    width_px: float
    step: float
    background: float

    @property
    def diameter_px(self) -> float:
        return 2.0 * self.radius_px

    @property
    def ratio(self) -> float:
        """The edge width as a share of the radius."""
        return self.width_px / self.radius_px if self.radius_px > 0 else math.inf


def edge_profile(gray: np.ndarray, x: float, y: float, radius_hint: float, bin_px: float = 0.25) -> EdgeProfile | None:
    """The edge of the round marker centred at ``(x, y)`` (px) whose radius is about
    ``radius_hint`` px, in the grey image ``gray``; None when it has no clear edge (the
    profile never falls, or the marker reaches the picture's border)."""
    h_img, w_img = gray.shape[:2]
    half = int(math.ceil(2.0 * radius_hint + 12.0))
    x0, y0 = int(round(x)) - half, int(round(y)) - half
    if x0 < 0 or y0 < 0 or x0 + 2 * half >= w_img or y0 + 2 * half >= h_img:
        return None
    roi = gray[y0 : y0 + 2 * half + 1, x0 : x0 + 2 * half + 1].astype(np.float64)
    yy, xx = np.mgrid[y0 : y0 + 2 * half + 1, x0 : x0 + 2 * half + 1]
    dist = np.hypot(xx - x, yy - y).ravel()
    keep = dist <= half
    k = (dist[keep] / bin_px).astype(np.int64)
    counts = np.bincount(k)
    sums = np.bincount(k, weights=roi.ravel()[keep])
    ok = counts > 0
    r = (np.nonzero(ok)[0] + 0.5) * bin_px
    p = sums[ok] / counts[ok]
    if p.size < 12:
        return None
    ps = np.convolve(np.pad(p, 1, mode="edge"), _SMOOTH, mode="valid")  # about 0.2 px of smoothing
    slope = -np.gradient(ps, r)  # the line spread (falling edge)
    inner = r > 0.5
    e = int(np.argmax(np.where(inner, slope, -np.inf)))
    peak = float(slope[e])
    if not peak > 0 or e + 1 >= len(r):
        return None
    # the steepest point, between bins (a parabola through the three around it)
    r_e = float(r[e])
    if 0 < e < len(r) - 1:
        a, b, c = slope[e - 1], slope[e], slope[e + 1]
        if a - 2 * b + c < 0:
            r_e += float(0.5 * (a - c) / (a - 2 * b + c) * bin_px)
            peak = float(b - 0.25 * (a - c) * (a - c) / (a - 2 * b + c))
    # outwards from it: the half-maximum of the line spread, then the background beyond
    after = np.nonzero(slope[e:] < 0.5 * peak)[0]
    dead = np.nonzero(slope[e:] < 0.1 * peak)[0]
    if not after.size or not dead.size:
        return None
    j = e + int(after[0])
    f = (slope[j - 1] - 0.5 * peak) / (slope[j - 1] - slope[j]) if slope[j - 1] != slope[j] else 0.5
    r_half = float(r[j - 1] + f * (r[j] - r[j - 1]))
    tail = p[min(e + int(dead[0]) + int(round(1.0 / bin_px)), len(p)) :]
    if tail.size < 4:
        return None
    l0 = float(np.median(tail))
    step = float(ps[: e + 1].max()) - l0
    if not step > 0:
        return None
    width = float(GAUSS_10_90 / HALF_WIDTH * max(r_half - r_e, 0.0))
    return EdgeProfile(float(x), float(y), r_e, width, step, l0)
