"""One simulated camera as the simulated HTTP server sees it: frames, LED and clock.

:class:`SimCameraSource` ties a camera of the :class:`~.scene.Scene` to a
:class:`~.render.Renderer` and a :class:`~.clock.SimClock`. Each JPEG it hands out carries the
two Axis comment segments (time from that camera's own clock, product id), like a real one.
All methods are safe to call from several HTTP handler threads at once: the scene's
schedules and the renderer lock what they share, and nothing here keeps mutable state.
"""

from __future__ import annotations

from vts_hw.recording.axis_jpeg import AxisProduct, stamp_jpeg
from vts_hw.sim_devices.clock import SimClock
from vts_hw.sim_devices.clock_warmup import warm_offset_s
from vts_hw.sim_devices.frame_bank import FrameBank
from vts_hw.sim_devices.optics import optics_of, set_optics
from vts_hw.sim_devices.render import Renderer
from vts_hw.sim_devices.scene import Scene


class SimCameraSource:
    """Frames and LED of camera ``cam`` of ``scene``, at times read from ``clock``."""

    def __init__(self, scene: Scene, renderer: Renderer, cam: str, clock: SimClock):
        if cam not in scene.cameras:
            raise KeyError(f"the scene has no camera {cam!r} (it has {', '.join(scene.cameras)})")
        self.scene = scene
        self.renderer = renderer
        self.clock = clock
        self.name: str = cam
        model = scene.cameras[cam]
        self.width: int = model.width
        self.height: int = model.height
        self.product: AxisProduct = scene.products[cam]
        self.bank: FrameBank | None = None  # frames made ahead of time (sim_devices/frame_bank.py)

    def stream_starting(self, t: float) -> None:
        """A stream's first frame is at grid time ``t``: frames made ahead start playing."""
        if self.bank is not None:
            self.bank.play_from(t)

    def camera_time(self, host_t: float | None = None) -> float:
        """This camera's clock at host time ``host_t`` (default: now)."""
        t = self.clock.now() if host_t is None else host_t
        return self.scene.clocks[self.name].camera_time(t) + warm_offset_s(self.scene, self.name, t)

    def started(self, t: float) -> None:
        """The camera (re)started at ``t``: a declared warm-up drift counts from then (warmup.py)."""
        self.scene.booted[self.name] = float(t)

    def set_led(self, on: bool) -> None:
        """Switch the LED ring on or off, now."""
        self.scene.set_led(self.name, on, self.clock.now())

    def pulse_led(self, duration_s: float) -> None:
        """LED on now, off ``duration_s`` simulated seconds later."""
        self.scene.pulse_led(self.name, self.clock.now(), duration_s)

    def set_optics(self, **changes) -> dict:
        """Change this camera's focus and mount (``focus_blur_px``, ``yaw_deg``, ``pitch_deg``:
        sim_devices/optics.py), now; returns all three. A bad value changes nothing (ValueError)."""
        return set_optics(self.scene, self.renderer, self.name, **changes).to_dict()

    def optics(self) -> dict:
        """This camera's focus and mount (sim_devices/optics.py)."""
        return optics_of(self.scene, self.renderer, self.name).to_dict()

    def led_on(self) -> bool:
        return self.scene.led_on(self.name, self.clock.now())

    def jpeg(self, quality: int, host_t: float | None = None) -> tuple[bytes, float]:
        """The frame at host time ``host_t`` (default: now) as a stamped JPEG.

        Returns ``(jpeg_bytes, camera_epoch)``: the camera-clock time of the frame (the stamp
        in the JPEG is that time truncated to 10 ms, as a camera writes it).
        """
        t = self.clock.now() if host_t is None else host_t
        cam_t = self.camera_time(t)
        made = self.bank.take(self.name, t, quality) if self.bank is not None and host_t is not None else None
        if made is None:
            made = self.renderer.encode(self.renderer.render(self.name, t), quality)
        return stamp_jpeg(made, cam_t, self.product), cam_t
