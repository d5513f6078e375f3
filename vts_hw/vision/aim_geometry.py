"""The room as one camera sees it: the SPECT field of view, the table and the gantry's opening
projected into its picture through its calibration and the VTS -> SPECT mapping.

:class:`RoomView` holds one calibrated camera (``K, dist, R, t`` in the VTS frame, mm) and the
mapping (a ``RigidTransform`` VTS -> SPECT). Everything it draws is in the SPECT frame
(vts_hw/spect/frame.py): the FOV is a cylinder about the axis of rotation (parallel to Z through
the FOV centre), ``fov_diameter_mm`` across and ``fov_length_mm`` long; the gantry's opening a
wider, ``bore_depth_mm`` deep one on the same axis; the table top a rectangle at
``table_top_y_mm`` (its nominal position: the table moves). The FOV centre is the centre of the
volume the mapping was made from when the mapping says (``meta.spect_volume.centre_mm``), else
the SPECT frame's origin.

What it draws is where the calibration puts the camera: a camera turned since it was calibrated
no longer looks there (the drift QA says whether it turned; calibrate it again).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from vts_hw.vision.aim_settings import AimSettings

__all__ = ["RoomView", "Outline", "fov_centre"]

_N = 72  # points per circle


def fov_centre(mapping) -> np.ndarray:
    """The FOV centre in the SPECT frame: the mapping's volume centre, else the origin."""
    vol = (getattr(mapping, "meta", None) or {}).get("spect_volume") or {}
    c = vol.get("centre_mm") if isinstance(vol, dict) else None
    try:
        out = np.asarray(c, float).reshape(3)
        return out if np.all(np.isfinite(out)) else np.zeros(3)
    except (TypeError, ValueError):
        return np.zeros(3)


@dataclass(frozen=True)
class Outline:
    """Polylines (pixels) of one thing drawn into the picture; ``share_inside``: the share of its
    points in front of the camera and inside the picture."""

    name: str
    lines: tuple[np.ndarray, ...]
    share_inside: float


class RoomView:
    """One calibrated camera and the VTS -> SPECT mapping (see the module docstring)."""

    def __init__(self, camera, mapping, size: tuple[int, int], settings: AimSettings):
        self.camera = camera  # K, dist, R, t (VTS frame -> camera), mm
        self.mapping = mapping  # RigidTransform VTS -> SPECT
        self.size = (int(size[0]), int(size[1]))
        self.settings = settings
        self.centre = fov_centre(mapping)
        inv = mapping.inverse()
        # SPECT -> camera in one rigid motion: x_c = R_c (R_m^T (x_s - t_m)) + t_c
        self.R = np.asarray(camera.R, float) @ inv.R
        self.t = np.asarray(camera.R, float) @ inv.t + np.asarray(camera.t, float)
        self.K = np.asarray(camera.K, float)
        self.dist = np.asarray(camera.dist, float).ravel()

    @property
    def focal_px(self) -> float:
        return float((self.K[0, 0] + self.K[1, 1]) / 2)

    @property
    def eye(self) -> np.ndarray:
        """The camera's optical centre in the SPECT frame."""
        return -self.R.T @ self.t

    def to_camera(self, pts_spect) -> np.ndarray:
        return np.asarray(pts_spect, float).reshape(-1, 3) @ self.R.T + self.t

    def project(self, pts_spect) -> tuple[np.ndarray, np.ndarray]:
        """Pixels (Nx2) of SPECT-frame points (Nx3), distortion included, and whether each is in
        front of the camera."""
        pts = np.asarray(pts_spect, float).reshape(-1, 3)
        front = self.to_camera(pts)[:, 2] > 1.0
        uv, _ = cv2.projectPoints(pts.reshape(-1, 1, 3), cv2.Rodrigues(self.R)[0], self.t, self.K, self.dist)
        return uv.reshape(-1, 2), front

    def angles_deg(self, pt_spect) -> tuple[float, float]:
        """``(right, down)``: how far a SPECT-frame point lies to the right of and below the
        camera's optical axis, degrees."""
        x, y, z = self.to_camera(pt_spect)[0]
        return math.degrees(math.atan2(x, z)), math.degrees(math.atan2(y, z))

    # ---------------------------------------------------------------- what is drawn
    def _circle(self, radius: float, z: float) -> np.ndarray:
        a = np.linspace(0.0, 2 * np.pi, _N + 1)
        c = self.centre
        return np.column_stack([c[0] + radius * np.cos(a), c[1] + radius * np.sin(a), np.full(a.size, c[2] + z)])

    def _outline(self, name: str, pieces: list[np.ndarray]) -> Outline:
        w, h = self.size
        lines, inside, total = [], 0, 0
        for piece in pieces:
            uv, front = self.project(piece)
            total += len(uv)
            inside += int(np.sum(front & (uv[:, 0] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= h - 1)))
            # a line is drawn only through points in front of the camera
            for run in np.split(np.arange(len(uv)), np.nonzero(~front)[0]):
                seen = [i for i in run if front[i]]
                if len(seen) >= 2:
                    lines.append(uv[seen])
        return Outline(name, tuple(lines), inside / total if total else 0.0)

    def fov(self) -> Outline:
        """The SPECT FOV: its two end circles and four lines along its length."""
        s = self.settings
        r, half = s.fov_diameter_mm / 2, s.fov_length_mm / 2
        ends = [self._circle(r, -half), self._circle(r, half)]
        sides = [np.linspace(ends[0][i], ends[1][i], 12) for i in range(0, _N, _N // 4)]
        return self._outline("fov", ends + sides)

    def bore(self) -> Outline:
        """The gantry's opening: its front and back rims."""
        s = self.settings
        return self._outline(
            "gantry", [self._circle(s.bore_diameter_mm / 2, z) for z in (-s.bore_depth_mm / 2, s.bore_depth_mm / 2)]
        )

    def table(self) -> Outline:
        """The table top at its nominal position: a rectangle and its centre line."""
        s = self.settings
        x, y = s.table_width_mm / 2, s.table_top_y_mm
        z0, z1 = s.table_z_mm
        corners = [(-x, y, z0), (x, y, z0), (x, y, z1), (-x, y, z1), (-x, y, z0)]
        edges = [np.linspace(corners[i], corners[i + 1], 40) for i in range(4)]
        middle = np.linspace((0.0, y, z0), (0.0, y, z1), 40)
        shift = np.array([self.centre[0], 0.0, 0.0])
        return self._outline("table", [e + shift for e in edges] + [middle + shift])

    def through_bore(self, pixels) -> np.ndarray:
        """Whether the line of sight through each pixel (Nx2) passes through the gantry's opening
        (inside its radius at both rims, beyond the camera)."""
        px = np.asarray(pixels, float).reshape(-1, 1, 2)
        if not len(px):
            return np.zeros(0, bool)
        norm = cv2.undistortPoints(px, self.K, self.dist).reshape(-1, 2)
        rays = np.column_stack([norm, np.ones(len(norm))]) @ self.R  # camera -> SPECT directions (R^T d)
        eye, c, s = self.eye, self.centre, self.settings
        ok = np.ones(len(rays), bool)
        for z in (-s.bore_depth_mm / 2, s.bore_depth_mm / 2):
            dz = rays[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                lam = (c[2] + z - eye[2]) / dz
            p = eye + lam[:, None] * rays
            radial = np.hypot(p[:, 0] - c[0], p[:, 1] - c[1])
            ok &= np.isfinite(lam) & (lam > 0) & (radial < s.bore_diameter_mm / 2)
        return ok
