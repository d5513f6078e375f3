"""The images of a simulated Axis camera: the Axis comment segments, snapshots and MJPEG streams.

:func:`restamp` writes a frame's Axis time and product segments the way the camera's firmware
generation lays them out; :func:`serve_snapshot` answers ``jpg/image.cgi`` and
:func:`serve_stream` answers ``mjpg/video.cgi`` (paced on the camera's clock, with the
stream faults of :mod:`.faults` applied before every frame).
"""

from __future__ import annotations

import math
import struct
from email.utils import formatdate
from typing import TYPE_CHECKING

from vts_hw.recording.axis_jpeg import SOI, AxisProduct, AxisTime, comment_segment
from vts_hw.sim_devices.axis_params import DEFAULT_FPS, MAX_FPS
from vts_hw.sim_devices.faults import LATE_LIMIT_S

__all__ = ["BOUNDARY", "LATE_LIMIT_S", "Reject", "restamp", "unstamped", "serve_snapshot", "serve_stream", "trickle"]

if TYPE_CHECKING:
    from vts_hw.sim_devices.axis_http import Handler

BOUNDARY = "myboundary"
STREAM_HEADER = (
    "HTTP/1.0 200 OK\r\n"
    "Cache-Control: no-cache\r\n"
    "Pragma: no-cache\r\n"
    "Expires: Thu, 01 Dec 1994 16:00:00 GMT\r\n"
    "Connection: close\r\n"
    f"Content-Type: multipart/x-mixed-replace; boundary={BOUNDARY}\r\n"
    "\r\n"
).encode("ascii")
_HTML = (
    "<HTML><HEAD><TITLE>{code} {reason}</TITLE></HEAD>\r\n"
    "<BODY><H1>{code} {reason}</H1>\r\n{text}\r\n</BODY></HTML>\r\n"
)
BODY_503 = _HTML.format(
    code=503, reason="Service Unavailable", text="Too many viewers: the maximum number of clients is already connected."
)
_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}  # start-of-frame markers (not DHT, JPG, DAC)


class Reject(Exception):
    """A request argument the camera refuses (answered 400 with ``Error: <message>``)."""


def restamp(
    jpeg: bytes, epoch: float, product: AxisProduct, layout: str = "after_app0", time_extra_zero: bool = False
) -> bytes:
    """``jpeg`` with its Axis comment segments replaced by those of ``epoch`` and ``product``.

    ``after_app0`` (firmware 5 and later): after the JFIF APP0 segment, time then product.
    ``after_tables`` (firmware 4.x): just before the start-of-frame segment, i.e. after the
    quantisation tables, product then time; ``time_extra_zero`` leaves the time segment's 5
    spare bytes zero, as 4.x firmware does.
    """
    if not jpeg.startswith(SOI):
        raise ValueError("restamp: not a JPEG")
    stamp = AxisTime.from_epoch(epoch)
    if time_extra_zero:
        stamp = AxisTime(stamp.seconds, stamp.hundredths)
    time_seg, product_seg = comment_segment(stamp.payload()), comment_segment(product.payload())
    kept, i, n = [SOI], 2, len(jpeg)
    insert_at = None  # index into kept
    while i + 4 <= n and jpeg[i] == 0xFF:
        marker = jpeg[i + 1]
        if marker == 0xDA:  # start of scan: the rest is image data
            break
        (length,) = struct.unpack(">H", jpeg[i + 2 : i + 4])
        seg = jpeg[i : i + 2 + length]
        is_axis = marker == 0xFE and length == 15 and seg[4:6] in (b"\x0a\x00", b"\x0a\x01")
        if layout == "after_tables" and marker in _SOF and insert_at is None:
            insert_at = len(kept)
        if not is_axis:
            kept.append(seg)
            if layout == "after_app0" and marker == 0xE0 and len(kept) == 2:
                insert_at = 2
        i += 2 + length
    if insert_at is None:
        insert_at = 1 if layout == "after_app0" else len(kept)
    segs = [time_seg, product_seg] if layout == "after_app0" else [product_seg, time_seg]
    kept[insert_at:insert_at] = segs
    return b"".join(kept) + jpeg[i:]


def unstamped(jpeg: bytes) -> bytes:
    """``jpeg`` without any Axis comment segment (time or product), as a non-Axis camera sends it."""
    if not jpeg.startswith(SOI):
        raise ValueError("unstamped: not a JPEG")
    kept, i, n = [SOI], 2, len(jpeg)
    while i + 4 <= n and jpeg[i] == 0xFF and jpeg[i + 1] != 0xDA:
        (length,) = struct.unpack(">H", jpeg[i + 2 : i + 4])
        seg = jpeg[i : i + 2 + length]
        if not (jpeg[i + 1] == 0xFE and length == 15 and seg[4:6] in (b"\x0a\x00", b"\x0a\x01")):
            kept.append(seg)
        i += 2 + length
    return b"".join(kept) + jpeg[i:]


def image_args(h: Handler) -> tuple[int, int, int]:
    """(width, height, JPEG quality) from resolution= and compression=."""
    cam = h.cam
    res = h.query.get("resolution") or cam.params.get("Image.I0.Appearance.Resolution")
    if res.lower() not in cam.resolutions:
        raise Reject(f"resolution {res} is not supported; supported: {','.join(cam.resolutions)}")
    width, height = (int(v) for v in res.lower().split("x"))
    comp = h.query.get("compression") or cam.params.get("Image.I0.Appearance.Compression")
    if not comp.isdigit() or int(comp) > 100:
        raise Reject(f"compression must be 0-100, not {comp}")
    return width, height, 100 - int(comp)


def serve_snapshot(h: Handler) -> None:
    width, height, quality = image_args(h)
    faults = h.cam.faults
    if faults.too_many_viewers:
        h.send(503, BODY_503, "text/html")
        return
    index = h.cam.next_snapshot_index()
    jpeg = h.cam.frame(width, height, quality)
    h.cam.count("frames_served")
    h.cam.count("snapshots_served")
    if faults.torn_jpeg_at != index:
        h.send(200, jpeg, "image/jpeg")
    elif faults.torn_mode == "short":
        h.send(200, jpeg[: len(jpeg) // 2], "image/jpeg")
    else:  # cut: announce the whole JPEG, send half, die
        head = (
            f"HTTP/1.1 200 OK\r\nDate: {formatdate(usegmt=True)}\r\nContent-Type: image/jpeg\r\n"
            f"Content-Length: {len(jpeg)}\r\nConnection: close\r\n\r\n"
        ).encode("latin-1")
        h.wfile.write(head + jpeg[: len(jpeg) // 2])
        h.hang_up()


def trickle(h: Handler, path: str) -> None:
    """The ``trickle`` fault: a 200 and its headers at once, then the body a byte every
    ``trickle_s`` seconds, until the client hangs up or the fault is cleared (then the rest at
    once). The body is what the request would get: a JPEG, a multipart stream, or text."""
    faults = h.cam.faults
    jpeg = h.cam.frame(*image_args(h)[:2], 75) if "jpg" in path else b""
    if path.endswith("mjpg/video.cgi"):
        head, body = (
            STREAM_HEADER,
            (f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\nContent-Length: {len(jpeg)}\r\n\r\n").encode("ascii") + jpeg,
        )
    else:
        body = jpeg or b"root.Brand.Brand=AXIS\r\n" * 64
        ctype = "image/jpeg" if jpeg else "text/plain"
        head = (
            f"HTTP/1.1 200 OK\r\nDate: {formatdate(usegmt=True)}\r\nContent-Type: {ctype}\r\n"
            f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n"
        ).encode("latin-1")
    h.close_connection = True
    try:
        h.wfile.write(head)
        h.wfile.flush()
        for k in range(len(body)):
            if not faults.trickle:
                h.wfile.write(body[k:])
                return
            h.wfile.write(body[k : k + 1])
            h.wfile.flush()
            if h.cam._stopping.wait(faults.trickle_s):  # the camera is being stopped
                return
    except OSError:  # the client hung up: what a client with a deadline does
        pass


def serve_stream(h: Handler) -> None:
    width, height, quality = image_args(h)
    cam = h.cam
    fps = _number(h.query.get("fps") or cam.params.get("Image.I0.Stream.FPS"), "fps")
    fps = min(fps, MAX_FPS) if fps > 0 else DEFAULT_FPS
    duration = _number(h.query.get("duration", "0"), "duration")
    nbr = _number(h.query.get("nbrofframes", "0"), "nbrofframes")
    faults = cam.faults
    if faults.too_many_viewers or (
        faults.max_viewers is not None and cam.counter("active_streams") >= faults.max_viewers
    ):
        h.send(503, BODY_503, "text/html")
        return
    cam.count("active_streams")
    try:
        h.close_connection = True
        h.wfile.write(STREAM_HEADER)
        StreamWriter(h, width, height, quality, fps, duration, int(nbr)).run()
    finally:
        cam.count("active_streams", -1)


class StreamWriter:
    """Sends the parts of one MJPEG stream, paced on the camera clock, applying the faults."""

    def __init__(
        self, handler: Handler, width: int, height: int, quality: int, fps: float, duration: float, nbrofframes: int
    ):
        self.h, self.cam = handler, handler.cam
        self.size, self.quality = (width, height), quality
        self.period, self.duration, self.nbr = 1.0 / fps, duration, nbrofframes

    def run(self) -> None:
        """Frame ``g`` of the sensor's grid is captured at ``g * period`` (host time on the
        camera's clock object), so that successive streams, and cameras at one rate, share one
        grid. A frame is sent when its time comes; made late (this host was busy) it is sent
        late, stamped with its capture time, unless the stream is further behind than its late
        limit (``LATE_LIMIT_S``, or the ``skip_when_late_s`` fault): then it skips to the live
        frame and the frames between are lost, as a camera's are. Lost frames (the loss
        faults) are not sent; ``k`` counts the parts sent."""
        faults, clock, cam = self.cam.faults, self.cam.clock, self.cam
        start = clock.now()
        g = math.ceil(start / self.period)
        starting = getattr(cam.source, "stream_starting", None)
        if starting is not None:  # frames made ahead of time start playing (frame_bank.py)
            starting(g * self.period)
        stalled = False
        k = 0
        while not self.nbr or k < self.nbr:
            target = g * self.period
            if self.duration and target - start >= self.duration:
                return
            if not cam.sleep_until(target):
                return
            now = clock.now()
            if now - target > faults.late_limit():  # too far behind: the frames between are lost
                live = math.ceil(now / self.period)
                cam.count("frames_skipped", live - g)
                g = live
                continue
            if cam.offline_now() or (faults.drop_after_frames is not None and k >= faults.drop_after_frames):
                self.h.hang_up()
                return
            if not stalled and faults.stall_after_frames is not None and k >= faults.stall_after_frames:
                stalled = True
                if not cam.sleep_until(clock.now() + faults.stall_s):
                    return
                g = math.ceil(clock.now() / self.period)  # the stall's frames are lost
                continue
            if faults.lost(cam.source.name, g, target, self.period):
                cam.count("frames_lost")
                g += 1
                continue
            # captured on the sensor's grid; a little late (this host was busy), it is sent late
            if now - target > self.period:
                cam.count("frames_late")
            if not self._send_part(k, target):
                return
            k += 1
            g += 1

    def _send_part(self, k: int, captured: float | None = None) -> bool:
        """Write part ``k`` (captured at host time ``captured``, default now); False when the
        connection was deliberately cut."""
        faults = self.cam.faults
        jpeg = self.cam.frame(*self.size, self.quality, captured)
        body, stated, cut = jpeg, len(jpeg), False
        if faults.torn_jpeg_at == k:
            body = jpeg[: len(jpeg) // 2]
            cut = faults.torn_mode == "cut"
            stated = len(jpeg) if cut else len(body)
        if faults.wrong_content_length_at == k:
            stated += faults.wrong_content_length_extra
        head = f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
        if not faults.missing_content_length:
            head += f"Content-Length: {stated}\r\n"
        data = head.encode("ascii") + b"\r\n" + body + (b"" if cut else b"\r\n")
        self.h.wfile.write(data)
        self.cam.count("frames_served")
        if cut:
            self.h.hang_up()
            return False
        return True


def _number(text: str, name: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise Reject(f"{name} must be a number, not {text}") from None
    if value < 0:
        raise Reject(f"{name} must not be negative")
    return value
