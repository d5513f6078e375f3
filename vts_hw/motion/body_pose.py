"""The body's rigid pose over time, with the breathing taken out.

Model of the patient's markers (docs/decisions/0035-breathing-and-body-motion.md): marker i
at frame f is at ``R_f (r_i + v_i s_f) + T_f``: ``r_i`` its reference position (the first
still period), ``v_i`` its breathing vector (mm per unit of the respiratory signal, in the
body's reference frame), ``s_f`` the respiratory signal, ``(R_f, T_f)`` the body's rigid pose
(reference → now, SPECT or VTS frame). :func:`kabsch_batch` fits the pose alone (every frame
at once); :func:`fit_pose_breathing` fits pose and ``s`` together per frame (Gauss-Newton on
the 7 unknowns), so that no filter runs over the pose: a body move keeps its shape and its
start.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["BodyPose", "kabsch_batch", "fit_pose_breathing", "back_to_reference", "POOR_FIT_MM"]

MIN_MARKERS = 3
POOR_FIT_MM = 0.3     # a frame's fit residual over this: the model does not explain its markers (a good
                      # fit is 0.02-0.1 mm; the pose error is of the residual's order): pose degraded


def kabsch_batch(ref, P, seen=None, weights=None):
    """Per frame, the rigid ``(R, T)`` taking ``ref`` (M, 3) onto ``P[f]`` (M, 3) over the
    markers ``seen[f]`` (``weights`` (F, M): a weighted fit). Returns R (F,3,3), T (F,3),
    rms (F,) mm; NaN where < 3 markers."""
    P = np.asarray(P, float)
    seen = np.isfinite(P[..., 0]) if seen is None else seen
    w = seen.astype(float) if weights is None else np.where(seen, weights, 0.0)
    seen = w > 0
    ok = seen.sum(axis=1) >= MIN_MARKERS
    n = w.sum(axis=1)
    nn = np.where(ok, n, 1.0)[:, None]
    Pz = np.where(seen[..., None], P, 0.0)
    ca = (np.broadcast_to(ref, P.shape) * w[..., None]).sum(axis=1) / nn     # both centroids weighted
    cb = (Pz * w[..., None]).sum(axis=1) / nn                                  # alike (an unweighted one
    a = (np.broadcast_to(ref, P.shape) - ca[:, None]) * w[..., None]           # here shifted the fit by
    b = Pz - cb[:, None]                                                       # mm: 0055)
    H = np.einsum("fmi,fmj->fij", a, b)                                        # sum of w a b^T
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("fij,fjk->fik", U, Vt).transpose(0, 2, 1)))
    D = np.zeros((len(P), 3, 3))
    D[:, 0, 0] = 1.0
    D[:, 1, 1] = 1.0
    D[:, 2, 2] = np.where(d == 0, 1.0, d)
    R = np.einsum("fji,fjk,fkl->fil", Vt, D, U.transpose(0, 2, 1))
    T = cb - np.einsum("fij,fj->fi", R, ca)
    res = np.where(seen[..., None], P - np.einsum("fij,mj->fmi", R, ref) - T[:, None], 0.0)
    rms = np.sqrt(np.sum(res ** 2, axis=(1, 2)) / np.maximum(seen.sum(axis=1), 1))
    R[~ok] = np.nan
    T[~ok] = np.nan
    rms[~ok] = np.nan
    return R, T, rms


def _skew(q):
    """(..., 3) -> (..., 3, 3) cross-product matrices."""
    z = np.zeros(q.shape[:-1])
    return np.stack([np.stack([z, -q[..., 2], q[..., 1]], -1),
                     np.stack([q[..., 2], z, -q[..., 0]], -1),
                     np.stack([-q[..., 1], q[..., 0], z], -1)], -2)


def fit_pose_breathing(ref, v, P, seen, R0, T0, s0=None, iterations: int = 6,
                       robust_mm=(10.0, 5.0, 3.0)):
    """Per frame, ``(R, T, s)`` minimising ``sum_i |P_i - R (ref_i + v_i s) - T|^2`` over the
    markers seen (Gauss-Newton from ``R0, T0, s0``), each point weighted by Tukey's biweight of
    its residual at the scale ``robust_mm[k]`` in iteration k (the last scale from then on):
    a wrong point (a ghost, a mismatch) loses its pull. ``v`` all zero: ``s`` stays 0.
    Returns R, T, s, rms (mm, per frame, over the points with weight)."""
    F, M = seen.shape
    known = np.isfinite(ref).all(axis=1) & np.isfinite(v).all(axis=1)   # a marker without a reference: unused
    seen = seen & known[None]
    ref, v = np.nan_to_num(ref), np.nan_to_num(v)
    ok = (seen.sum(axis=1) >= MIN_MARKERS) & np.isfinite(R0[:, 0, 0])
    R = np.where(ok[:, None, None], R0, np.eye(3))
    T = np.where(ok[:, None], T0, 0.0)
    s = np.zeros(F) if s0 is None else np.where(np.isfinite(s0), s0, 0.0)
    breathing = bool(np.any(np.abs(v) > 0))
    Pz = np.where(seen[..., None], P, 0.0)
    for it in range(iterations):
        body = ref[None] + v[None] * s[:, None, None]                 # (F, M, 3)
        q = np.einsum("fij,fmj->fmi", R, body)
        e = Pz - q - T[:, None]
        c = robust_mm[min(it, len(robust_mm) - 1)] if robust_mm else np.inf
        u = np.clip(np.linalg.norm(e, axis=2) / c, 0.0, 1.0)
        wm = np.where(seen, (1 - u ** 2) ** 2, 0.0)
        enough = (wm > 0).sum(axis=1) >= MIN_MARKERS
        wm = np.where(enough[:, None], wm, seen.astype(float))       # too few left: unweighted
        w = wm[..., None]
        e = e * w
        J = np.zeros((F, M, 3, 7))
        J[..., :3] = -_skew(q)
        J[..., 3:6] = np.eye(3)
        J[..., 6] = np.einsum("fij,mj->fmi", R, v)
        J *= w[..., None]
        N = np.einsum("fmki,fmkj->fij", J, J)
        g = np.einsum("fmki,fmk->fi", J, e)
        scale = np.trace(N, axis1=1, axis2=2)[:, None] / 7.0 + 1e-9
        N += np.eye(7)[None] * 1e-9 * scale[:, :, None]
        if not breathing:
            N[:, 6, :] = 0.0
            N[:, :, 6] = 0.0
            N[:, 6, 6] = 1.0
            g[:, 6] = 0.0
        N[~ok] = np.eye(7)
        g[~ok] = 0.0
        dx = np.linalg.solve(N, g[..., None])[..., 0]
        R = np.einsum("fij,fjk->fik", Rotation.from_rotvec(dx[:, :3]).as_matrix(), R)
        T = T + dx[:, 3:6]
        s = s + dx[:, 6]
    body = ref[None] + v[None] * s[:, None, None]
    used = seen & (wm > 0)
    res = np.where(used[..., None], P - np.einsum("fij,fmj->fmi", R, body) - T[:, None], 0.0)
    rms = np.sqrt(np.sum(res ** 2, axis=(1, 2)) / np.maximum(used.sum(axis=1), 1))
    R[~ok], T[~ok], s[~ok], rms[~ok] = np.nan, np.nan, np.nan, np.nan
    return R, T, s, rms


def back_to_reference(R, T, P):
    """Positions ``P`` (F, M, 3) taken back into the reference frame: ``R^T (P - T)``."""
    return np.einsum("fji,fmj->fmi", R, P - T[:, None])


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
