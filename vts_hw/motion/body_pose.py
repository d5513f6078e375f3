"""The body's rigid pose over time, with the breathing taken out: what the patient model
(:mod:`vts_hw.motion.patient_model`) fitted, frame by frame, as one result shape for the
offline analysis and the live path's pose series (docs/decisions/0035, 0092).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["BodyPose", "POOR_FIT_MM"]

POOR_FIT_MM = 0.3  # a frame's fit residual over this: the model does not explain its markers (a good
# fit is 0.02-0.1 mm; the pose error is of the residual's order): pose degraded


@dataclass
class BodyPose:
    """The body's pose per frame: ``R`` (F,3,3), ``T`` (F,3) mm, reference → now (x -> R x + T);
    ``resp`` the respiratory signal fitted with it; ``rms_mm`` the fit residual; ``n_markers``
    markers used; ``centre``: the reference centroid of the patient's markers (mm)."""

    t: np.ndarray
    R: np.ndarray
    T: np.ndarray
    resp: np.ndarray
    rms_mm: np.ndarray
    n_markers: np.ndarray
    centre: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.T[:, 0])

    @property
    def poor_fit(self) -> np.ndarray:
        """(F,) frames with a pose whose fit residual is over :data:`POOR_FIT_MM`."""
        return self.valid & (np.nan_to_num(self.rms_mm, nan=np.inf) > POOR_FIT_MM)

    def six_dof(self) -> np.ndarray:
        """(F, 6): tx, ty, tz mm, rx, ry, rz deg (extrinsic x-y-z, as RigidTransform.as_euler_xyz_deg)."""
        out = np.full((len(self.t), 6), np.nan)
        v = self.valid
        out[v, :3] = self.T[v]
        out[v, 3:] = Rotation.from_matrix(self.R[v]).as_euler("xyz", degrees=True)
        return out

    def quaternions(self) -> np.ndarray:
        """(F, 4) unit quaternions x, y, z, w (scalar last)."""
        out = np.full((len(self.t), 4), np.nan)
        v = self.valid
        out[v] = Rotation.from_matrix(self.R[v]).as_quat()
        return out

    def angle_deg(self) -> np.ndarray:
        out = np.full(len(self.t), np.nan)
        v = self.valid
        out[v] = np.degrees(Rotation.from_matrix(self.R[v]).magnitude())
        return out

    def centre_shift(self) -> np.ndarray:
        """(F, 3): where the reference centroid of the markers went (mm, displacement)."""
        return np.einsum("fij,j->fi", self.R, self.centre) + self.T - self.centre

    def points(self, X) -> np.ndarray:
        """(F, K, 3): reference points ``X`` (K, 3) carried by the pose."""
        return np.einsum("fij,kj->fki", self.R, np.asarray(X, float)) + self.T[:, None]
