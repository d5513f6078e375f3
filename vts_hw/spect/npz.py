"""NumPy ``.npz`` volumes: keys ``data`` (3-D), ``voxel_size`` (3, mm), ``origin`` (3, mm).

``data`` is in the canonical layout ``data[z, y, x]`` (indices increasing along +Z, +Y, +X)
unless an optional ``direction`` (3×3, row ``a`` = SPECT unit vector of array axis ``a``) says
otherwise. ``voxel_size`` is per array axis, in the order of ``data.shape`` — (dz, dy, dx) for
the canonical layout. ``origin`` is the SPECT (X, Y, Z) position of the centre of voxel
``[0, 0, 0]``.
"""

from __future__ import annotations

import io
import math
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np
from numpy.lib import format as fmt

from vts_hw.errors import DataError
from vts_hw.files import write_atomic
from vts_hw.spect.volume import CANONICAL_DIRECTION, Volume, triple

KEYS = ("data", "voxel_size", "origin", "direction")
MAX_ARRAY_BYTES = 4 << 30  # 4 GiB: far above any reconstructed volume
# what a broken zip archive or .npy member raises from zipfile, zlib and numpy.lib.format
_BROKEN = (
    OSError,
    EOFError,
    ValueError,
    KeyError,
    NotImplementedError,
    RuntimeError,
    zipfile.BadZipFile,
    zlib.error,
    struct.error,
)


def _arrays(path: Path) -> dict[str, np.ndarray]:
    """The archive's arrays we read, each checked against its declared size before it is
    allocated (a header may claim terabytes); never unpickles."""
    arrays = {}
    with zipfile.ZipFile(path) as zf:
        for info in zf.infolist():
            key = info.filename[:-4] if info.filename.endswith(".npy") else None
            if key not in KEYS or key in arrays:
                continue
            with zf.open(info) as f:
                major, _minor = fmt.read_magic(f)
                read_header = fmt.read_array_header_1_0 if major == 1 else fmt.read_array_header_2_0
                shape, _fortran, dtype = read_header(f)
            if dtype.hasobject:
                raise DataError(f"{path}: '{key}' holds Python objects, not numbers")
            size = math.prod(shape) * dtype.itemsize
            if size > min(info.file_size, MAX_ARRAY_BYTES):
                raise DataError(
                    f"{path}: '{key}' claims {size} bytes of {dtype} {tuple(shape)}, "
                    f"but its member holds {info.file_size}"
                )
            with zf.open(info) as f:
                arrays[key] = fmt.read_array(f, allow_pickle=False)
    return arrays


def read_npz(path) -> Volume:
    """Read a ``.npz`` volume; returns the canonical :class:`Volume`."""
    path = Path(path)
    try:
        arrays = _arrays(path)
    except _BROKEN as e:
        raise DataError(f"{path}: not a readable .npz archive ({type(e).__name__}: {e})") from None
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
        return Volume(data, triple(arrays["voxel_size"]), triple(arrays["origin"]), direction, path).canonical()
    except ValueError as e:
        raise DataError(f"{path}: {e}") from None


def write_npz(volume: Volume, path) -> Path:
    """Write ``volume`` (canonical layout) as a compressed ``.npz``; returns the path."""
    path = Path(path)
    v = volume.canonical()
    buf = io.BytesIO()  # keeps the exact name (np.savez adds .npz otherwise); written whole (files.py)
    np.savez_compressed(buf, data=v.data, voxel_size=np.asarray(v.voxel_size), origin=np.asarray(v.origin))
    return write_atomic(path, buf.getvalue())
