"""An Axis MJPEG stream that survives drops and stalls, and reports every gap.

:class:`FrameStream` yields :class:`~vts_hw.drivers.axis.Frame` objects and, where frames
are missing, :class:`StreamGap` records. A dropped connection, a stall (no bytes for
``stall_timeout``), a 503 or a refused connection end in a reconnect with backoff; only a 401
(wrong password) or a reply that is not a multipart stream stops it with an error. Gaps are
found from the cameras' own timestamps, so frames lost anywhere are counted, never hidden.
A torn frame (no end-of-image) is not yielded: it is counted and shows up as a gap.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import urllib3

from vts_hw.errors import DataError
from vts_hw.recording.mjpeg import MultipartParser, boundary_from_content_type
from vts_hw.drivers.axis import AxisCamera, AxisError, BadReply, CameraUnauthorized, frame_from_bytes


class NotAStream(BadReply):
    """The camera answered the stream request with something that is not multipart MJPEG."""


@dataclass(frozen=True)
class StreamGap:
    """Frames missing between two received frames (or while reconnecting)."""

    after_seq: int
    camera_t0: float | None
    camera_t1: float | None
    missing: int
    reason: str
    host_time: float

    @property
    def seconds(self) -> float | None:
        if self.camera_t0 is None or self.camera_t1 is None:
            return None
        return self.camera_t1 - self.camera_t0


@dataclass
class StreamStats:
    frames: int = 0
    torn: int = 0
    gaps: int = 0
    missing: int = 0
    reconnects: int = 0
    last_error: str = ""
    problems: list[str] = field(default_factory=list)


class FrameStream:
    """Iterate over the frames of one camera's MJPEG stream.

    fps, duration (host seconds) and nbrofframes are asked of the camera; on reconnect the
    remainder is asked for. ``stop()`` (from any thread) ends the iteration promptly.
    """

    def __init__(self, camera: AxisCamera, *, fps: float | None = None, duration: float | None = None,
                 nbrofframes: int | None = None, reconnect: bool = True, stall_timeout: float | None = None,
                 max_backoff: float = 5.0, give_up_after: float | None = None,
                 stop_event: threading.Event | None = None):
        self.camera = camera
        self.fps = float(fps or camera.fps)
        self.duration = duration
        self.nbrofframes = nbrofframes
        self.reconnect = reconnect
        self.stall_timeout = stall_timeout or max(2.0, 5.0 / self.fps)
        self.max_backoff = max_backoff
        self.give_up_after = give_up_after
        self.stop_event = stop_event or threading.Event()
        self.stats = StreamStats()
        self._resp = None
        self._lock = threading.Lock()

    def stop(self) -> None:
        self.stop_event.set()
        with self._lock:
            resp = self._resp
        if resp is not None:
            try:
                resp.close()
            except Exception:
                pass

    # -- iteration -------------------------------------------------------------------
    def __iter__(self):
        cam = self.camera
        session = cam.new_session()
        started = time.monotonic()
        last_ok = started
        backoff = 0.25
        seq = 0
        last_cam_t: float | None = None
        pending_reason = ""
        try:
            while not self.stop_event.is_set():
                remaining = None
                if self.duration is not None:
                    remaining = self.duration - (time.monotonic() - started)
                    if remaining <= 0:
                        return
                if self.nbrofframes is not None and seq >= self.nbrofframes:
                    return
                ended_normally = False
                try:
                    for item in self._one_connection(session, remaining, seq):
                        if isinstance(item, str):  # a torn frame
                            self.stats.torn += 1
                            pending_reason = pending_reason or "torn frame discarded"
                            continue
                        frame = item
                        if last_cam_t is not None and frame.camera_time is not None:
                            gap = self._gap(seq - 1, last_cam_t, frame.camera_time, pending_reason)
                            if gap is not None:
                                yield gap
                        pending_reason = ""
                        if frame.camera_time is not None:
                            last_cam_t = frame.camera_time
                        self.stats.frames += 1
                        seq += 1
                        last_ok = time.monotonic()
                        backoff = 0.25
                        yield frame
                        if self.nbrofframes is not None and seq >= self.nbrofframes:
                            return
                        if self.duration is not None and time.monotonic() - started >= self.duration:
                            return
                        if self.stop_event.is_set():
                            return
                    ended_normally = True
                except CameraUnauthorized:
                    raise
                except (AxisError, urllib3.exceptions.HTTPError, OSError, DataError) as exc:
                    if self.stop_event.is_set():
                        return
                    if isinstance(exc, NotAStream):
                        raise
                    reason = _why(exc)
                    self.stats.last_error = reason
                    if not self.reconnect:
                        raise AxisError(cam.name, f"camera {cam.name}: stream lost ({reason})") from None
                    pending_reason = f"reconnect after {reason}"
                if self.stop_event.is_set():
                    return
                if ended_normally:
                    asked_end = (self.duration is not None and time.monotonic() - started >= self.duration - 0.5)
                    if asked_end:
                        return
                    if not self.reconnect:
                        return
                    pending_reason = pending_reason or "reconnect after the camera ended the stream"
                if self.give_up_after is not None and time.monotonic() - last_ok > self.give_up_after:
                    raise AxisError(cam.name, f"camera {cam.name}: no frames for {self.give_up_after:g} s "
                                              f"({self.stats.last_error or 'stream ended'}); giving up")
                self.stats.reconnects += 1
                self.stop_event.wait(backoff)
                backoff = min(backoff * 2, self.max_backoff)
        finally:
            session.close()

    def _gap(self, after_seq: int, t0: float, t1: float, reason: str) -> StreamGap | None:
        interval = 1.0 / self.fps
        dt = t1 - t0
        if dt <= 1.5 * interval + 0.01:
            return None
        missing = max(1, int(round(dt / interval)) - 1)
        self.stats.gaps += 1
        self.stats.missing += missing
        return StreamGap(after_seq, t0, t1, missing, reason or "camera skipped frames", self.camera.clock())

    def _one_connection(self, session, remaining: float | None, seq: int):
        """Yield frames (or the string 'torn') from one HTTP connection until it ends."""
        cam = self.camera
        params: dict[str, object] = {"resolution": cam.resolution, "fps": _num(self.fps),
                                     "compression": cam.compression}
        if remaining is not None:
            params["duration"] = max(1, int(remaining + 0.999))
        if self.nbrofframes is not None:
            params["nbrofframes"] = self.nbrofframes - seq
        resp = cam.request("GET", "/axis-cgi/mjpg/video.cgi", params=params, stream=True, session=session,
                           timeout=(cam.timeout, self.stall_timeout))
        with self._lock:
            self._resp = resp
        try:
            ctype = resp.headers.get("content-type", "")
            if "multipart" not in ctype.lower():
                raise NotAStream(cam.name, f"camera {cam.name} sent {ctype or 'no content type'} instead of a "
                                         f"multipart MJPEG stream")
            parser = MultipartParser(boundary_from_content_type(ctype))
            raw = resp.raw
            while True:
                chunk = raw.read1(65536)
                if not chunk:
                    break
                host_t = cam.clock()
                for part in parser.feed(chunk):
                    # the header walk in frame_from_bytes already says whether the JPEG is whole
                    frame = frame_from_bytes(seq, part.body, host_t, part.problems)
                    if not frame.complete:
                        yield "torn"
                        continue
                    yield frame
                    seq += 1
                if self.stop_event.is_set():
                    return
            last = parser.flush()
            if last is not None and last.body:
                frame = frame_from_bytes(seq, last.body, cam.clock(), last.problems)
                yield frame if frame.complete else "torn"
        finally:
            with self._lock:
                self._resp = None
            resp.close()


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


def _why(exc: Exception) -> str:
    if isinstance(exc, AxisError):
        text = str(exc)
        return text.split(": ", 1)[-1] if "too many viewers" not in text else "too many viewers (HTTP 503)"
    if isinstance(exc, urllib3.exceptions.ReadTimeoutError):
        return "a stall (no data)"
    if isinstance(exc, urllib3.exceptions.ProtocolError):
        return "a dropped connection"
    return type(exc).__name__
