"""A simulated camera's clock warming up after it starts: its rate departs, then settles.

After a camera starts, its clock's rate against the host's is not yet its settled rate (the
quartz warms with the board; the NTP client's frequency correction is still hunting): declared
per camera (``SimRig(clock_warmup=True)`` or ``{camera: {amplitude_ppm, tau_min}}``;
``Scene.clock_warmups``), the rate departs from the settled skew (``CameraClock``) by
``amplitude_ppm * exp(-age / tau)``, ``age`` the time since the camera started (``Scene.booted``,
as the picture's warm-up, sim_devices/warmup.py). Its offset is the integral of that: the clock
runs ``amplitude_ppm * 1e-6 * tau * exp(-age / tau)`` seconds behind its settled line (a jump
at the start, then closing), so that a camera started long ago keeps its settled clock exactly:
declaring a warm-up changes nothing for it, and a rig without one is as before.

Seeded per camera: 100-300 ppm (either sign) with a time constant of 5-12 min. That is larger
than a quartz's temperature coefficient alone (a few ppm) and is meant to be: it stands for a
cold start's frequency discipline too, and a departure much smaller than this cannot be told
over minutes from clock readings of 1 ms resolution (docs/decisions/0072-warm-up-settling.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from vts_hw.sim_devices.warmup import declare_warmups, declared

__all__ = ["ClockWarmup", "declare_clock_warmups", "declare_warm_starts", "warm_offset_s", "AMPLITUDE_PPM", "TAU_MIN"]

AMPLITUDE_PPM = (100.0, 300.0)  # seeded per camera: how far the rate is off right after the start
TAU_MIN = (5.0, 12.0)  # ... and the time constant of its settling, minutes


@dataclass(frozen=True)
class ClockWarmup:
    """How a camera's clock departs from its settled line ``age`` seconds after it started."""

    amplitude_ppm: float  # the rate's departure at the start (signed)
    tau_s: float

    def __post_init__(self):
        if not math.isfinite(self.amplitude_ppm):
            raise ValueError(f"amplitude_ppm must be a number, not {self.amplitude_ppm!r}")
        if not (math.isfinite(self.tau_s) and self.tau_s > 0):
            raise ValueError(f"tau must be a time > 0, not {self.tau_s!r} s")

    def offset_s(self, age_s: float) -> float:
        """Camera time minus its settled line (s), ``age_s`` after the start (before it: as at it)."""
        return -self.amplitude_ppm * 1e-6 * self.tau_s * math.exp(-max(0.0, age_s) / self.tau_s)

    def departure_ppm(self, age_s: float) -> float:
        """The rate's departure from the settled skew, ppm (the truth a test checks)."""
        return self.amplitude_ppm * math.exp(-max(0.0, age_s) / self.tau_s)

    def change_ppm_min(self, age_s: float) -> float:
        """How fast the rate changes, ppm/min, its size: ``|amplitude| / tau * exp(-age / tau)``."""
        return abs(self.amplitude_ppm) / (self.tau_s / 60.0) * math.exp(-max(0.0, age_s) / self.tau_s)

    def settled_after_s(self, limit_ppm_min: float) -> float:
        """The age (s) from which the rate changes slower than ``limit_ppm_min``."""
        c0 = self.change_ppm_min(0.0)
        return 0.0 if c0 <= limit_ppm_min else self.tau_s * math.log(c0 / limit_ppm_min)


def warm_offset_s(scene, cam: str, t: float) -> float:
    """What a declared clock warm-up adds to camera ``cam``'s clock at host time ``t`` (0 without one)."""
    warm = scene.clock_warmups.get(cam)
    if warm is None or cam not in scene.booted:
        return 0.0
    return warm.offset_s(t - scene.booted[cam])


def declare_clock_warmups(scene, seed: int, cameras: dict | bool) -> dict[str, ClockWarmup]:
    """Give cameras of ``scene`` a clock warm-up: ``True`` every camera, seeded per camera
    (amplitude in :data:`AMPLITUDE_PPM`, either sign, time constant in :data:`TAU_MIN`); or
    ``{camera: {"amplitude_ppm": .., "tau_min": ..}}`` (either key may be left out: seeded)."""
    for i, name, given in declared(scene, cameras, ("amplitude_ppm", "tau_min"), "clock warm-up"):
        rng = np.random.default_rng([seed, 25, i])
        amp = rng.uniform(*AMPLITUDE_PPM) * rng.choice([-1.0, 1.0])
        tau = rng.uniform(*TAU_MIN)
        scene.clock_warmups[name] = ClockWarmup(
            float(given.get("amplitude_ppm", amp)), 60.0 * float(given.get("tau_min", tau))
        )
    return dict(scene.clock_warmups)


def declare_warm_starts(scene, seed: int, picture: dict | bool, clock: dict | bool) -> None:
    """What ``SimRig(warmup_drift=..., clock_warmup=...)`` declares: the picture's drift after a
    start (sim_devices/warmup.py) and the clock's (here); each only when given."""
    if picture:
        declare_warmups(scene, seed, picture)
    if clock:
        declare_clock_warmups(scene, seed, clock)
