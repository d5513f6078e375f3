"""Volume readers, registered by file type, so a vendor format can be added later.

A reader is a :class:`VolumeReader`: a ``name``, the file ``extensions`` it claims, a
``sniff(head)`` test on the first bytes of a file and a ``read(path) -> Volume`` that returns
the canonical volume (see :mod:`vts_hw.spect.volume`) or raises
:class:`~vts_hw.errors.DataError` naming the file. :func:`read_volume` picks the reader by
extension, then by content; :func:`register_reader` adds one (a later registration of the same
name replaces the earlier one).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from vts_hw.errors import DataError
from vts_hw.spect.dicom_nm import read_dicom_nm
from vts_hw.spect.interfile import read_interfile
from vts_hw.spect.npz import read_npz
from vts_hw.spect.volume import Volume

SNIFF_BYTES = 512


@dataclass(frozen=True)
class VolumeReader:
    """One file type: how to recognise it and how to read it."""

    name: str
    extensions: tuple[str, ...]  # lower case, with the dot: ".h33"
    sniff: Callable[[bytes], bool]
    read: Callable[[Path], Volume]


_READERS: dict[str, VolumeReader] = {}


def register_reader(reader: VolumeReader) -> None:
    """Add (or replace, by name) a reader."""
    _READERS[reader.name] = reader


def list_readers() -> list[VolumeReader]:
    """The registered readers, in registration order."""
    return list(_READERS.values())


def _head(path: Path) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(SNIFF_BYTES)
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror})") from None


def reader_for(path) -> VolumeReader:
    """The reader for ``path``: by extension, else by content; DataError if none."""
    path = Path(path)
    ext = path.suffix.lower()
    for r in _READERS.values():
        if ext in r.extensions:
            return r
    head = _head(path)
    for r in _READERS.values():
        if r.sniff(head):
            return r
    raise DataError(f"{path}: unknown volume format (known: "
                    f"{', '.join(r.name for r in _READERS.values())})")


def read_volume(path, fmt: str | None = None) -> Volume:
    """Read a reconstructed volume; ``fmt`` (a reader name) overrides the choice."""
    path = Path(path)
    if fmt is not None:
        if fmt not in _READERS:
            raise DataError(f"{path}: unknown volume format '{fmt}' (known: {', '.join(_READERS)})")
        return _READERS[fmt].read(path)
    if not path.is_file():
        raise DataError(f"{path}: no such file")
    return reader_for(path).read(path)


register_reader(VolumeReader(
    "interfile", (".h33", ".hdr", ".hv"),
    lambda head: head.lstrip().lstrip(b"!").upper().startswith(b"INTERFILE"),
    read_interfile))
register_reader(VolumeReader(
    "dicom", (".dcm", ".dicom", ".ima"),
    lambda head: head[128:132] == b"DICM",
    read_dicom_nm))
register_reader(VolumeReader(
    "npz", (".npz",),
    lambda head: head[:4] == b"PK\x03\x04",
    read_npz))
