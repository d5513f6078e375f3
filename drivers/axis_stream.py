"""One multipart MJPEG connection over HTTP (Axis ``mjpg/video.cgi`` or any MJPEG camera).

:class:`MultipartConnection` is what :meth:`AxisCamera.open_stream` (and the ``mjpeg`` kind)
return: the frames of one HTTP response, or :data:`~vts_hw.camera.TORN` for a frame that
arrived cut short. Failures of the wire become camera errors that say what happened (``a
stall (no data)``, ``a dropped connection``); the reconnecting, gap-counting stream over any
camera is :class:`vts_hw.camera_stream.FrameStream` (re-exported here). :class:`HttpCamera` is
what the HTTP camera kinds (``axis``, ``mjpeg``) are built on: the client, the image settings
of :data:`HTTP_KEYS`, this stream, and ``from_config``.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any, Self

import urllib3

from vts_hw.camera import TORN, Frame, StreamGap
from vts_hw.camera_stream import FrameStream
from vts_hw.drivers.axis_client import AxisClient
from vts_hw.drivers.axis_errors import BadReply, CameraUnreachable
from vts_hw.recording.mjpeg import MultipartParser, boundary_from_content_type


class NotAStream(BadReply):
    """The camera answered the stream request with something that is not multipart MJPEG."""

    retry = False


class MultipartConnection:
    """``GET path?params`` as a multipart stream; iterate for frames, ``close()`` from any thread."""

    def __init__(
        self,
        cam,
        path: str,
        params: dict,
        *,
        stall_timeout: float,
        first_seq: int,
        make_frame: Callable[[int, bytes, float, tuple], Frame],
    ):
        self.cam = cam
        self.path = path
        self.params = params
        self.stall_timeout = stall_timeout
        self.seq = first_seq
        self.make_frame = make_frame
        self._lock = threading.Lock()
        self._resp = None
        self._closed = False
        self._session = cam.new_session()  # a stream in a thread must not share connections

    def close(self) -> None:
        with self._lock:
            self._closed = True
            resp = self._resp
        if resp is not None:
            try:
                resp.close()
            except Exception:
                pass

    def __iter__(self):
        cam = self.cam
        try:
            resp = cam.request(
                "GET",
                self.path,
                params=self.params,
                stream=True,
                session=self._session,
                timeout=(cam.timeout, self.stall_timeout),
            )
            with self._lock:
                self._resp = resp
                closed = self._closed
            if closed:
                return
            try:
                yield from self._frames(resp)
            except urllib3.exceptions.ReadTimeoutError:
                raise CameraUnreachable(cam.name, f"camera {cam.name}: a stall (no data)") from None
            except urllib3.exceptions.HTTPError:
                raise CameraUnreachable(cam.name, f"camera {cam.name}: a dropped connection") from None
            finally:
                with self._lock:
                    self._resp = None
                resp.close()
        finally:
            self._session.close()

    def _frames(self, resp):
        cam = self.cam
        ctype = resp.headers.get("content-type", "")
        if "multipart" not in ctype.lower():
            raise NotAStream(
                cam.name, f"camera {cam.name} sent {ctype or 'no content type'} instead of a multipart MJPEG stream"
            )
        parser = MultipartParser(boundary_from_content_type(ctype))
        raw = resp.raw
        # a whole frame at least every `patience` s: a camera that trickles bytes never trips the
        # per-read stall timeout, and would hold the stream (and its caller) for ever
        patience = max(self.stall_timeout, float(getattr(cam, "timeout", 0) or 0))
        last_part = time.monotonic()
        while True:
            chunk = raw.read1(65536)
            if not chunk:
                break
            host_t = cam.clock()
            now = time.monotonic()
            if now - last_part > patience:
                raise CameraUnreachable(
                    cam.name, f"camera {cam.name}: no whole frame in {patience:g} s (data comes, too slowly)"
                )
            for part in parser.feed(chunk):
                last_part = now
                # the header walk in make_frame already says whether the JPEG is whole
                frame = self.make_frame(self.seq, part.body, host_t, part.problems)
                if not frame.complete:
                    yield TORN
                    continue
                yield frame
                self.seq += 1
            if self._closed:
                return
        last = parser.flush()
        if last is not None and last.body:
            frame = self.make_frame(self.seq, last.body, cam.clock(), last.problems)
            yield frame if frame.complete else TORN


class MultipartStream:
    """The streaming half of the :class:`~vts_hw.camera.Frames` role of an HTTP camera
    (mixed into an :class:`~vts_hw.drivers.axis_client.AxisClient`: :class:`HttpCamera`): ``GET stream_path`` as one
    connection, and the reconnecting stream over it; each JPEG is made a Frame by the kind's
    ``make_frame`` (timed by its Axis stamp, or by its receipt)."""

    stream_path = "/axis-cgi/mjpg/video.cgi"
    resolution: str
    compression: int

    def make_frame(self, seq: int, jpeg: bytes, host_time: float, problems=()) -> Frame:
        raise NotImplementedError

    def open_stream(
        self,
        *,
        fps: float,
        duration: float | None = None,
        nbrofframes: int | None = None,
        first_seq: int = 0,
        stall_timeout: float = 2.0,
    ):
        """One connection of ``mjpg/video.cgi`` (the camera ends it after ``duration`` s or
        ``nbrofframes`` frames when asked)."""
        params: dict[str, object] = {"resolution": self.resolution, "fps": num(fps), "compression": self.compression}
        if duration is not None:
            params["duration"] = max(1, int(duration + 0.999))
        if nbrofframes is not None:
            params["nbrofframes"] = nbrofframes
        return MultipartConnection(
            self, self.stream_path, params, stall_timeout=stall_timeout, first_seq=first_seq, make_frame=self.make_frame
        )

    def stream(self, **kwargs) -> FrameStream:
        """Frames that reconnect on drops and stalls, with gaps (vts_hw.camera_stream)."""
        return FrameStream(self, **kwargs)


#: the keys of a camera entry an HTTP camera (the ``axis`` and ``mjpeg`` kinds) uses; the host must be given
HTTP_KEYS = (
    "host",
    "port",
    "scheme",
    "user",
    "password_env",
    "ca_cert",
    "timeout_s",
    "led_port",
    "resolution",
    "fps",
    "compression",
)


class HttpCamera(MultipartStream, AxisClient):
    """What every HTTP camera kind is built on (the ``axis`` kind and the ``mjpeg`` kind): the
    client, its image settings, the stream, and ``from_config`` from its kind's ``settings``
    (whose entry keys are :data:`HTTP_KEYS`)."""

    settings: Any  # the kind's vts_hw.camera.kind_settings model

    def __init__(
        self,
        name: str,
        base_url: str,
        user: str | None = "root",
        password: str | None = None,
        *,
        timeout: float = 5.0,
        led_port: int = 1,
        resolution: str = "640x480",
        fps: float = 25.0,
        compression: int = 25,
        clock=time.time,
        verify: bool | str = True,
    ):
        super().__init__(name, base_url, user, password, timeout=timeout, clock=clock, verify=verify)
        self.led_port = led_port  # the I/O port of its LED, for a kind that has one (AxisIOPort)
        self.resolution = resolution
        self.fps = fps
        self.compression = compression

    @classmethod
    def from_config(cls, cfg, clock=time.time, *, checked=None, **extra) -> Self:
        """The camera of a rig.yaml entry, checked by ``cls.settings`` (or already: ``checked``),
        its password from the environment variable the entry names; ``extra``: the kind's own arguments."""
        s = checked if checked is not None else cls.settings.from_entry(cfg)
        return cls(
            cfg.name,
            cfg.base_url,
            s.user,
            cfg.password(),
            timeout=s.timeout_s,
            led_port=s.led_port,
            resolution=cfg.resolution_str,
            fps=s.fps,
            compression=s.compression,
            clock=clock,
            verify=s.ca_cert or True,
            **extra,
        )

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, {self.base_url!r}, user={self.user!r})"


def num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


__all__ = [
    "FrameStream",
    "HTTP_KEYS",
    "HttpCamera",
    "MultipartConnection",
    "MultipartStream",
    "NotAStream",
    "StreamGap",
    "num",
]
