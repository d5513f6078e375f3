"""Interfile 3.3 volumes: an ASCII header (``.hdr``/``.h33``) and a raw data file.

Conventions (the writer and the reader agree on them; see docs/decisions/0014):

* ``!matrix size [1]`` is the fastest-varying index in the data file (columns), ``[2]`` the
  rows, ``[3]`` the slices (planes).
* Matrix axis [1] runs along SPECT **+X**, [2] along SPECT **−Y** (rows run from the top of a
  transaxial slice down, the usual display convention), [3] along SPECT **+Z**.
* ``scaling factor (mm/pixel) [i]`` is the voxel size along matrix axis ``i``.
* ``first pixel offset (mm) [i]`` is the SPECT coordinate — X for [1], Y for [2], Z for [3] —
  of the **centre** of the first voxel in the file. When absent the volume is centred on the
  origin (FOV centre), which is where a reconstruction's centre is by definition.
* ``!data offset in bytes`` (default 0) skips a file preamble.

An image **CASToR wrote** (its header has ``CASToR version``) is read in CASToR's own frame
instead (CASToR's documentation, and ``oInterfileIO``/``oProjectionLine`` of CASToR 3.1.1): [1]
along CASToR's x (= SPECT +X, the patient's left for a head-first supine patient), [2] along its
y (up: SPECT **+Y**), [3] along its z (into the gantry, towards the head: SPECT **-Z**), the image
centred on the field of view; CASToR writes its field-of-view offset (``-off``, image
coordinates = scanner coordinates + offset) under ``first pixel offset (mm)``, not the first
voxel's place, so the matrix centre is at minus that offset. Read as the display convention
above, a CASToR image would have its origin on its first voxel and Y pointing down.

Keys are matched case-insensitively, with the leading ``!`` and repeated blanks ignored.
"""

from __future__ import annotations

import math
import re
import stat
from pathlib import Path

import numpy as np

from vts_hw.bounded import LISTMODE, SMALL, read_bytes, read_text
from vts_hw.errors import DataError
from vts_hw.files import write_atomic
from vts_hw.spect.volume import Volume, triple

# (number format, bytes per pixel) -> numpy kind+size; byte order added later
_FORMATS = {
    ("unsigned integer", 1): "u1",
    ("unsigned integer", 2): "u2",
    ("unsigned integer", 4): "u4",
    ("signed integer", 1): "i1",
    ("signed integer", 2): "i2",
    ("signed integer", 4): "i4",
    ("float", 4): "f4",
    ("float", 8): "f8",
    ("short float", 4): "f4",
    ("long float", 8): "f8",
}
_BYTE_ORDERS = {"littleendian": "<", "bigendian": ">"}
_DIRECTION = np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])  # [3], [2], [1]
_CASTOR_DIRECTION = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])  # [3], [2], [1]


def _norm(key: str) -> str:
    return re.sub(r"\s+", " ", key.strip().lstrip("!").strip().lower())


def parse_header(path: Path) -> dict[str, str]:
    """``key := value`` lines to a dict of normalised keys; comments (``;``) dropped."""
    try:
        text = read_text(path, SMALL, "Interfile header", encoding="latin-1")
    except OSError as e:
        raise DataError(f"{path}: cannot read the Interfile header ({e.strerror})") from None
    lines = [ln.split(";", 1)[0] for ln in text.splitlines()]
    if not any("interfile" in ln.lower() for ln in lines[:5]):
        raise DataError(f"{path}: not an Interfile header (no '!INTERFILE :=' line at the top)")
    header: dict[str, str] = {}
    for ln in lines:
        if ":=" in ln:
            key, value = ln.split(":=", 1)
            header[_norm(key)] = value.strip()
    return header


def _castor(header: dict[str, str]) -> bool:
    return "castor version" in header or header.get("version of keys", "").lower().startswith("castor")


def written_by_castor(path) -> bool:
    """True when the header at ``path`` is one CASToR wrote (see the module)."""
    return _castor(parse_header(Path(path)))


def _get(header: dict[str, str], path: Path, key: str, default: str | None = None) -> str:
    value = header.get(_norm(key), default)
    if value is None or value == "":
        raise DataError(f"{path}: missing key '{key}' in the Interfile header")
    return value


def _number(header, path, key, kind=float, default=None):
    text = _get(header, path, key, default)
    try:
        return kind(text)
    except ValueError:
        raise DataError(f"{path}: key '{key}' is '{text}', not a number") from None


def read_interfile(path) -> Volume:
    """Read an Interfile 3.3 volume (header path); returns the canonical :class:`Volume`."""
    path = Path(path)
    h = parse_header(path)
    shape = [_number(h, path, f"!matrix size [{i}]", int) for i in (1, 2, 3)]
    if min(shape) <= 0:
        raise DataError(f"{path}: matrix size {shape} is not positive")
    size = [_number(h, path, f"scaling factor (mm/pixel) [{i}]") for i in (1, 2, 3)]
    for i, v in enumerate(size, 1):
        if not (math.isfinite(v) and v > 0):
            raise DataError(f"{path}: key 'scaling factor (mm/pixel) [{i}]' is {v}, not a positive number of mm")
    fmt = _norm(_get(h, path, "!number format"))
    nbytes = _number(h, path, "!number of bytes per pixel", int)
    if (fmt, nbytes) not in _FORMATS:
        raise DataError(f"{path}: unknown number format '{fmt}' with {nbytes} bytes per pixel")
    order_text = _norm(_get(h, path, "imagedata byte order", "LITTLEENDIAN"))
    if order_text not in _BYTE_ORDERS:
        raise DataError(f"{path}: unknown imagedata byte order '{order_text}'")
    dtype = np.dtype(_BYTE_ORDERS[order_text] + _FORMATS[(fmt, nbytes)])
    name = _get(h, path, "!name of data file")
    data_path = path.parent / name
    shown = data_path if len(name) <= 80 else f"{name[:40]!r}... ({len(name)} characters)"
    if "\x00" in name:
        raise DataError(f"{path}: key '!name of data file' holds a NUL byte ({name[:40]!r})")
    offset = _number(h, path, "!data offset in bytes", int, "0")
    if offset < 0:
        raise DataError(f"{path}: key '!data offset in bytes' is {offset}, not a byte count")
    try:
        if not stat.S_ISREG(data_path.stat().st_mode):  # a folder, /dev/zero, a FIFO
            raise DataError(f"{path}: the data file {shown} is not a regular file")
        raw = read_bytes(data_path, LISTMODE, "list-mode data file")
    except OSError as e:  # missing, unreadable, a name too long
        raise DataError(f"{path}: cannot read the data file {shown} ({e.strerror})") from None
    expected = math.prod(shape) * nbytes
    if len(raw) - offset != expected:
        raise DataError(
            f"{path}: data file {data_path.name} holds {len(raw) - offset} bytes "
            f"after the offset, the header says {expected} ({shape[0]}×{shape[1]}×"
            f"{shape[2]} × {nbytes} bytes)"
        )
    data = np.frombuffer(raw, dtype=dtype, offset=offset).reshape(shape[2], shape[1], shape[0])
    if _castor(h):
        return _castor_volume(h, path, data.astype(dtype.newbyteorder("=")), shape, size)
    centre = [(n - 1) / 2 * s for n, s in zip(shape, size)]  # default: centred on the origin
    default_xyz = (-centre[0], centre[1], -centre[2])
    xyz = [_number(h, path, f"first pixel offset (mm) [{i}]", float, repr(default_xyz[i - 1])) for i in (1, 2, 3)]
    if not all(math.isfinite(v) for v in xyz):
        raise DataError(f"{path}: 'first pixel offset (mm)' is {xyz}, not three finite numbers")
    vol = Volume(data.astype(dtype.newbyteorder("=")), (size[2], size[1], size[0]), triple(xyz), _DIRECTION, path)
    return vol.canonical()


def _castor_volume(h, path, data, shape, size) -> Volume:
    """A CASToR image (see the module): centred on the field of view less CASToR's offset."""
    off = [_number(h, path, f"first pixel offset (mm) [{i}]", float, "0") for i in (1, 2, 3)]
    if not all(math.isfinite(v) for v in off):
        raise DataError(f"{path}: 'first pixel offset (mm)' is {off}, not three finite numbers")
    steps = _CASTOR_DIRECTION * np.array([size[2], size[1], size[0]])[:, None]  # per array axis
    centre = _CASTOR_DIRECTION.T @ (-np.array([off[2], off[1], off[0]]))  # CASToR z, y, x -> SPECT
    first = centre - np.array([(shape[2] - 1) / 2, (shape[1] - 1) / 2, (shape[0] - 1) / 2]) @ steps
    return Volume(data, (size[2], size[1], size[0]), first, _CASTOR_DIRECTION, path).canonical()


def write_interfile(volume: Volume, path, number_format: str = "float") -> Path:
    """Write ``volume`` as ``path`` (header, ``.h33``/``.hdr``) plus ``<stem>.img`` (raw data).

    ``number_format``: ``"float"`` (4-byte float) or ``"unsigned integer"`` (2 bytes, values
    rounded and clipped to 0..65535). Returns the header path.
    """
    path = Path(path)
    v = volume.canonical()
    data = v.data[:, ::-1, :]  # file axes: [3]=+Z slices, [2]=-Y rows, [1]=+X columns
    if number_format == "float":
        raw, nbytes = np.ascontiguousarray(data, dtype="<f4"), 4
    elif number_format == "unsigned integer":
        raw = np.ascontiguousarray(np.clip(np.rint(data), 0, 65535), dtype="<u2")
        nbytes = 2
    else:
        raise ValueError(f"number_format must be 'float' or 'unsigned integer', not {number_format!r}")
    nz, ny, nx = v.data.shape
    dz, dy, dx = v.voxel_size
    first = v.index_to_mm((0, ny - 1, 0))  # the first voxel in the file: top row of slice 0
    data_path = path.with_suffix(".img")
    write_atomic(data_path, raw.tobytes())  # whole or not at all; never over a device, FIFO or link
    lines = [
        "!INTERFILE :=",
        "!imaging modality := nucmed",
        "!version of keys := 3.3",
        "!GENERAL DATA :=",
        f"!name of data file := {data_path.name}",
        "!data offset in bytes := 0",
        "!GENERAL IMAGE DATA :=",
        "!type of data := Tomographic",
        "imagedata byte order := LITTLEENDIAN",
        "number of dimensions := 3",
        f"!matrix size [1] := {nx}",
        f"!matrix size [2] := {ny}",
        f"!matrix size [3] := {nz}",
        f"!number format := {number_format}",
        f"!number of bytes per pixel := {nbytes}",
        f"scaling factor (mm/pixel) [1] := {dx!r}",
        f"scaling factor (mm/pixel) [2] := {dy!r}",
        f"scaling factor (mm/pixel) [3] := {dz!r}",
        "; SPECT frame: [1] runs along +X, [2] along -Y (rows top to bottom), [3] along +Z;",
        "; first pixel offset = X, Y, Z (mm) of the centre of the first voxel in the file",
        f"first pixel offset (mm) [1] := {float(first[0])!r}",
        f"first pixel offset (mm) [2] := {float(first[1])!r}",
        f"first pixel offset (mm) [3] := {float(first[2])!r}",
        "!END OF INTERFILE :=",
    ]
    write_atomic(path, "\n".join(lines) + "\n", encoding="ascii")
    return path
