"""MJPEG framing: the multipart stream of ``mjpg/video.cgi`` and concatenated JPEG files.

* :class:`MultipartParser` is fed the bytes of an HTTP multipart body as they arrive and
  returns whole parts. It accepts a boundary given with or without ``--``, headers in any
  case, a missing Content-Length (it scans for the next boundary) and a Content-Length that
  is wrong (the bytes after it are not a boundary: it falls back to scanning).
* :func:`jpeg_end` finds where one JPEG ends (segment walk, then the entropy-coded data up
  to EOI), and :func:`split_jpegs` cuts a concatenation of JPEGs (a recording's ``.mjpeg``
  file) into frames, also when one of them is torn.
* :func:`read_frames_file` reads a file of either kind, or a single JPEG.
"""

from __future__ import annotations

import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw.bounded import CAPTURE, read_bytes
from vts_hw.errors import DataError
from vts_hw.recording.axis_jpeg import EOI, SOI

_MAX_HEADER = 4096


@dataclass
class Part:
    """One part of a multipart stream."""

    body: bytes
    headers: dict[str, str] = field(default_factory=dict)
    problems: list[str] = field(default_factory=list)

    @property
    def complete(self) -> bool:
        return jpeg_end(self.body, 0) == len(self.body)


def boundary_from_content_type(content_type: str) -> bytes:
    """The boundary token of a ``multipart/x-mixed-replace`` Content-Type, without ``--``."""
    m = re.search(r'boundary\s*=\s*"?([^";\s]+)"?', content_type or "", re.I)
    if not m:
        raise DataError(f"no boundary in Content-Type {content_type!r}")
    token = m.group(1)
    if token.startswith("--"):
        token = token[2:]
    return token.encode("latin-1")


class MultipartParser:
    """Incremental parser of a multipart/x-mixed-replace body."""

    def __init__(self, boundary: bytes | str):
        if isinstance(boundary, str):
            boundary = boundary.encode("latin-1")
        if boundary.startswith(b"--"):
            boundary = boundary[2:]
        self.delim = b"--" + boundary
        self._buf = bytearray()
        self._state = "preamble"
        self._headers: dict[str, str] = {}
        self._length: int | None = None
        self.bytes_fed = 0

    def feed(self, chunk: bytes) -> list[Part]:
        self._buf += chunk
        self.bytes_fed += len(chunk)
        out: list[Part] = []
        while True:
            part = self._step()
            if part is None:
                break
            if part is not _CONTINUE:
                out.append(part)
        return out

    @property
    def pending(self) -> int:
        """Bytes received but not yet returned as a part (a frame in flight)."""
        return len(self._buf)

    # -- state machine -------------------------------------------------------------
    def _step(self):
        buf = self._buf
        if self._state == "preamble":
            i = buf.find(self.delim)
            if i < 0:
                # keep a tail that may hold the start of a delimiter
                if len(buf) > len(self.delim):
                    del buf[: len(buf) - len(self.delim)]
                return None
            eol = buf.find(b"\n", i)
            if eol < 0:
                return None
            del buf[: eol + 1]
            self._state = "headers"
            return _CONTINUE
        if self._state == "headers":
            end = _find_blank_line(buf)
            if end is None:
                if len(buf) > _MAX_HEADER:
                    # not a header block: resynchronise on the next delimiter
                    self._state = "preamble"
                    del buf[:1]
                    return _CONTINUE
                return None
            head, body_start = end
            self._headers = _parse_headers(bytes(buf[:head]))
            del buf[:body_start]
            cl = self._headers.get("content-length")
            try:
                self._length = int(cl) if cl is not None else None
            except ValueError:
                self._length = None
            self._state = "body"
            return _CONTINUE
        # body
        problems: list[str] = []
        if self._length is not None:
            n = self._length
            if len(buf) >= n and n >= 4 and buf[n - 2 : n] == EOI and buf[:2] == SOI:
                # the usual case: a whole JPEG of the declared length; hand it over at once
                body = bytes(buf[:n])
                del buf[:n]
                return self._finish(body, problems)
            if len(buf) < n + 2 + len(self.delim):
                return None
            after = bytes(buf[n : n + 2 + len(self.delim)]).lstrip(b"\r\n")
            if self.delim.startswith(after) or after.startswith(self.delim):
                body = bytes(buf[:n])  # declared length right, the JPEG itself torn
                del buf[:n]
                return self._finish(body, problems)
            problems.append(f"Content-Length {n} does not match the data; found the frame by its boundary")
        i = self._find_delim(buf)
        if i is None:
            return None
        body = bytes(buf[:i])
        del buf[:i]
        if self._length is None:
            problems.append("no Content-Length; found the frame by its boundary")
        return self._finish(body.rstrip(b"\r\n") if not body.endswith(EOI) else body, problems)

    def _find_delim(self, buf) -> int | None:
        start = 0
        while True:
            i = buf.find(self.delim, start)
            if i < 0:
                return None
            # a delimiter stands at the start of a line
            if i == 0 or buf[i - 1 : i] == b"\n":
                return i
            start = i + 1

    def _finish(self, body: bytes, problems: list[str]) -> Part:
        part = Part(body=body, headers=self._headers, problems=problems)
        self._headers = {}
        self._length = None
        self._state = "preamble"
        return part

    def flush(self) -> Part | None:
        """At the end of the stream: the part in flight, if any."""
        if self._state != "body" or not self._buf:
            self._buf.clear()
            return None
        body = bytes(self._buf)
        self._buf.clear()
        problems = []
        if self._length is not None and len(body) >= self._length:
            body = body[: self._length]
        else:
            body = body.rstrip(b"\r\n") if not body.endswith(EOI) else body
            problems.append("the stream ended inside this part")
        return self._finish(body, problems)


_CONTINUE = object()


def _find_blank_line(buf) -> tuple[int, int] | None:
    for sep in (b"\r\n\r\n", b"\n\n"):
        i = buf.find(sep)
        if i >= 0:
            return i, i + len(sep)
    # a part with no headers at all: the JPEG starts right after the delimiter line
    if buf[:2] == SOI:
        return 0, 0
    return None


def _parse_headers(block: bytes) -> dict[str, str]:
    headers: dict[str, str] = {}
    for line in block.decode("latin-1").splitlines():
        if ":" in line:
            k, v = line.split(":", 1)
            headers[k.strip().lower()] = v.strip()
    return headers


# -- JPEG boundaries ---------------------------------------------------------------
def jpeg_end(data: bytes, start: int = 0) -> int | None:
    """Index just past the EOI of the JPEG that starts at ``start``, or None if it is torn.

    Walks the header segments (so an EOI inside an APP segment is not mistaken for the end)
    and then the entropy-coded data, where 0xFF is always followed by 0x00, RSTn or a marker.
    """
    n = len(data)
    if data[start : start + 2] != SOI:
        return None
    i = start + 2
    while i + 4 <= n:
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:
            i += 1
            continue
        if marker == 0xD9:
            return i + 2
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:
            i += 2
            continue
        (length,) = struct.unpack(">H", data[i + 2 : i + 4])
        i += 2 + length
        if marker == 0xDA:
            break
    else:
        return None
    while True:
        j = data.find(b"\xff", i)
        if j < 0 or j + 1 >= n:
            return None
        m = data[j + 1]
        if m == 0xD9:
            return j + 2
        if m == 0x00 or 0xD0 <= m <= 0xD7 or m == 0xFF:
            i = j + 1
            continue
        # another marker inside the scan (DHT/DQT/SOS of a progressive JPEG): skip it
        if j + 4 > n:
            return None
        (length,) = struct.unpack(">H", data[j + 2 : j + 4])
        i = j + 2 + length


@dataclass(frozen=True)
class FrameSpan:
    offset: int
    length: int
    complete: bool


def split_jpegs(data: bytes) -> list[FrameSpan]:
    """Cut concatenated JPEGs into frames. A torn frame runs up to the next SOI."""
    spans: list[FrameSpan] = []
    i = data.find(SOI + b"\xff")
    n = len(data)
    while 0 <= i < n:
        end = jpeg_end(data, i)
        if end is not None:
            spans.append(FrameSpan(i, end - i, True))
            nxt = data.find(SOI + b"\xff", end)
        else:
            nxt = data.find(SOI + b"\xff", i + 2)
            stop = nxt if nxt >= 0 else n
            spans.append(FrameSpan(i, stop - i, False))
        i = nxt
    return spans


def read_frames_file(path: str | Path) -> list[tuple[bytes, list[str]]]:
    """Frames of a file: a multipart capture (.mjpg), concatenated JPEGs, or one JPEG.

    Returns (jpeg bytes, problems) per frame; raises DataError for a file that holds none.
    """
    p = Path(path)
    try:
        data = read_bytes(p, CAPTURE, "frames file (.mjpg or JPEG)")
    except OSError as exc:
        raise DataError(f"{p}: cannot read ({exc.strerror})") from None
    head = data[:256].lstrip()
    if head.startswith(b"--"):
        line = head.split(b"\n", 1)[0].strip()
        parser = MultipartParser(line[2:])
        parts = parser.feed(data)
        last = parser.flush()
        if last is not None and last.body:
            parts.append(last)
        frames = []
        for part in parts:
            probs = list(part.problems)
            if not part.complete:
                probs.append("the frame is cut short (no end-of-image marker)")
            frames.append((part.body, probs))
        if not frames:
            raise DataError(f"{p}: a multipart file with no parts")
        return frames
    spans = split_jpegs(data)
    if not spans:
        raise DataError(f"{p}: no JPEG frames in this file (no start-of-image marker)")
    return [
        (
            data[s.offset : s.offset + s.length],
            [] if s.complete else ["the frame is cut short (no end-of-image marker)"],
        )
        for s in spans
    ]
