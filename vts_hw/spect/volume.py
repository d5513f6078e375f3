"""The reconstructed SPECT volume: a data array with its place in the SPECT frame.

The SPECT frame (docs/design.md, :mod:`vts_hw.spect.frame`): millimetres, right-handed, X
towards the patient's left, Y anterior (up for a supine patient), Z towards the feet; its origin
is where the volume places it (the centre of the field of view on the axis of rotation for a
centred Interfile or CASToR image; DICOM's patient-coordinate origin for DICOM NM).

A :class:`Volume` is an affine grid:

* ``data`` — a 3-D array; array axis ``a`` (0, 1, 2) steps along ``direction[a]``;
* ``voxel_size`` — mm per step along each **array axis** (same order as ``data.shape``);
* ``origin`` — SPECT-frame position (X, Y, Z, mm) of the **centre** of voxel ``[0, 0, 0]``;
* ``direction`` — 3×3, row ``a`` is the SPECT-frame unit vector of array axis ``a``.

The *canonical* layout, which every reader returns, is ``data[z, y, x]`` with the indices
increasing along +Z, +Y, +X: ``direction = [[0, 0, 1], [0, 1, 0], [1, 0, 0]]``, so
``voxel_size = (dz, dy, dx)``. :meth:`Volume.canonical` brings any axis-aligned volume
(``direction`` a signed permutation) to that layout by transposes and flips, without
resampling.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

CANONICAL_DIRECTION = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])


def triple(values) -> tuple[float, float, float]:
    """Three numbers (a list, a tuple, an array of 3) as the tuple a Volume keeps; ValueError
    for another count."""
    x, y, z = (float(v) for v in np.asarray(values, dtype=float).reshape(3))
    return x, y, z


@dataclass(frozen=True)
class Volume:
    """A 3-D image placed in the SPECT frame (see the module docstring for the conventions)."""

    data: np.ndarray
    voxel_size: tuple[float, float, float]
    origin: tuple[float, float, float]
    direction: np.ndarray = field(default_factory=lambda: CANONICAL_DIRECTION.copy())
    source: Path | None = None  # the file it was read from, for messages

    def __post_init__(self) -> None:
        data = np.asarray(self.data)
        if data.ndim != 3:
            raise ValueError(f"a Volume needs a 3-D array, got shape {data.shape}")
        vs = triple(self.voxel_size)
        if not all(np.isfinite(v) and v > 0 for v in vs):
            raise ValueError(f"voxel sizes must be positive, got {vs}")
        org = triple(self.origin)
        d = np.asarray(self.direction, dtype=float).reshape(3, 3)
        if not np.allclose(d @ d.T, np.eye(3), atol=1e-6):
            raise ValueError(f"direction rows must be orthonormal, got {d.tolist()}")
        object.__setattr__(self, "data", data)
        object.__setattr__(self, "voxel_size", vs)
        object.__setattr__(self, "origin", org)
        object.__setattr__(self, "direction", d)

    @property
    def affine(self) -> np.ndarray:
        """4×4 matrix taking homogeneous array indices ``(i0, i1, i2, 1)`` to SPECT mm."""
        a = np.eye(4)
        a[:3, :3] = (self.direction * np.asarray(self.voxel_size)[:, None]).T
        a[:3, 3] = self.origin
        return a

    def index_to_mm(self, index) -> np.ndarray:
        """SPECT-frame position (mm) of (fractional) array indices; shape (..., 3) -> (..., 3)."""
        idx = np.asarray(index, dtype=float)
        steps = self.direction * np.asarray(self.voxel_size)[:, None]  # row a: mm per index a
        return np.asarray(self.origin) + idx @ steps

    def mm_to_index(self, point) -> np.ndarray:
        """Inverse of :meth:`index_to_mm` (fractional indices)."""
        p = np.asarray(point, dtype=float) - np.asarray(self.origin)
        return (p @ self.direction.T) / np.asarray(self.voxel_size)

    def canonical(self) -> Volume:
        """The same volume as ``data[z, y, x]`` with indices increasing along +Z, +Y, +X."""
        d = np.round(self.direction)
        if not (np.allclose(d, self.direction, atol=1e-6) and np.allclose(np.abs(d).sum(0), 1)):
            raise ValueError("only an axis-aligned volume can be made canonical (no resampling)")
        # array axis that runs along SPECT Z, Y, X:
        order = [int(np.flatnonzero(d[:, c])[0]) for c in (2, 1, 0)]
        data = np.transpose(self.data, order)
        vs = triple([self.voxel_size[a] for a in order])
        first = np.zeros(3)
        for new_axis, a in enumerate(order):
            if d[a].sum() < 0:  # this axis runs backwards: flip it
                data = np.flip(data, axis=new_axis)
                first[a] = self.data.shape[a] - 1
        origin = self.index_to_mm(first)
        return Volume(np.ascontiguousarray(data), vs, triple(origin), CANONICAL_DIRECTION.copy(), self.source)
