"""A simulated camera's lens focus and mount: what commissioning adjusts (issue 24 §2).

* **focus** -- ``focus_blur_px``: the defocus of the lens, the standard deviation (px) of a
  Gaussian blur of the marker light (sim_devices/render.py); 0 is a lens in focus and costs the
  renderer nothing.
* **mount** -- ``yaw_deg`` and ``pitch_deg``: how far the camera's mount is turned from the
  pose the scene gives it. ``yaw_deg`` > 0 turns the camera to its right (the picture's content
  moves left), ``pitch_deg`` > 0 tilts it up (the content moves down). Applied on top of the
  camera's slow drift (:meth:`Scene.camera_at`), so the true calibration written while a mount
  is turned is the turned camera, and one turned afterwards no longer matches its calibration,
  as a real camera knocked after calibration.

Set per camera with :func:`set_optics` (``SimRig(optics=...)``, ``SimCameraSource.set_optics``,
``POST /sim/optics`` on the simulated camera). docs/decisions/0068-aim-and-focus.md.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np

__all__ = ["Optics", "set_optics", "optics_of", "mount_rotation", "FIELDS"]

FIELDS = ("focus_blur_px", "yaw_deg", "pitch_deg")
MAX_BLUR_PX = 20.0
MAX_TURN_DEG = 45.0


@dataclass(frozen=True)
class Optics:
    """One camera's focus and mount (see the module docstring)."""

    focus_blur_px: float = 0.0
    yaw_deg: float = 0.0
    pitch_deg: float = 0.0

    def __post_init__(self):
        for name in FIELDS:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{name} must be a finite number, not {v!r}")
            object.__setattr__(self, name, float(v))
        if not 0.0 <= self.focus_blur_px <= MAX_BLUR_PX:
            raise ValueError(f"focus_blur_px must be 0 to {MAX_BLUR_PX:g} px, not {self.focus_blur_px:g}")
        for name in ("yaw_deg", "pitch_deg"):
            if abs(getattr(self, name)) > MAX_TURN_DEG:
                raise ValueError(f"{name} must be within ±{MAX_TURN_DEG:g}°, not {getattr(self, name):g}")

    def changed(self, changes: dict) -> Optics:
        """A copy with ``changes`` (names of :data:`FIELDS`); an unknown name is a ValueError."""
        unknown = sorted(set(changes) - set(FIELDS))
        if unknown:
            raise ValueError(f"unknown optics setting {unknown[0]!r} (known: {', '.join(FIELDS)})")
        return replace(self, **changes)

    def to_dict(self) -> dict:
        return asdict(self)


def mount_rotation(optics: Optics) -> np.ndarray | None:
    """The rotation vector (camera coordinates, radians) of the mount's turn; None when it is
    not turned. Pan about the camera's vertical axis, then tilt about its horizontal axis."""
    if optics.yaw_deg == 0.0 and optics.pitch_deg == 0.0:
        return None
    import cv2

    pan = cv2.Rodrigues(np.array([0.0, -math.radians(optics.yaw_deg), 0.0]))[0]
    tilt = cv2.Rodrigues(np.array([-math.radians(optics.pitch_deg), 0.0, 0.0]))[0]
    return cv2.Rodrigues(tilt @ pan)[0].ravel()


def optics_of(scene, renderer, cam: str) -> Optics:
    """Camera ``cam``'s optics as the scene and renderer hold them."""
    return (
        scene.optics.get(cam, Optics())
        if renderer is None
        else replace(scene.optics.get(cam, Optics()), focus_blur_px=float(renderer.focus.get(cam, 0.0)))
    )


def set_optics(scene, renderer, cam: str, **changes) -> Optics:
    """Change camera ``cam``'s focus and/or mount, at once (all or nothing: a bad value changes
    nothing and raises ValueError)."""
    if cam not in scene.cameras:
        raise ValueError(f"the scene has no camera {cam!r}")
    new = optics_of(scene, renderer, cam).changed(changes)
    scene.optics[cam] = new
    rvec = mount_rotation(new)
    if rvec is None:
        scene.mounts.pop(cam, None)
    else:
        scene.mounts[cam] = rvec
    if renderer is not None:
        renderer.focus[cam] = new.focus_blur_px
    return new
