"""A simulated fixed camera's clock and its slow drift over days (re-exported by scene.py).

* :class:`CameraClock` -- the camera's own clock against the host's: an offset and a skew.
* :class:`CameraDrift` -- a slow rotation of the camera about its own centre over days and
  months (a linear trend plus a seeded random walk): what the daily drift QA watches.

The drift while a camera warms up after it starts (minutes) is sim_devices/warmup.py.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

DAY = 86400.0


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


@dataclass(frozen=True)
class CameraClock:
    """A camera's own clock: ``camera = host + offset + skew * 1e-6 * (host - ref_epoch)``."""

    offset_s: float = 0.0
    skew_ppm: float = 0.0
    ref_epoch: float = 0.0

    def camera_time(self, host_t: float) -> float:
        return host_t + self.offset_s + self.skew_ppm * 1e-6 * (host_t - self.ref_epoch)

    def host_time(self, camera_t: float) -> float:
        """The inverse of :meth:`camera_time`."""
        s = self.skew_ppm * 1e-6
        return (camera_t - self.offset_s + s * self.ref_epoch) / (1.0 + s)


@dataclass(frozen=True, eq=False)
class CameraDrift:
    """Slow rotation of a fixed camera: a linear trend plus a seeded random walk.

    :meth:`rotation_at` gives a small rotation vector (camera coordinates, radians) to apply
    on top of the base pose. The random walk is a table of daily steps (``days`` long, drawn
    once from ``seed``) interpolated linearly, so any instant is evaluated deterministically
    and in any order. Before ``ref_epoch`` the camera sits at its base pose; after the table
    ends the walk holds its last value while the trend goes on.
    """

    trend_axis: np.ndarray
    trend_rad_per_day: float
    walk_sigma_rad: float
    seed: int
    ref_epoch: float
    days: int = 3660
    _walk: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        rng = np.random.default_rng(self.seed)
        steps = rng.normal(0.0, self.walk_sigma_rad, size=(self.days, 3))
        walk = np.vstack([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
        object.__setattr__(self, "_walk", walk)
        object.__setattr__(self, "trend_axis", _unit(self.trend_axis))

    @classmethod
    def reference(
        cls,
        focal_px: float,
        seed: int,
        ref_epoch: float,
        px_per_60_days: float = 1.0,
        walk_px_per_60_days: float = 0.07,
    ) -> CameraDrift:
        """A drift that moves the image by about ``px_per_60_days`` (trend) over 60 days, plus
        a random walk whose 60-day standard deviation per image axis is ``walk_px_per_60_days``."""
        rng = np.random.default_rng(seed)
        phi = rng.uniform(0, 2 * np.pi)
        axis = np.array([np.cos(phi), np.sin(phi), 0.1 * rng.normal()])
        return cls(
            axis, px_per_60_days / focal_px / 60.0, walk_px_per_60_days / focal_px / np.sqrt(60.0), seed + 1, ref_epoch
        )

    def rotation_at(self, t: float) -> np.ndarray:
        d = max(0.0, (t - self.ref_epoch) / DAY)
        i = min(int(d), self.days - 1)
        frac = min(d - i, 1.0)
        walk = self._walk[i] * (1.0 - frac) + self._walk[i + 1] * frac
        return self.trend_axis * (self.trend_rad_per_day * d) + walk
