"""A camera stream that survives drops and stalls, and reports every gap — over any camera.

:class:`FrameStream` yields :class:`~vts_hw.camera.Frame` objects and, where frames are
missing, :class:`~vts_hw.camera.StreamGap` records, from the connections a
:class:`~vts_hw.camera.Camera` opens (``camera.open_stream``). A dropped connection, a stall,
a 503 or a refused connection end in a reconnect with backoff; only an error whose ``retry``
is False (wrong password, a reply that is not a stream) stops it with that error, and
:class:`~vts_hw.camera.SourceEnded` (a replay at its end) ends it. Gaps are found from the
cameras' own timestamps, so frames lost anywhere are counted, never hidden; frames timed only
by their receipt cannot show gaps, and the stream's ``stats.problems`` says so. A torn frame
(no end-of-image) is not yielded: it is counted and shows up as a gap.
"""

from __future__ import annotations

import threading
import time

from vts_hw.camera import TORN, CameraError, SourceEnded, StreamGap, StreamStats
from vts_hw.errors import DataError

NO_GAPS_FROM_RECEIPT = "frames timed by their receipt only: frames the camera skipped cannot be counted"


class FrameStream:
    """Iterate over the frames of one camera's stream.

    fps, duration (host seconds) and nbrofframes are asked of the camera; on reconnect the
    remainder is asked for. ``stop()`` (from any thread) ends the iteration promptly.
    """

    def __init__(
        self,
        camera,
        *,
        fps: float | None = None,
        duration: float | None = None,
        nbrofframes: int | None = None,
        reconnect: bool = True,
        stall_timeout: float | None = None,
        max_backoff: float = 5.0,
        give_up_after: float | None = None,
        stop_event: threading.Event | None = None,
    ):
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
        self._conn = None
        self._lock = threading.Lock()

    def stop(self) -> None:
        self.stop_event.set()
        with self._lock:
            conn = self._conn
        if conn is not None:
            try:
                conn.close()
            except Exception:
                pass

    def shortfall(self, interrupted: bool = False) -> str | None:
        """One sentence, naming the camera, of how the stream fell short of what was asked
        (None when it did not): no frames at all, or frames with the stream lost on the way
        (reconnects). A stream the user stopped (``interrupted``) is not blamed for its length."""
        st, name = self.stats, self.camera.name
        cause = st.last_error or "the camera ended the stream early"
        if st.frames == 0 and not interrupted:
            asked = f" in {self.duration:g} s" if self.duration is not None else ""
            return f"camera {name}: no frames{asked} ({cause})"
        if st.reconnects:
            return (
                f"camera {name}: the stream was not whole: {st.reconnects} reconnect(s) after {cause}; "
                f"{st.frames} frame(s), {st.missing} missing"
            )
        return None

    # -- iteration -------------------------------------------------------------------
    def __iter__(self):
        cam = self.camera
        error = getattr(cam, "error_class", CameraError)  # the kind's own error class, if it has one
        started = time.monotonic()
        last_ok = started
        backoff = 0.25
        seq = 0
        last_cam_t: float | None = None
        pending_reason = ""
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
                for item in self._one_connection(remaining, seq):
                    if item == TORN:
                        self.stats.torn += 1
                        pending_reason = pending_reason or "torn frame discarded"
                        continue
                    frame = item
                    if frame.time_source == "receipt" and NO_GAPS_FROM_RECEIPT not in self.stats.problems:
                        self.stats.problems.append(NO_GAPS_FROM_RECEIPT)
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
            except SourceEnded:
                return
            except (CameraError, OSError, DataError) as exc:
                if self.stop_event.is_set():
                    return
                if not getattr(exc, "retry", True):
                    raise
                reason = _why(exc)
                self.stats.last_error = reason
                if not self.reconnect:
                    raise error(cam.name, f"camera {cam.name}: stream lost ({reason})") from None
                pending_reason = f"reconnect after {reason}"
            if self.stop_event.is_set():
                return
            if ended_normally:
                asked_end = self.duration is not None and time.monotonic() - started >= self.duration - 0.5
                if asked_end:
                    return
                if not self.reconnect:
                    return
                pending_reason = pending_reason or "reconnect after the camera ended the stream"
            if self.give_up_after is not None and time.monotonic() - last_ok > self.give_up_after:
                raise error(
                    cam.name,
                    f"camera {cam.name}: no frames for {self.give_up_after:g} s "
                    f"({self.stats.last_error or 'stream ended'}); giving up",
                )
            self.stats.reconnects += 1
            self.stop_event.wait(backoff)
            backoff = min(backoff * 2, self.max_backoff)

    def _one_connection(self, remaining: float | None, seq: int):
        conn = self.camera.open_stream(
            fps=self.fps,
            duration=remaining,
            nbrofframes=None if self.nbrofframes is None else self.nbrofframes - seq,
            first_seq=seq,
            stall_timeout=self.stall_timeout,
        )
        with self._lock:
            self._conn = conn
        try:
            if self.stop_event.is_set():
                return
            yield from conn
        finally:
            with self._lock:
                self._conn = None
            conn.close()

    def _gap(self, after_seq: int, t0: float, t1: float, reason: str) -> StreamGap | None:
        interval = 1.0 / self.fps
        dt = t1 - t0
        if dt <= 1.5 * interval + 0.01:
            return None
        missing = max(1, int(round(dt / interval)) - 1)
        self.stats.gaps += 1
        self.stats.missing += missing
        return StreamGap(after_seq, t0, t1, missing, reason or "camera skipped frames", self.camera.clock())


def _why(exc: Exception) -> str:
    if isinstance(exc, CameraError):
        text = str(exc)
        return text.split(": ", 1)[-1] if "too many viewers" not in text else "too many viewers (HTTP 503)"
    name = type(exc).__name__
    if name == "ReadTimeoutError":
        return "a stall (no data)"
    if name == "ProtocolError":
        return "a dropped connection"
    return name
