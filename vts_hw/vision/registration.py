"""Rigid registration of corresponding 3D point sets (e.g. VTS → SPECT with the 7-sphere phantom).

* :class:`RigidTransform` — ``x -> R @ x + t`` (mm); Euler angles, inverse, composition, JSON.
* :func:`kabsch` — least-squares rigid fit by SVD with the reflection fix; :func:`kabsch_batch`
  the same fit for many frames at once (weighted, markers unseen left out): the one Kabsch of
  the project (issue 33).
* :func:`fre` / :func:`loo_tre` — fiducial registration error and leave-one-out target
  registration error (the fit residual alone says little about accuracy: docs/design.md).
* :func:`difference` — how far apart two transforms are (rotation in degrees, translation in mm).
* :func:`read_mapping` — the VTS → SPECT mapping's one loader (a transform file, or a saved
  mapping that holds one; the room and every analysis read it so).

Euler convention everywhere: **extrinsic x-y-z** (rotate about the fixed x axis, then the fixed
y, then the fixed z: ``R = Rz(γ) @ Ry(β) @ Rx(α)``), i.e. scipy ``Rotation.as_euler("xyz")``,
in degrees. See docs/decisions/0013-triangulation-and-registration.md.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vts_hw import __version__
from vts_hw.bounded import SMALL, read_text
from vts_hw.errors import DataError
from vts_hw.files import write_json_atomic

__all__ = [
    "RigidTransform",
    "kabsch",
    "kabsch_batch",
    "fre",
    "loo_tre",
    "LooTre",
    "difference",
    "TransformDifference",
    "EULER_CONVENTION",
    "read_mapping",
]

EULER_CONVENTION = "extrinsic x-y-z (scipy Rotation.as_euler('xyz')), degrees"
_FORMAT = "vts-hw rigid transform v1"


def _points(p, name: str) -> np.ndarray:
    arr = np.asarray(p, float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must be an Nx3 array of points, got shape {arr.shape}")
    return arr


@dataclass(frozen=True, eq=False)
class RigidTransform:
    """A proper rigid motion ``x -> R @ x + t`` (R 3x3 rotation, t in mm).

    ``meta`` is free-form JSON-able context kept by :meth:`to_dict` (e.g. the source frames).
    """

    R: np.ndarray
    t: np.ndarray
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "R", np.asarray(self.R, float).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, float).reshape(3))

    # ------------------------------------------------------------ construction
    @classmethod
    def identity(cls) -> RigidTransform:
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_euler_xyz_deg(cls, angles_deg, t=(0.0, 0.0, 0.0)) -> RigidTransform:
        """From rotations about x, y, z (extrinsic, degrees) and a translation (mm)."""
        return cls(Rotation.from_euler("xyz", angles_deg, degrees=True).as_matrix(), t)

    @classmethod
    def from_rotvec(cls, rotvec, t=(0.0, 0.0, 0.0)) -> RigidTransform:
        """From a rotation vector (axis * angle, radians) and a translation (mm)."""
        return cls(Rotation.from_rotvec(np.asarray(rotvec, float)).as_matrix(), t)

    # ------------------------------------------------------------ algebra
    def apply(self, pts) -> np.ndarray:
        """The transformed points: Nx3 in, Nx3 out (a single 3-vector gives a 3-vector)."""
        p = np.asarray(pts, float)
        out = p.reshape(-1, 3) @ self.R.T + self.t
        return out.reshape(p.shape)

    def inverse(self) -> RigidTransform:
        return RigidTransform(self.R.T, -self.R.T @ self.t)

    def compose(self, other: RigidTransform) -> RigidTransform:
        """``self ∘ other``: apply ``other`` first, then ``self``."""
        return RigidTransform(self.R @ other.R, self.R @ other.t + self.t)

    def as_matrix(self) -> np.ndarray:
        """4x4 homogeneous matrix."""
        m = np.eye(4)
        m[:3, :3], m[:3, 3] = self.R, self.t
        return m

    def as_euler_xyz_deg(self) -> np.ndarray:
        """Rotations about x, y, z in degrees, extrinsic x-y-z (scipy ``as_euler("xyz")``)."""
        return Rotation.from_matrix(self.R).as_euler("xyz", degrees=True)

    @property
    def rotation_angle_deg(self) -> float:
        """Angle of the rotation about its axis, degrees in [0, 180]."""
        # The rotation vector's norm: accurate near 0, unlike arccos((trace - 1) / 2).
        return float(np.degrees(np.linalg.norm(Rotation.from_matrix(self.R).as_rotvec())))

    # ------------------------------------------------------------ persistence
    def to_dict(self) -> dict:
        """JSON-able dict: R, t, the Euler angles (for people; ignored on load), the
        convention, creation time (UTC ISO 8601) and ``vts_hw.__version__``."""

        return {
            "format": _FORMAT,
            "R": self.R.tolist(),
            "t_mm": self.t.tolist(),
            "euler_xyz_deg": self.as_euler_xyz_deg().tolist(),
            "rotation_angle_deg": self.rotation_angle_deg,
            "euler_convention": EULER_CONVENTION,
            "created": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "vts_hw_version": __version__,
            "meta": dict(self.meta),
        }

    @classmethod
    def from_dict(cls, d: dict) -> RigidTransform:
        """Inverse of :meth:`to_dict`; a matrix that is not a rotation raises :class:`DataError`."""
        try:
            R = np.asarray(d["R"], float).reshape(3, 3)
            t = np.asarray(d["t_mm"], float).reshape(3)
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise DataError(f"not a rigid transform: missing or malformed R/t_mm ({exc})") from None
        if not np.all(np.isfinite(R)) or not np.all(np.isfinite(t)):
            raise DataError("not a rigid transform: R or t_mm holds non-finite numbers")
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise DataError("not a rigid transform: R is not a proper rotation matrix")
        meta = d.get("meta") or {}
        if not isinstance(meta, dict):
            raise DataError(f"not a rigid transform: 'meta' must be a JSON object, not {type(meta).__name__}")
        return cls(R, t, dict(meta))

    def save(self, path) -> Path:
        """Write :meth:`to_dict` as JSON, whole or not at all (vts_hw/files.py)."""
        return write_json_atomic(path, self.to_dict())

    @classmethod
    def load(cls, path) -> RigidTransform:
        """Read a file written by :meth:`save`; a bad file raises :class:`DataError`."""
        path = Path(path)
        try:
            d = json.loads(read_text(path, SMALL, "transform file"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise DataError(f"cannot read transform file {path}: {exc}") from None
        except (ValueError, RecursionError) as exc:  # a 5000-digit number, arrays nested 1000 deep
            why = "nested too deeply" if isinstance(exc, RecursionError) else str(exc).split(":")[0]
            raise DataError(f"cannot read transform file {path}: {why}") from None
        if not isinstance(d, dict):
            raise DataError(f"cannot read transform file {path}: not a JSON object")
        try:
            return cls.from_dict(d)
        except DataError as exc:
            raise DataError(f"{path}: {exc}") from None


def kabsch(A, B) -> RigidTransform:
    """Least-squares rigid transform with ``B ≈ R @ A + t`` (Kabsch / Arun, SVD).

    A and B are Nx3 corresponding points, N >= 3 and not all collinear. The reflection fix
    (``diag(1, 1, sign(det))``) makes R a proper rotation even for coplanar or mirrored data.
    """
    A, B = _points(A, "A"), _points(B, "B")
    if A.shape != B.shape:
        raise ValueError(f"A and B must have the same shape, got {A.shape} and {B.shape}")
    if len(A) < 3:
        raise ValueError("kabsch needs at least 3 point pairs")
    sv = np.linalg.svd(A - A.mean(axis=0), compute_uv=False)
    if sv[1] <= 1e-12 * max(sv[0], 1e-300):
        raise ValueError("kabsch: the points are collinear (the rotation about their line is undefined)")
    R, t, _ = kabsch_batch(A, B[None])
    return RigidTransform(R[0], t[0])


def kabsch_batch(ref, P, seen=None, weights=None):
    """Per frame, the rigid ``(R, T)`` taking ``ref`` (M, 3) onto ``P[f]`` (M, 3) over the
    markers ``seen[f]`` (``weights`` (F, M): a weighted fit). Returns R (F,3,3), T (F,3),
    rms (F,) mm; NaN where < 3 markers."""
    P = np.asarray(P, float)
    seen = np.isfinite(P[..., 0]) if seen is None else seen
    w = seen.astype(float) if weights is None else np.where(seen, weights, 0.0)
    seen = w > 0
    ok = seen.sum(axis=1) >= 3
    n = w.sum(axis=1)
    nn = np.where(ok, n, 1.0)[:, None]
    Pz = np.where(seen[..., None], P, 0.0)
    ca = (np.broadcast_to(ref, P.shape) * w[..., None]).sum(axis=1) / nn  # both centroids weighted
    cb = (Pz * w[..., None]).sum(axis=1) / nn  # alike (an unweighted one
    a = (np.broadcast_to(ref, P.shape) - ca[:, None]) * w[..., None]  # here shifted the fit by
    b = Pz - cb[:, None]  # mm: 0055)
    H = np.einsum("fmi,fmj->fij", a, b)  # sum of w a b^T
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("fij,fjk->fik", U, Vt).transpose(0, 2, 1)))
    D = np.zeros((len(P), 3, 3))
    D[:, 0, 0] = 1.0
    D[:, 1, 1] = 1.0
    D[:, 2, 2] = np.where(d == 0, 1.0, d)
    R = np.einsum("fji,fjk,fkl->fil", Vt, D, U.transpose(0, 2, 1))
    T = cb - np.einsum("fij,fj->fi", R, ca)
    res = np.where(seen[..., None], P - np.einsum("fij,mj->fmi", R, ref) - T[:, None], 0.0)
    rms = np.sqrt(np.sum(res**2, axis=(1, 2)) / np.maximum(seen.sum(axis=1), 1))
    R[~ok] = np.nan
    T[~ok] = np.nan
    rms[~ok] = np.nan
    return R, T, rms


def fre(A, B, T: RigidTransform) -> float:
    """Fiducial registration error: RMS over points of ``|T(A_i) - B_i|`` (mm)."""
    A, B = _points(A, "A"), _points(B, "B")
    return float(np.sqrt(np.mean(np.sum((T.apply(A) - B) ** 2, axis=1))))


@dataclass(frozen=True)
class LooTre:
    """Leave-one-out target registration error: per point (fit on the others, error at the
    left-out point, mm), their RMS and max."""

    per_point: np.ndarray
    rms: float
    max: float


def loo_tre(A, B) -> LooTre:
    """Leave-one-out TRE: for each i, :func:`kabsch` on all pairs but i, error ``|T(A_i) - B_i|``.

    Needs N >= 4 (three points remain for each fit).
    """
    A, B = _points(A, "A"), _points(B, "B")
    n = len(A)
    if n < 4:
        raise ValueError("loo_tre needs at least 4 point pairs")
    errs = np.empty(n)
    for i in range(n):
        keep = np.arange(n) != i
        T = kabsch(A[keep], B[keep])
        errs[i] = np.linalg.norm(T.apply(A[i]) - B[i])
    return LooTre(errs, float(np.sqrt(np.mean(errs**2))), float(errs.max()))


@dataclass(frozen=True)
class TransformDifference:
    """How ``T2`` differs from ``T1``.

    ``angle_deg``: angle of ``R1ᵀ R2``. ``axes_deg``: that relative rotation as extrinsic x-y-z
    Euler angles. ``euler_diff_deg``: ``euler(T2) - euler(T1)`` wrapped to (-180, 180] (what
    a table of the two systems' 6-DOF numbers shows). ``translation_mm``: ``t2 - t1``;
    ``translation_norm_mm`` its length.
    """

    angle_deg: float
    axes_deg: np.ndarray
    euler_diff_deg: np.ndarray
    translation_mm: np.ndarray
    translation_norm_mm: float


def difference(T1: RigidTransform, T2: RigidTransform) -> TransformDifference:
    """Rotation difference (angle of ``R1ᵀ R2``, degrees, and per axis) and translation
    difference (mm) of two transforms, e.g. the VTS and SPECT estimates of the same motion."""
    rel = RigidTransform(T1.R.T @ T2.R, np.zeros(3))
    diff = T2.as_euler_xyz_deg() - T1.as_euler_xyz_deg()
    diff = -((-diff + 180.0) % 360.0 - 180.0)  # wrap to (-180, 180]
    dt = T2.t - T1.t
    return TransformDifference(rel.rotation_angle_deg, rel.as_euler_xyz_deg(), diff, dt, float(np.linalg.norm(dt)))


def read_mapping(mapping):
    """THE VTS → SPECT mapping loader: a RigidTransform as given (a SpectMapping: its
    ``transform``), or read from a path (a RigidTransform file, or a saved SpectMapping whose
    ``transform`` it holds); DataError naming the file for anything else."""
    if mapping is None or not isinstance(mapping, (str, os.PathLike)):
        return (
            getattr(mapping, "transform", mapping) if mapping is not None and not hasattr(mapping, "apply") else mapping
        )
    path = Path(mapping)
    try:
        return RigidTransform.load(path)
    except DataError:
        try:
            d = json.loads(read_text(path, SMALL, "mapping"))
            return RigidTransform.from_dict(d["transform"])
        except Exception:
            raise DataError(f"{path}: not a VTS -> SPECT transform file") from None
