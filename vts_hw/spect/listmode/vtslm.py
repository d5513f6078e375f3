"""VTSLM: our own list-mode format (docs/listmode-format.md), its reader and writer.

A 16-byte preamble (magic ``\\x89VTSLM\\r\\n``, version, header length), a JSON header, then
blocks of fixed-size little-endian records (``EVNT`` events, ``TMRK`` timing marks, ``FRAM``
frame starts, ``GATE`` gating-voltage samples, ``DEAD`` dead-time intervals) and a closing
``END`` block. Every time in the file is an integer count of nanoseconds of list-mode time
(SPECT clock, since the acquisition start); the API speaks seconds.

:class:`VtslmWriter` writes a file block by block (a long acquisition never has to be in
memory at once); :func:`read_vtslm` reads one whole file into a :class:`~.base.ListMode` with
a handful of ``numpy.frombuffer`` calls; :func:`write_vtslm` writes a ListMode back.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from vts_hw.bounded import LISTMODE, open_checked, read_bytes
from vts_hw.errors import DataError
from vts_hw.files import open_writable
from vts_hw.spect.listmode.base import GATE_SAMPLES, ListMode

NAME = "vtslm"
EXTENSIONS = (".vtslm",)
MAGIC = b"\x89VTSLM\r\n"
VERSION = (1, 0)
PREAMBLE = struct.Struct("<8sHHI")  # magic, major, minor, header length
BLOCK = struct.Struct("<4sIII")  # tag, record count, record size, reserved (0)
NS = 1_000_000_000

EVENT = np.dtype([("t_ns", "<i8"), ("z_mm", "<f4"), ("u_01mm", "<i2"), ("head", "u1"), ("flags", "u1")])
MARK = np.dtype([("t_ns", "<i8")])
FRAME = np.dtype([("t_ns", "<i8"), ("index", "<u4"), ("angle_mdeg", "<i4")])
GATE = np.dtype("<i2")
DEAD = np.dtype([("start_ns", "<i8"), ("end_ns", "<i8")])
END = np.dtype([("t_ns", "<i8")])
RECORDS = {b"EVNT": EVENT, b"TMRK": MARK, b"FRAM": FRAME, b"GATE": GATE, b"DEAD": DEAD, b"END ": END}


def _number(v):
    # a JSON integer of 400 digits is an int no float can hold: not a number here
    return isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) < 1e300


def _positive(v):
    return _number(v) and v > 0


def _int(v):
    return isinstance(v, int) and not isinstance(v, bool) and -(2**63) <= v < 2**63


# header keys every file must have: name -> (check, what it must be)
REQUIRED = {
    "start_time": (_number, "a number (SPECT wall clock at t = 0, UTC epoch s)"),
    "duration_s": (lambda v: _number(v) and v >= 0, "a number >= 0 (s)"),
    "timing_mark_s": (_positive, "a positive number (s)"),
    "frame_s": (_positive, "a positive number (s)"),
    "heads": (lambda v: _int(v) and 1 <= v <= 255, "a whole number from 1 to 255"),
    "gate_rate_hz": (_positive, "a positive number (Hz)"),
    "gate_t0_ns": (_int, "a whole number (ns)"),
    "gate_volts_per_count": (_positive, "a positive number (V)"),
    "dead_time_recorded": (lambda v: isinstance(v, bool), "true or false"),
}


def sniff(head: bytes) -> bool:
    return head[: len(MAGIC)] == MAGIC


def _ns(seconds) -> np.ndarray:
    return np.round(np.asarray(seconds, dtype=np.float64) * NS).astype(np.int64)


# ---------------------------------------------------------------------------------- writer


class VtslmWriter:
    """Write a VTSLM file block by block. Times in list-mode seconds, positions in mm, volts.

    ``with VtslmWriter(path, start_time=..., duration_s=..., gate_rate_hz=...) as w:``
    then any number of ``events``/``timing_marks``/``frames``/``gate``/``dead`` calls in any
    order (each is one block; records of a kind must come in time order across blocks), and
    ``close(end_s)`` (the context manager closes with ``duration_s``). Extra keyword arguments
    go into the header as they are (scanner name, software version, ...).
    """

    def __init__(
        self,
        path,
        *,
        start_time: float,
        duration_s: float,
        gate_rate_hz: float,
        gate_volts_per_count: float = 10.0 / 32768,
        gate_t0_s: float = 0.0,
        timing_mark_s: float = 0.01,
        frame_s: float = 0.1,
        heads: int = 2,
        dead_time_recorded: bool = False,
        **extra,
    ):
        self.path = Path(path)
        header = dict(extra)
        header.update(
            format="VTSLM",
            start_time=float(start_time),
            duration_s=float(duration_s),
            timing_mark_s=float(timing_mark_s),
            frame_s=float(frame_s),
            heads=int(heads),
            gate_rate_hz=float(gate_rate_hz),
            gate_t0_ns=int(_ns(gate_t0_s)),
            gate_volts_per_count=float(gate_volts_per_count),
            dead_time_recorded=bool(dead_time_recorded),
        )
        for key, (ok, what) in REQUIRED.items():
            if not ok(header[key]):
                raise ValueError(f"VTSLM header key {key!r} must be {what}, not {header[key]!r}")
        self.header = header
        self.volts_per_count = header["gate_volts_per_count"]
        text = json.dumps(header, indent=1, sort_keys=True).encode("utf-8")
        text += b" " * (-(PREAMBLE.size + len(text)) % 8)
        self._f = open_writable(self.path, "wb")  # a regular file: never a device, FIFO or symbolic link
        self._f.write(PREAMBLE.pack(MAGIC, VERSION[0], VERSION[1], len(text)))
        self._f.write(text)
        self.closed = False

    def _block(self, tag: bytes, records: np.ndarray) -> None:
        if self.closed:
            raise ValueError(f"{self.path}: already closed")
        dtype = RECORDS[tag]
        records = np.ascontiguousarray(records, dtype=dtype)
        if records.size == 0:
            return
        self._f.write(BLOCK.pack(tag, records.size, dtype.itemsize, 0))
        self._f.write(records.tobytes())

    def events(self, t_s, z_mm, u_mm, head, flags=None) -> None:
        """Events: list-mode time (s), axial and transaxial detector positions (mm), head."""
        t = _ns(t_s)
        rec = np.empty(t.size, EVENT)
        rec["t_ns"] = t
        rec["z_mm"] = z_mm
        rec["u_01mm"] = np.clip(np.round(np.asarray(u_mm, np.float64) * 10), -32768, 32767)
        rec["head"] = head
        rec["flags"] = 0 if flags is None else flags
        self._block(b"EVNT", rec)

    def timing_marks(self, t_s) -> None:
        rec = np.empty(np.size(t_s), MARK)
        rec["t_ns"] = _ns(t_s)
        self._block(b"TMRK", rec)

    def frames(self, t_s, index, angle_deg) -> None:
        """Frame starts: time (s), frame number, head-0 gantry angle (degrees)."""
        rec = np.empty(np.size(t_s), FRAME)
        rec["t_ns"] = _ns(t_s)
        rec["index"] = index
        rec["angle_mdeg"] = np.round(np.asarray(angle_deg, np.float64) * 1000)
        self._block(b"FRAM", rec)

    def gate(self, volts) -> None:
        """The next gating-voltage samples (they continue the previous ones at gate_rate_hz)."""
        raw = np.clip(np.round(np.asarray(volts, np.float64) / self.volts_per_count), -32768, 32767)
        self._block(b"GATE", raw.astype(GATE))

    def dead(self, start_s, end_s) -> None:
        """Dead-time intervals [start, end) in list-mode seconds (heads rotating)."""
        rec = np.empty(np.size(start_s), DEAD)
        rec["start_ns"] = _ns(start_s)
        rec["end_ns"] = _ns(end_s)
        self._block(b"DEAD", rec)

    def close(self, end_s: float | None = None) -> None:
        """Write the END block (the acquisition's end, s) and close the file."""
        if self.closed:
            return
        rec = np.empty(1, END)
        rec["t_ns"] = _ns(self.header["duration_s"] if end_s is None else end_s)
        self._block(b"END ", rec)
        self.closed = True
        self._f.close()

    def __enter__(self) -> VtslmWriter:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        if exc_type is None:
            self.close()
        else:  # an interrupted write leaves a file without END: the reader says so
            self._f.close()
            self.closed = True


def write_vtslm(path, lm: ListMode, **extra) -> Path:
    """Write a whole ListMode (gating as regular samples) as VTSLM; returns the path."""
    if lm.gate_kind != GATE_SAMPLES:
        raise ValueError("VTSLM stores the gating voltage as regular samples, not transitions")
    rate = lm.header.get("gate_rate_hz")
    if rate is None:
        if lm.gate_t.size < 2:
            raise ValueError("cannot tell the gating sample rate from fewer than 2 samples")
        rate = 1.0 / float(np.median(np.diff(lm.gate_t)))
    keep = {k: v for k, v in lm.header.items() if k not in REQUIRED and k != "format"}
    keep.update(extra)
    with VtslmWriter(
        path,
        start_time=lm.start_time,
        duration_s=lm.duration_s,
        gate_rate_hz=rate,
        gate_volts_per_count=lm.header.get("gate_volts_per_count", 10.0 / 32768),
        gate_t0_s=float(lm.gate_t[0]) if lm.gate_t.size else 0.0,
        timing_mark_s=lm.header.get("timing_mark_s", 0.01),
        frame_s=lm.header.get("frame_s", 0.1),
        heads=int(lm.header.get("heads", int(lm.head.max()) + 1 if lm.head.size else 1)),
        dead_time_recorded=lm.dead is not None,
        **keep,
    ) as w:
        w.events(lm.t, lm.z, lm.u, lm.head)
        w.timing_marks(lm.timing_marks)
        w.frames(lm.frame_starts, np.arange(lm.frame_starts.size), lm.frame_angles)
        w.gate(lm.gate_v)
        if lm.dead is not None and len(lm.dead):
            w.dead(lm.dead[:, 0], lm.dead[:, 1])
        w.close(lm.duration_s)
    return Path(path)


# ---------------------------------------------------------------------------------- reader


def _header(path: Path, data: bytes) -> tuple[dict, int]:
    if len(data) < PREAMBLE.size:
        raise DataError(f"{path}: truncated: {len(data)} bytes, shorter than the {PREAMBLE.size}-byte VTSLM preamble")
    magic, major, minor, length = PREAMBLE.unpack_from(data)
    if magic != MAGIC:
        raise DataError(f"{path}: not a VTSLM list-mode file (starts with {magic!r}, expected {MAGIC!r})")
    if major != VERSION[0]:
        raise DataError(f"{path}: VTSLM version {major}.{minor} is not supported (this reader reads {VERSION[0]}.x)")
    end = PREAMBLE.size + length
    if end > len(data):
        raise DataError(
            f"{path}: truncated in the header ({length} header bytes announced, {len(data) - PREAMBLE.size} present)"
        )
    try:
        header = json.loads(data[PREAMBLE.size : end].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise DataError(f"{path}: the header is not valid JSON ({e})") from None
    except (ValueError, RecursionError) as e:  # a 5000-digit number, arrays nested 1000 deep
        why = "nested too deeply" if isinstance(e, RecursionError) else str(e).split(":")[0]
        raise DataError(f"{path}: the header is not valid JSON ({why})") from None
    if not isinstance(header, dict):
        raise DataError(f"{path}: the header is not a JSON object")
    for key, (ok, what) in REQUIRED.items():
        if key not in header:
            raise DataError(f"{path}: header key {key!r} is missing")
        if not ok(header[key]):
            shown = repr(header[key])
            shown = shown if len(shown) <= 40 else shown[:37] + "..."
            raise DataError(f"{path}: header key {key!r} must be {what}, not {shown}")
    return header, end


def _blocks(path: Path, data: bytes, pos: int) -> tuple[dict[bytes, list[tuple[int, int]]], int]:
    """Walk the blocks: {tag: [(offset of the records, count)]} and the END time (ns)."""
    found: dict[bytes, list[tuple[int, int]]] = {tag: [] for tag in RECORDS}
    end_ns = None
    size = len(data)
    while pos < size:
        if end_ns is not None:
            raise DataError(f"{path}: {size - pos} bytes after the END block at byte {pos}")
        if size - pos < BLOCK.size:
            raise DataError(
                f"{path}: truncated: a block header at byte {pos} has only {size - pos} of {BLOCK.size} bytes"
            )
        tag, n, rsize, _reserved = BLOCK.unpack_from(data, pos)
        name = tag.decode("ascii", "replace")
        if not (tag.isascii() and tag.decode("ascii").strip().isalnum()):
            raise DataError(f"{path}: bad block tag {tag!r} at byte {pos} (corrupt file?)")
        body = pos + BLOCK.size
        if body + n * rsize > size:
            raise DataError(
                f"{path}: truncated: block {name!r} at byte {pos} needs {n * rsize} "
                f"bytes of records, only {size - body} left"
            )
        dtype = RECORDS.get(tag)
        if dtype is not None:
            if rsize != dtype.itemsize:
                raise DataError(
                    f"{path}: block {name!r} at byte {pos} has {rsize}-byte records, VTSLM 1 has {dtype.itemsize}"
                )
            if tag == b"END ":
                if n != 1:
                    raise DataError(f"{path}: the END block at byte {pos} has {n} records, not 1")
                end_ns = int(np.frombuffer(data, END, 1, body)["t_ns"][0])
            else:
                found[tag].append((body, n))
        # an unknown tag (a later minor version): skipped, its record size says how far
        pos = body + n * rsize
    if end_ns is None:
        raise DataError(
            f"{path}: no END block: the file was not closed (truncated, or the acquisition was interrupted)"
        )
    return found, end_ns


def _gather(data: bytes, dtype: np.dtype, parts: list[tuple[int, int]]) -> np.ndarray:
    if not parts:
        return np.empty(0, dtype)
    return np.concatenate([np.frombuffer(data, dtype, n, off) for off, n in parts])


def _ascending(path: Path, what: str, t: np.ndarray) -> None:
    if t.size > 1:
        bad = np.flatnonzero(np.diff(t) < 0)
        if bad.size:
            raise DataError(f"{path}: {what} times go backwards at record {bad[0] + 1}")


def read_vtslm(path) -> ListMode:
    """Read a VTSLM file into a ListMode (list-mode seconds, mm, volts)."""
    path = Path(path)
    try:
        data = read_bytes(path, LISTMODE, "list-mode file")
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror})") from None
    header, pos = _header(path, data)
    found, end_ns = _blocks(path, data, pos)
    ev = _gather(data, EVENT, found[b"EVNT"])
    marks = _gather(data, MARK, found[b"TMRK"])
    frames = _gather(data, FRAME, found[b"FRAM"])
    gate = _gather(data, GATE, found[b"GATE"])
    dead = _gather(data, DEAD, found[b"DEAD"])
    _ascending(path, "event", ev["t_ns"])
    _ascending(path, "timing mark", marks["t_ns"])
    _ascending(path, "frame", frames["t_ns"])
    if ev.size and int(ev["head"].max()) >= header["heads"]:
        raise DataError(
            f"{path}: an event on head {int(ev['head'].max())}, but the header says {header['heads']} heads"
        )
    if np.any(dead["end_ns"] < dead["start_ns"]):
        raise DataError(f"{path}: a dead-time interval ends before it starts")
    rate = float(header["gate_rate_hz"])
    gate_t = header["gate_t0_ns"] / 1e9 + np.arange(gate.size) / rate
    return ListMode(
        start_time=float(header["start_time"]),
        duration_s=end_ns / 1e9,
        t=ev["t_ns"] / 1e9,
        z=ev["z_mm"].astype(np.float32),
        u=ev["u_01mm"].astype(np.float32) * np.float32(0.1),
        head=ev["head"].astype(np.uint8),
        timing_marks=marks["t_ns"] / 1e9,
        frame_starts=frames["t_ns"] / 1e9,
        frame_angles=frames["angle_mdeg"] * 1e-3,
        gate_t=gate_t,
        gate_v=gate.astype(np.float32) * np.float32(header["gate_volts_per_count"]),
        gate_kind=GATE_SAMPLES,
        dead=(
            np.column_stack([dead["start_ns"] / 1e9, dead["end_ns"] / 1e9]) if header["dead_time_recorded"] else None
        ),
        header=header,
        source=path,
        format=NAME,
    )


def vtslm_span(path) -> tuple[float, float]:
    """``(start_time, duration_s)`` of a VTSLM file from its preamble, header and last 24 bytes
    only (a 20-minute file is not read whole to learn when it was acquired): the END block's
    time when the file ends with one, else the header's planned ``duration_s`` (a file cut
    short is refused by :func:`read_vtslm`, not here). DataError naming the file."""
    path = Path(path)
    try:
        with open_checked(path, LISTMODE, "list-mode file") as f:
            head = f.read(PREAMBLE.size)
            length = PREAMBLE.unpack_from(head)[3] if len(head) == PREAMBLE.size else 0
            data = head + f.read(length)
            header, end = _header(path, data)
            size = f.seek(0, 2)
            duration = float(header["duration_s"])
            if size >= end + BLOCK.size + END.itemsize:
                f.seek(size - BLOCK.size - END.itemsize)
                tail = f.read(BLOCK.size + END.itemsize)
                tag, n, rsize, _ = BLOCK.unpack_from(tail)
                if tag == b"END " and n == 1 and rsize == END.itemsize:
                    duration = int(np.frombuffer(tail, END, 1, BLOCK.size)["t_ns"][0]) / 1e9
    except FileNotFoundError:
        raise DataError(f"{path}: no such file") from None
    except OSError as e:
        raise DataError(f"{path}: cannot read ({e.strerror})") from None
    return float(header["start_time"]), duration


class VtslmReader:
    """The registry entry for VTSLM."""

    name = NAME
    extensions: tuple[str, ...] = EXTENSIONS

    @staticmethod
    def sniff(head: bytes) -> bool:
        return sniff(head)

    @staticmethod
    def read(path: Path) -> ListMode:
        return read_vtslm(path)

    @staticmethod
    def span(path: Path) -> tuple[float, float]:
        return vtslm_span(path)
