"""NumPy ``.npz`` volumes: keys ``data`` (3-D), ``voxel_size`` (3, mm), ``origin`` (3, mm).

``data`` is in the canonical layout ``data[z, y, x]`` (indices increasing along +Z, +Y, +X)
unless an optional ``direction`` (3×3, row ``a`` = SPECT unit vector of array axis ``a``) says
otherwise. ``voxel_size`` is per array axis, in the order of ``data.shape`` — (dz, dy, dx) for
the canonical layout. ``origin`` is the SPECT (X, Y, Z) position of the centre of voxel
``[0, 0, 0]``.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from vts_hw.errors import DataError
from vts_hw.spect.volume import CANONICAL_DIRECTION, Volume


def read_npz(path) -> Volume:
    """Read a ``.npz`` volume; returns the canonical :class:`Volume`."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise DataError(f"{path}: not a readable .npz archive ({e})") from None
    for key in ("data", "voxel_size", "origin"):
        if key not in arrays:
            raise DataError(f"{path}: npz missing key '{key}' (has {sorted(arrays)})")
    data = arrays["data"]
    if data.ndim != 3:
        raise DataError(f"{path}: 'data' must be 3-D, has shape {data.shape}")
    if not np.issubdtype(data.dtype, np.number):
        raise DataError(f"{path}: 'data' has non-numeric type {data.dtype}")
    for key in ("voxel_size", "origin"):
        if arrays[key].size != 3 or not np.issubdtype(arrays[key].dtype, np.number):
            raise DataError(f"{path}: '{key}' must be 3 numbers, got {arrays[key]!r}")
    direction = arrays.get("direction", CANONICAL_DIRECTION)
    try:
        return Volume(data, arrays["voxel_size"], arrays["origin"], direction, path).canonical()
    except ValueError as e:
        raise DataError(f"{path}: {e}") from None


def write_npz(volume: Volume, path) -> Path:
    """Write ``volume`` (canonical layout) as a compressed ``.npz``; returns the path."""
    path = Path(path)
    v = volume.canonical()
    with open(path, "wb") as f:  # keeps the exact name (np.savez adds .npz otherwise)
        np.savez_compressed(f, data=v.data, voxel_size=np.asarray(v.voxel_size),
                            origin=np.asarray(v.origin))
    return path
