"""SPECT list-mode: the data model, the reader registry and our own documented format.

* :class:`ListMode` (:mod:`.base`) — events (list-mode time s, z and u mm, head), timing
  marks, frame starts, gating voltage, dead time, header; list-mode time is seconds since the
  acquisition start on the SPECT's own clock;
* :func:`read_listmode` / :func:`read_listmode_span` / :func:`register_reader` / :class:`ListModeReader` (:mod:`.base`) —
  a vendor format is one more reader, the analysis never changes;
* VTSLM (:mod:`.vtslm`, docs/listmode-format.md) — :class:`VtslmWriter`, :func:`write_vtslm`,
  :func:`read_vtslm`.
"""

from vts_hw.spect.listmode.base import (
    GATE_SAMPLES,
    GATE_TRANSITIONS,
    ListMode,
    ListModeReader,
    list_readers,
    read_listmode,
    read_listmode_span,
    reader_for,
    register_reader,
)
from vts_hw.spect.listmode.vtslm import VtslmReader, VtslmWriter, read_vtslm, write_vtslm

register_reader(VtslmReader())

__all__ = [
    "ListMode",
    "ListModeReader",
    "read_listmode",
    "reader_for",
    "list_readers",
    "register_reader",
    "read_listmode_span",
    "GATE_SAMPLES",
    "GATE_TRANSITIONS",
    "VtslmWriter",
    "VtslmReader",
    "read_vtslm",
    "write_vtslm",
]
