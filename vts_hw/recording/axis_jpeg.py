"""The Axis comment segments in a JPEG: the camera's own 10 ms timestamp and product id.

Axis cameras put two COM segments (``FF FE 00 0F``, 13-byte payload) in the header of every
JPEG they send, in either order:

* time:    ``0A 01`` + uint32 BE seconds since 1970 + uint8 hundredths + 5 bytes + ``01``
  (firmware 5 and later repeat seconds and hundredths in the 5 bytes; 4.x leaves them zero);
* product: ``0A 00`` + 2-byte hardware id + 3-byte firmware version + 6-byte MAC.

:func:`inspect_jpeg` reads them (and whether the frame is whole); :func:`stamp_jpeg` writes
them into a JPEG the way a camera does (the simulated cameras use it).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from vts_hw.errors import DataError

SOI = b"\xff\xd8"
EOI = b"\xff\xd9"
_COM = 0xFE
_SOS = 0xDA
_SEG_LEN = 15  # length field of an Axis comment segment: 2 + 13 payload bytes
_TIME_TAG = b"\x0a\x01"
_PRODUCT_TAG = b"\x0a\x00"


class JpegError(DataError):
    """Bytes that are not a JPEG at all."""


@dataclass(frozen=True)
class AxisTime:
    seconds: int
    hundredths: int
    extra: bytes = b"\x00" * 5

    @property
    def epoch(self) -> float:
        """UTC epoch seconds, at the camera's 10 ms resolution."""
        return self.seconds + self.hundredths / 100.0

    def payload(self) -> bytes:
        return _TIME_TAG + struct.pack(">IB", self.seconds, self.hundredths) + self.extra + b"\x01"

    @classmethod
    def from_epoch(cls, epoch: float) -> AxisTime:
        """The stamp a camera writes at ``epoch`` (truncated to 10 ms, as the camera does)."""
        ticks = int(epoch * 100.0 + 1e-6)
        sec, hund = divmod(ticks, 100)
        return cls(sec, hund, struct.pack(">IB", sec, hund))


@dataclass(frozen=True)
class AxisProduct:
    hardware_id: int
    firmware: tuple[int, int, int]
    mac: bytes

    @property
    def firmware_str(self) -> str:
        major, minor, patch = self.firmware
        return f"{major:d}.{minor:d}.{patch:d}"

    @property
    def mac_str(self) -> str:
        return ":".join(f"{b:02X}" for b in self.mac)

    def payload(self) -> bytes:
        return _PRODUCT_TAG + struct.pack(">H", self.hardware_id) + bytes(self.firmware) + bytes(self.mac)


@dataclass(frozen=True)
class JpegInfo:
    """What the header of one JPEG says. ``problems`` lists what is wrong, in words."""

    time: AxisTime | None
    product: AxisProduct | None
    complete: bool
    width: int | None = None
    height: int | None = None
    problems: tuple[str, ...] = field(default=())

    @property
    def timestamp(self) -> float | None:
        return self.time.epoch if self.time else None


def _axis_payload(payload: bytes):
    if len(payload) != 13:
        return None
    if payload[:2] == _TIME_TAG and payload[12] == 0x01:
        sec, hund = struct.unpack(">IB", payload[2:7])
        if hund > 99:
            return None
        return AxisTime(sec, hund, bytes(payload[7:12]))
    if payload[:2] == _PRODUCT_TAG:
        (hw,) = struct.unpack(">H", payload[2:4])
        return AxisProduct(hw, (payload[4], payload[5], payload[6]), bytes(payload[7:13]))
    return None


def _ends_whole(data: bytes) -> bool:
    return data.rstrip(b"\r\n\x00").endswith(EOI)


def inspect_jpeg(data: bytes) -> JpegInfo:
    """Read the header of one JPEG: Axis time and product, size, and whether it is whole.

    Raises :class:`JpegError` when the bytes do not start like a JPEG. A frame that is cut
    short, or has no Axis segments, is answered with ``problems`` rather than an exception.
    """
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise TypeError("inspect_jpeg expects bytes")
    data = bytes(data)
    if not data.startswith(SOI):
        raise JpegError("not a JPEG: it does not start with the start-of-image marker FF D8")
    time = product = None
    width = height = None
    problems: list[str] = []
    i = 2
    n = len(data)
    while True:
        while i < n and data[i] == 0xFF and i + 1 < n and data[i + 1] == 0xFF:
            i += 1  # fill bytes
        if i + 2 > n:
            problems.append("the header is cut short")
            break
        if data[i] != 0xFF:
            problems.append(f"no marker where one was expected (byte {i})")
            break
        marker = data[i + 1]
        if marker == 0xD9:
            problems.append("end-of-image before any image data")
            break
        if 0xD0 <= marker <= 0xD7 or marker == 0x01:
            i += 2
            continue
        if i + 4 > n:
            problems.append("the header is cut short")
            break
        (length,) = struct.unpack(">H", data[i + 2 : i + 4])
        if length < 2 or i + 2 + length > n:
            problems.append("the header is cut short" if length >= 2 else f"bad segment length at byte {i}")
            break
        body = data[i + 4 : i + 2 + length]
        if marker == _COM and length == _SEG_LEN:
            seg = _axis_payload(body)
            if isinstance(seg, AxisTime):
                time = time or seg
            elif isinstance(seg, AxisProduct):
                product = product or seg
        elif marker in (0xC0, 0xC1, 0xC2, 0xC3) and len(body) >= 5:
            height, width = struct.unpack(">HH", body[1:5])
        if marker == _SOS:
            break
        i += 2 + length
    complete = _ends_whole(data)
    if not complete:
        problems.append("the frame is cut short (no end-of-image marker)")
    if time is None:
        problems.append("no Axis time segment")
    if product is None:
        problems.append("no Axis product segment")
    return JpegInfo(time, product, complete, width, height, tuple(problems))


def axis_timestamp(data: bytes) -> float | None:
    """The camera's epoch time stamped in a JPEG, or None when it has none (or is no JPEG)."""
    try:
        return inspect_jpeg(data).timestamp
    except JpegError:
        return None


def comment_segment(payload: bytes) -> bytes:
    return b"\xff\xfe" + struct.pack(">H", len(payload) + 2) + payload


def stamp_jpeg(jpeg: bytes, epoch: float, product: AxisProduct, time_first: bool = True) -> bytes:
    """Insert the two Axis comment segments after the JFIF APP0 segment (or after SOI).

    The layout is that of firmware 5.x/6.x frames: APP0, time, product, then the tables.
    """
    if not jpeg.startswith(SOI):
        raise JpegError("stamp_jpeg: not a JPEG")
    pos = 2
    if jpeg[2:4] == b"\xff\xe0":
        (length,) = struct.unpack(">H", jpeg[4:6])
        pos = 4 + length
    segs = [comment_segment(AxisTime.from_epoch(epoch).payload()), comment_segment(product.payload())]
    if not time_first:
        segs.reverse()
    return jpeg[:pos] + b"".join(segs) + jpeg[pos:]
