"""The SPECT list-mode data model and the reader registry.

Clocks and units (everything a reader returns follows them, whatever the file stored):

* **list-mode time** ``t``: seconds since the acquisition start, counted by the SPECT's own
  clock (its tick counter). It runs at the SPECT clock's rate, which differs from the host's
  by a skew of some tens of ppm; :mod:`vts_hw.spect.gating` maps it to trigger and host time.
* ``start_time``: the SPECT's wall clock (UTC epoch seconds, *its* clock, off the host's by
  up to seconds) at ``t = 0``, as the file's header states it.
* positions: millimetres in the SPECT frame; ``z`` is axial (along the table), ``u`` the
  transaxial position on the detector face; ``head`` the detector head (0-based).
* gating voltage: volts.

A reader is anything with the :class:`ListModeReader` shape (``name``, ``extensions``,
``sniff(head) -> bool``, ``read(path) -> ListMode``) added by :func:`register_reader`;
:func:`read_listmode` picks one by content first, then by suffix. A vendor format is one more
module and one ``register_reader`` call: the analysis only ever sees a :class:`ListMode`.
Every reader raises :class:`~vts_hw.errors.DataError` with a one-line message that names the
file and what is wrong.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from vts_hw.errors import DataError
from vts_hw.formats import FormatRegistry

SNIFF_BYTES = 64

GATE_SAMPLES = "samples"  # gate_t/gate_v: the voltage sampled at (regular) times
GATE_TRANSITIONS = "transitions"  # gate_t/gate_v: the times the level changed, the new level


@dataclass
class ListMode:
    """One list-mode acquisition, whatever file it came from. Times are list-mode seconds
    (see the module docstring); ``dead`` is ``None`` when the format records no dead time."""

    start_time: float  # SPECT wall clock at t = 0, UTC epoch s (its clock)
    duration_s: float  # list-mode time of the acquisition's end
    t: np.ndarray  # (n,) float64, event times, s, ascending
    z: np.ndarray  # (n,) float32, axial position on the detector, mm
    u: np.ndarray  # (n,) float32, transaxial position, mm
    head: np.ndarray  # (n,) uint8, detector head
    timing_marks: np.ndarray  # (m,) float64, s (every 10 ms on the SPECT clock)
    frame_starts: np.ndarray  # (f,) float64, s (every 100 ms)
    frame_angles: np.ndarray  # (f,) float64, head-0 angle at each frame start, deg
    gate_t: np.ndarray  # float64, s
    gate_v: np.ndarray  # float32, V
    gate_kind: str = GATE_SAMPLES
    dead: np.ndarray | None = None  # (k, 2) float64 [start, end) s, or None
    header: dict = field(default_factory=dict)
    source: Path | None = None  # the file, for messages
    format: str = ""

    @property
    def n_events(self) -> int:
        return int(self.t.size)

    def where(self) -> str:
        """How messages name this acquisition."""
        return str(self.source) if self.source is not None else "list-mode"


@runtime_checkable
class ListModeReader(Protocol):
    """What a list-mode format provides. ``extensions`` are lower case with the dot."""

    name: str
    extensions: tuple[str, ...]

    def sniff(self, head: bytes) -> bool:
        """Whether the first bytes of a file are this format."""
        ...

    def read(self, path: Path) -> ListMode:
        """The whole file as a ListMode, or DataError naming the file."""
        ...


_REGISTRY: FormatRegistry[ListModeReader] = FormatRegistry(
    "list-mode", content_first=True, check=lambda r: isinstance(r, ListModeReader), sniff_bytes=SNIFF_BYTES
)


def register_reader(reader: ListModeReader) -> None:
    """Add (or replace, by name) a reader."""
    _REGISTRY.register(reader)


def list_readers() -> list[ListModeReader]:
    """The registered readers, in registration order."""
    return _REGISTRY.readers()


def reader_for(path) -> ListModeReader:
    """The reader for ``path``: by content, else by suffix; DataError if none."""
    return _REGISTRY.reader_for(path)


def read_listmode(path, fmt: str | None = None) -> ListMode:
    """Read a list-mode file; ``fmt`` (a reader name) overrides the choice."""
    return _REGISTRY.read(path, fmt)


def read_listmode_span(path) -> tuple[float, float]:
    """``(start_time, duration_s)`` of a list-mode file: when it was acquired (SPECT wall
    clock, UTC epoch s) and for how long (s). From the header alone when the reader offers
    ``span(path)`` (optional; VTSLM does), else from the whole file."""
    path = Path(path)
    if not path.exists():
        raise DataError(f"{path}: no such file")
    if not path.is_file():
        raise DataError(f"{path}: not a file")
    reader = _REGISTRY.reader_for(path)
    span = getattr(reader, "span", None)
    if callable(span):
        return span(path)
    lm = reader.read(path)
    return lm.start_time, lm.duration_s
