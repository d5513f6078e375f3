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

HTTP, authentication, timeouts and the typed errors are the Axis driver's (the same
``requests`` session and digest handling); the paths default to the VAPIX ones, which many
cameras also answer. ``led: vapix`` switches an LED on the camera's I/O port as an Axis
camera does; ``led: none`` (the default) accepts the calls as no-ops and ``device_info`` says so.
"""

from __future__ import annotations

import time
from typing import Literal

from pydantic import BaseModel, ConfigDict

from vts_hw.camera import ClockOffset, Frame, NoParameters, check_whole, kind_options
from vts_hw.drivers.axis import AxisCamera, BadReply
from vts_hw.errors import ConfigError


class MjpegOptions(BaseModel):
    model_config = ConfigDict(extra="forbid")
    stream_path: str = "/axis-cgi/mjpg/video.cgi"
    snapshot_path: str = "/axis-cgi/jpg/image.cgi"
    led: Literal["none", "vapix"] = "none"


def receipt_frame(seq: int, jpeg: bytes, host_time: float, problems=()) -> Frame:
    """A JPEG timed by its receipt only (whatever segments it carries)."""
    probs = list(problems)
    if not jpeg.startswith(b"\xff\xd8"):
        probs.append("not a JPEG")
    elif not jpeg.rstrip(b"\x00\r\n").endswith(b"\xff\xd9"):
        probs.append("JPEG cut short (no end-of-image marker)")
    return Frame(seq, jpeg, None, host_time, tuple(probs), time_source="receipt")


class MjpegCamera(AxisCamera):
    """An MJPEG camera over HTTP, timed by receipt."""

    def __init__(self, *args, options: MjpegOptions | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.options = options or MjpegOptions()
        self.stream_path = self.options.stream_path
        self.led_switches = self.options.led == "vapix"
        self.led_calls: list[str] = []
        self._worst_rtt = 0.0

    @classmethod
    def from_config(cls, cfg, clock=time.time) -> "MjpegCamera":
        opts = kind_options(cfg, MjpegOptions)
        if not cfg.host:
            raise ConfigError(f"camera {cfg.name!r} (kind mjpeg): host is required")
        return cls(cfg.name, cfg.base_url, cfg.user, cfg.password(), timeout=cfg.timeout_s,
                   led_port=cfg.led_port, resolution=cfg.resolution_str, fps=cfg.fps,
                   compression=cfg.compression, clock=clock, verify=cfg.ca_cert or True, options=opts)

    def __repr__(self) -> str:
        return f"MjpegCamera({self.name!r}, {self.base_url!r}, user={self.user!r})"

    def make_frame(self, seq: int, jpeg: bytes, host_time: float, problems=()) -> Frame:
        return receipt_frame(seq, jpeg, host_time, problems)

    def snapshot(self, compression: int | None = None) -> Frame:
        t0 = self.clock()
        r = self.request("GET", self.options.snapshot_path,
                         params={"resolution": self.resolution, "compression": self.compression
                                 if compression is None else int(compression)})
        data = r.content
        host_t = self.clock()
        self._worst_rtt = max(self._worst_rtt, host_t - t0)
        if not data.startswith(b"\xff\xd8"):
            ctype = r.headers.get("content-type", "")
            raise BadReply(self.name, f"camera {self.name} sent {ctype or 'data'} instead of a JPEG")
        frame = receipt_frame(0, data, host_t)
        check_whole(frame, self.name)
        return frame

    @property
    def vapix_version(self) -> int:
        return 0

    def get_params(self, group: str) -> dict[str, str]:
        raise NoParameters(self.name, f"camera {self.name} (kind mjpeg) has no parameters to read")

    def set_params(self, values) -> None:
        raise NoParameters(self.name, f"camera {self.name} (kind mjpeg) has no parameters to set")

    def led_on(self) -> None:
        self._led("on", super().led_on)

    def led_off(self) -> None:
        self._led("off", super().led_off)

    def led_pulse(self, ms: int) -> None:
        if not 1 <= int(ms) <= 60000:
            raise ValueError("LED pulse must be 1 to 60000 ms")
        self._led(f"pulse {int(ms)}", lambda: AxisCamera.led_pulse(self, ms))

    def led_state(self) -> bool | None:
        """The I/O port's state (``led: vapix``); None (not known) for a camera without one."""
        return super().led_state() if self.led_switches else None

    def _led(self, what: str, call) -> None:
        self.led_calls.append(what)
        if self.led_switches:
            call()

    def device_info(self) -> dict[str, str]:
        return {"Brand": "MJPEG over HTTP", "ProdNbr": "mjpeg", "URL": self.base_url,
                "Stream": self.stream_path, "Clock": "none in the frames: times are host receipt times",
                "LED": "I/O port (VAPIX)" if self.led_switches else "no-op: calls accepted and recorded only"}

    def clock_offset(self, samples: int = 5) -> ClockOffset:
        """No camera clock: offset 0 by definition, uncertain by the longest round trip of
        ``samples`` snapshots (a frame is exposed somewhere in its request's round trip)."""
        for _ in range(max(1, samples)):
            self.snapshot()
        return ClockOffset(0.0, self._worst_rtt, self.clock(), "receipt", samples, source="receipt")
