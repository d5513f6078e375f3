"""A simulated fixed camera warming up after it starts: the picture drifts, then settles.

A real fixed camera's picture moves by a pixel or a few in the minutes after it is switched on
(the sensor, lens and housing warm and expand), then stays. Declared per camera
(``SimRig(warmup_drift=True)`` or ``{camera: {amplitude_px, tau_min}}``; ``Scene.warmups``),
the picture is offset by ``amplitude_px * exp(-age / tau)`` along a direction of its own, ``age``
the time since the camera started (``Scene.booted``, set by ``SimAxisCamera`` at construction
and by ``reboot()``). A settled camera (age many ``tau``) is at its scene pose: declaring a
warm-up changes nothing for a camera that started long ago, and a rig without one is as before.

The offset is made by turning the camera about its own centre (a small rotation in camera
coordinates: ``du / f`` about its y axis, ``-dv / f`` about its x axis), so every marker, near
or far, moves the same few pixels, as a warming camera's picture does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["WarmupDrift", "declare_warmups", "AMPLITUDE_PX", "TAU_MIN"]

AMPLITUDE_PX = (2.0, 4.0)  # seeded per camera: how far the picture is off right after the start
TAU_MIN = (8.0, 15.0)  # ... and the time constant of its settling, minutes


@dataclass(frozen=True)
class WarmupDrift:
    """The offset of a camera's picture ``age`` seconds after it started (see the module)."""

    amplitude_px: float
    tau_s: float
    direction: tuple[float, float]  # unit vector in the image (u right, v down)
    focal_px: float

    def __post_init__(self):
        if not (math.isfinite(self.amplitude_px) and self.amplitude_px >= 0):
            raise ValueError(f"amplitude_px must be a number ≥ 0, not {self.amplitude_px!r}")
        if not (math.isfinite(self.tau_s) and self.tau_s > 0):
            raise ValueError(f"tau must be a time > 0, not {self.tau_s!r} s")

    def offset_px(self, age_s: float) -> tuple[float, float]:
        """(du, dv): how far the picture is off ``age_s`` after the start (0 before it: never)."""
        k = self.amplitude_px * math.exp(-max(0.0, age_s) / self.tau_s)
        return k * self.direction[0], k * self.direction[1]

    def rate_px_min(self, age_s: float) -> float:
        """How fast the picture moves ``age_s`` after the start, px/min (the truth a test checks)."""
        return self.amplitude_px / (self.tau_s / 60.0) * math.exp(-max(0.0, age_s) / self.tau_s)

    def settled_after_s(self, limit_px_min: float) -> float:
        """The age (s) from which it moves slower than ``limit_px_min``."""
        r0 = self.amplitude_px / (self.tau_s / 60.0)
        return 0.0 if r0 <= limit_px_min else self.tau_s * math.log(r0 / limit_px_min)

    def rotation_at(self, age_s: float) -> np.ndarray:
        """The camera's turn (rotation vector in camera coordinates) that makes :meth:`offset_px`."""
        du, dv = self.offset_px(age_s)
        return np.array([-dv / self.focal_px, du / self.focal_px, 0.0])


def declared(scene, cameras: dict | bool, keys: tuple[str, ...], what: str):
    """``(index, camera, its given settings)`` of each camera ``cameras`` declares a warm-up for
    (``True``: every camera of ``scene``, nothing given); ValueError naming a camera the scene
    has not, or a setting not among ``keys``. (The picture's drift here, the clock's in
    clock_warmup.py: each seeds what is not given from the camera's index.)"""
    chosen = {name: {} for name in scene.cameras} if cameras is True else dict(cameras or {})
    missing = sorted(set(chosen) - set(scene.cameras))
    if missing:
        raise ValueError(f"{what} for {missing[0]}: the scene has no such camera")
    for i, name in enumerate(scene.cameras):
        if name not in chosen:
            continue
        given = dict(chosen[name] or {})
        unknown = sorted(set(given) - set(keys))
        if unknown:
            raise ValueError(f"{what} of {name}: unknown setting {unknown[0]!r} ({', '.join(keys)})")
        yield i, name, given


def declare_warmups(scene, seed: int, cameras: dict | bool) -> dict[str, WarmupDrift]:
    """Give cameras of ``scene`` a warm-up drift: ``True`` every camera, seeded per camera
    (amplitude in :data:`AMPLITUDE_PX`, time constant in :data:`TAU_MIN`, direction at random);
    or ``{camera: {"amplitude_px": .., "tau_min": ..}}`` (either key may be left out: seeded)."""
    for i, name, given in declared(scene, cameras, ("amplitude_px", "tau_min"), "warm-up drift"):
        rng = np.random.default_rng([seed, 24, i])
        amp, tau, phi = rng.uniform(*AMPLITUDE_PX), rng.uniform(*TAU_MIN), rng.uniform(0, 2 * math.pi)
        scene.warmups[name] = WarmupDrift(
            float(given.get("amplitude_px", amp)),
            60.0 * float(given.get("tau_min", tau)),
            (math.cos(phi), math.sin(phi)),
            scene.cameras[name].focal,
        )
    return dict(scene.warmups)
