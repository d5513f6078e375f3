"""Any MJPEG-over-HTTP camera: the ``mjpeg`` kind of :class:`vts_hw.camera.Camera`.

For cameras that do not stamp their frames (no Axis JPEG comment segments): every frame is
timed by its receipt on the host (``Frame.time_source == "receipt"``, ``camera_time`` None),
and the clock model says so (``ClockOffset.source == "receipt"``: no camera clock, offset 0,
uncertainty the longest snapshot round trip seen). Such a stream cannot show the frames the
camera skipped (``FrameStream.stats.problems`` says so).

rig.yaml::

    - name: cam3
      kind: mjpeg
      host: 192.0.2.30
      options: {stream_path: /video.mjpg, snapshot_path: /snapshot.jpg, led: none}

HTTP, authentication, timeouts and the typed errors are the Axis driver's client
(:mod:`.axis_client`), and the stream its multipart connection; the paths default to the VAPIX
ones, which many cameras also answer. Its roles (:mod:`vts_hw.camera`): frames, device
information and the clock, always; ``led: vapix`` adds the LED on the camera's I/O port as an
Axis camera has it (:class:`MjpegLedCamera`, the :class:`~vts_hw.camera.Illumination` role);
``led: none`` (the default) has no LED role at all. It has no parameters and tells no uptime.
"""

from __future__ import annotations

import time
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from vts_hw.camera import ClockOffset, Frame, check_whole, kind_settings
from vts_hw.drivers.axis_errors import BadReply
from vts_hw.drivers.axis_io import AxisIOPort
from vts_hw.drivers.axis_stream import HTTP_KEYS, HttpCamera


class MjpegOptions(BaseModel):
    """The ``mjpeg`` kind's own keys (``options:``)."""

    model_config = ConfigDict(extra="forbid")
    # a path from / only: anything else joins onto the host (http://cam + ".evil.example/x" is another
    # host, "@evil.example/x" another host with this one as its user name), and the credentials go there
    stream_path: str = Field(
        default="/axis-cgi/mjpg/video.cgi", pattern=r"^/", description="the path of its MJPEG stream (from /)"
    )
    snapshot_path: str = Field(
        default="/axis-cgi/jpg/image.cgi", pattern=r"^/", description="the path of one JPEG (from /)"
    )
    led: Literal["none", "vapix"] = Field(
        default="none",
        description="vapix: its LED ring hangs on a VAPIX I/O port (`led_port`); none: it has no LED to switch",
    )


MjpegSettings = kind_settings(
    "MjpegSettings",
    "Any MJPEG-over-HTTP camera that stamps nothing (frames timed by their receipt): its "
    "address and credentials as an Axis camera's, and under `options:` the paths of its stream and snapshot "
    "and whether its LED hangs on a VAPIX I/O port.",
    HTTP_KEYS,
    required=("host",),
    options=MjpegOptions,
)


def receipt_frame(seq: int, jpeg: bytes, host_time: float, problems=()) -> Frame:
    """A JPEG timed by its receipt only (whatever segments it carries)."""
    probs = list(problems)
    if not jpeg.startswith(b"\xff\xd8"):
        probs.append("not a JPEG")
    elif not jpeg.rstrip(b"\x00\r\n").endswith(b"\xff\xd9"):
        probs.append("JPEG cut short (no end-of-image marker)")
    return Frame(seq, jpeg, None, host_time, tuple(probs), time_source="receipt")


class MjpegCamera(HttpCamera):
    """An MJPEG camera over HTTP, timed by receipt: frames, device information, the clock."""

    settings = MjpegSettings

    def __init__(self, *args, options: MjpegOptions | None = None, **kwargs):
        """:class:`~vts_hw.drivers.axis_stream.HttpCamera`'s arguments, and the kind's ``options``."""
        super().__init__(*args, **kwargs)
        self.options = options or MjpegOptions()
        self.stream_path = self.options.stream_path
        self._worst_rtt = 0.0

    @classmethod
    def from_config(cls, cfg, clock=time.time, **extra) -> MjpegCamera:
        """The camera of an entry: :class:`MjpegLedCamera` when its LED hangs on an I/O port."""
        s = cls.settings.from_entry(cfg)  # checked once: the options are its fields
        opts = MjpegOptions.model_construct(**{k: getattr(s, k) for k in MjpegOptions.model_fields})
        kind = MjpegLedCamera if opts.led == "vapix" else MjpegCamera
        return super(MjpegCamera, kind).from_config(cfg, clock, checked=s, options=opts, **extra)

    def make_frame(self, seq: int, jpeg: bytes, host_time: float, problems=()) -> Frame:
        return receipt_frame(seq, jpeg, host_time, problems)

    def snapshot(self, compression: int | None = None) -> Frame:
        t0 = self.clock()
        r = self.request(
            "GET",
            self.options.snapshot_path,
            params={
                "resolution": self.resolution,
                "compression": self.compression if compression is None else int(compression),
            },
        )
        data = r.content
        host_t = self.clock()
        self._worst_rtt = max(self._worst_rtt, host_t - t0)
        if not data.startswith(b"\xff\xd8"):
            ctype = r.headers.get("content-type", "")
            raise BadReply(self.name, f"camera {self.name} sent {ctype or 'data'} instead of a JPEG")
        frame = receipt_frame(0, data, host_t)
        check_whole(frame, self.name)
        return frame

    def device_info(self) -> dict[str, str]:
        return {
            "Brand": "MJPEG over HTTP",
            "ProdNbr": "mjpeg",
            "URL": self.base_url,
            "Stream": self.stream_path,
            "Clock": "none in the frames: times are host receipt times",
            "LED": "I/O port (VAPIX)"
            if isinstance(self, AxisIOPort)
            else "none: this camera cannot switch one (an LED switch is a no-op)",
        }

    def clock_offset(self, samples: int = 5) -> ClockOffset:
        """No camera clock: offset 0 by definition, uncertain by the longest round trip of
        ``samples`` snapshots (a frame is exposed somewhere in its request's round trip)."""
        for _ in range(max(1, samples)):
            self.snapshot()
        return ClockOffset(0.0, self._worst_rtt, self.clock(), "receipt", samples, source="receipt")


class MjpegLedCamera(AxisIOPort, MjpegCamera):
    """An MJPEG camera whose LED ring hangs on a VAPIX I/O port (``led: vapix``): the
    :class:`~vts_hw.camera.Illumination` role besides."""


__all__ = ["MjpegCamera", "MjpegLedCamera", "MjpegOptions", "MjpegSettings", "receipt_frame"]
