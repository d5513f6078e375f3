"""The camera contract: what procedures, the recorder and the CLI may ask of any camera.

A camera kind (``drivers/axis.py``, ``drivers/mjpeg.py``, ``drivers/replay.py``...) is one
module that implements :class:`Camera`; ``vts_hw.drivers.registry.open_camera(cfg)`` picks it
from the ``kind:`` of a rig.yaml camera entry. Nothing above the drivers knows which kind it
holds. The types every kind shares live here: the one :class:`Frame`, the
:class:`ClockOffset`, a :class:`StreamGap`, and :class:`CameraError`, the error procedures
catch (each kind raises subclasses of it).

Where a frame's time comes from is part of the frame (``time_source``) and of the clock model
(``ClockOffset.source``): ``camera`` (the camera's own stamp, e.g. Axis JPEG comments),
``receipt`` (the camera stamps nothing: the host's receive time is all there is) or
``recording`` (a recorded session played back with the times it was recorded with).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Iterator, Protocol, runtime_checkable

from vts_hw.errors import ConfigError, DeviceError

TORN = "torn"   # what a connection yields for a frame that arrived cut short (never a Frame)
TIME_SOURCES = ("camera", "receipt", "recording")


class CameraError(DeviceError):
    """A camera failed; ``camera`` names it. ``retry``: whether reconnecting can help (a
    refused password or a reply that is not a stream cannot)."""

    retry = True

    def __init__(self, camera: str, message: str):
        super().__init__(message)
        self.camera = camera


class NoParameters(CameraError):
    """This kind of camera has no parameters to read or lock (e.g. a replayed recording)."""

    retry = False


class Refused(CameraError):
    """The camera answered but refused the request (e.g. a parameter group it does not have)."""


class SourceEnded(CameraError):
    """The camera has no more frames, for good (a replayed recording that reached its end)."""

    retry = False


@dataclass(frozen=True)
class Frame:
    """One JPEG as received from a camera.

    ``camera_time``: the camera's own stamp (UTC epoch s), None when it stamps nothing;
    ``host_time``: when the host received it (for a replay: when it was received while
    recording); ``time_source``: see the module docstring."""

    seq: int
    jpeg: bytes
    camera_time: float | None
    host_time: float
    problems: tuple[str, ...] = ()
    time_source: str = "camera"

    @property
    def complete(self) -> bool:
        return not any("cut short" in p or "not a JPEG" in p for p in self.problems)


@dataclass(frozen=True)
class ClockOffset:
    """camera clock minus host clock, in seconds, with its uncertainty.

    ``source`` ``receipt``: the camera has no clock of its own in its frames; the offset is
    0 by definition and the uncertainty is the spread of receive delays (not measured)."""

    offset_s: float
    uncertainty_s: float
    host_time: float
    method: str
    samples: int
    source: str = "camera"


@dataclass(frozen=True)
class Uptime:
    """How long the camera has been running since it started, as the camera tells it:
    ``seconds`` within ``resolution_s`` (1 s from a count of seconds, 60 s from an ``up 2:01``
    line); ``method`` says where it was read."""

    seconds: float
    resolution_s: float
    method: str


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


@runtime_checkable
class Connection(Protocol):
    """One connection of a stream: frames (or :data:`TORN`) until it ends; ``close()`` from
    any thread ends it promptly."""

    def __iter__(self) -> Iterator[Frame | str]: ...

    def close(self) -> None: ...


@runtime_checkable
class Camera(Protocol):
    """What a camera of any kind offers.

    ``led_switches`` says whether ``led_on``/``led_off`` change what the camera sees (False
    for a replay: the calls are accepted and recorded as no-ops, and ``device_info`` says so).
    ``led_state()`` reads the LED's state back (None: not known): a switch is only known to
    have taken when the camera says so.
    """

    name: str
    fps: float
    resolution: str
    clock: Callable[[], float]
    led_switches: bool

    def snapshot(self, compression: int | None = None) -> Frame:
        """One frame, now. ``compression`` (0-100) is a hint for this request only; a kind
        that cannot change it ignores it."""

    def open_stream(self, *, fps: float, duration: float | None, nbrofframes: int | None,
                    first_seq: int, stall_timeout: float) -> Connection:
        """One connection of the camera's stream (the reconnecting stream is built on it)."""

    def stream(self, **kwargs) -> "Iterator[Frame | StreamGap]":
        """A reconnecting stream (``vts_hw.camera_stream.FrameStream``) over this camera."""

    def led_on(self) -> None: ...

    def led_off(self) -> None: ...

    def led_pulse(self, ms: int) -> None: ...

    def led_state(self) -> bool | None:
        """Whether the LED ring's output is on now, read back from the camera (True/False);
        None where the kind cannot tell (a replay, a camera without an I/O port)."""

    def device_info(self) -> dict[str, str]: ...

    def clock_offset(self, samples: int = 5) -> ClockOffset: ...

    def get_params(self, group: str) -> dict[str, str]:
        """Parameters of a group; :class:`NoParameters` where the kind has none."""

    # optional: ``uptime() -> Uptime`` where the kind can tell it (the daily QA's warm-up check
    # says "not known" for a kind without it, or a camera that cannot tell)

    def close(self) -> None: ...

    def __enter__(self) -> "Camera": ...

    def __exit__(self, *exc) -> None: ...


class StreamFellShort(CameraError):
    """A stream delivered nothing, or was lost on the way (it reconnected)."""


class NotWhole(CameraError):
    """The camera sent an image that is not a whole JPEG (cut short, or one that does not decode)."""


def check_whole(frame: Frame, camera: str) -> None:
    """Raise :class:`NotWhole`, naming ``camera``, unless ``frame`` is a whole JPEG: SOI first,
    EOI last, and it decodes. Called on every snapshot before anyone keeps or uses it."""
    jpeg = frame.jpeg
    why = None
    if not jpeg.startswith(b"\xff\xd8"):
        why = "it does not start as a JPEG does"
    elif not frame.complete or not jpeg.rstrip(b"\x00\r\n").endswith(b"\xff\xd9"):
        why = "it is cut short (no end-of-image marker)"
    else:
        import cv2
        import numpy as np
        img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_UNCHANGED)
        if img is None or img.size == 0:
            why = "it does not decode"
    if why:
        raise NotWhole(camera, f"camera {camera} sent a JPEG that is not whole ({len(jpeg)} bytes: {why}); "
                               f"nothing was kept")


def kind_options(cfg, model):
    """A camera entry's ``options:`` checked against a kind's pydantic ``model``; a wrong or
    unknown key is a ConfigError naming the camera, the key and what was expected."""
    from pydantic import ValidationError

    try:
        return model.model_validate(dict(cfg.options))
    except ValidationError as exc:
        err = exc.errors()[0]
        key = ".".join(str(x) for x in err.get("loc", ())) or "options"
        raise ConfigError(f"camera {cfg.name!r} (kind {cfg.kind}): options.{key}: {err.get('msg', 'invalid')}") \
            from None


__all__ = ["check_whole", "NotWhole", "StreamFellShort", "Camera", "CameraError", "ClockOffset", "Connection", "Frame", "NoParameters", "Refused", "SourceEnded",
           "StreamGap", "StreamStats", "TORN", "TIME_SOURCES", "Uptime", "kind_options"]
