"""Volume readers, registered by file type, so a vendor format can be added later.

A reader is a :class:`VolumeReader`: a ``name``, the file ``extensions`` it claims, a
``sniff(head)`` test on the first bytes of a file and a ``read(path) -> Volume`` that returns
the canonical volume (see :mod:`vts_hw.spect.volume`) or raises
:class:`~vts_hw.errors.DataError` naming the file. :func:`read_volume` picks the reader by
extension, then by content; :func:`register_reader` adds one (a later registration of the same
name replaces the earlier one).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from vts_hw.formats import FormatRegistry
from vts_hw.spect.dicom_nm import read_dicom_nm
from vts_hw.spect.interfile import read_interfile
from vts_hw.spect.npz import read_npz
from vts_hw.spect.volume import Volume


@dataclass(frozen=True)
class VolumeReader:
    """One file type: how to recognise it and how to read it."""

    name: str
    extensions: tuple[str, ...]  # lower case, with the dot: ".h33"
    sniff: Callable[[bytes], bool]
    read: Callable[[Path], Volume]


_REGISTRY: FormatRegistry[VolumeReader] = FormatRegistry("volume")


def register_reader(reader: VolumeReader) -> None:
    """Add (or replace, by name) a reader."""
    _REGISTRY.register(reader)


def list_readers() -> list[VolumeReader]:
    """The registered readers, in registration order."""
    return _REGISTRY.readers()


def reader_for(path) -> VolumeReader:
    """The reader for ``path``: by extension, else by content; DataError if none."""
    return _REGISTRY.reader_for(path)


def read_volume(path, fmt: str | None = None) -> Volume:
    """Read a reconstructed volume; ``fmt`` (a reader name) overrides the choice."""
    return _REGISTRY.read(path, fmt)


register_reader(
    VolumeReader(
        "interfile",
        (".h33", ".hdr", ".hv"),
        lambda head: head.lstrip().lstrip(b"!").upper().startswith(b"INTERFILE"),
        read_interfile,
    )
)
register_reader(VolumeReader("dicom", (".dcm", ".dicom", ".ima"), lambda head: head[128:132] == b"DICM", read_dicom_nm))
register_reader(VolumeReader("npz", (".npz",), lambda head: head[:4] == b"PK\x03\x04", read_npz))
