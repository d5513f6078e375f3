"""The camera contract: what procedures, the recorder and the CLI may ask of any camera.

The contract is cut by role, as ophyd-async composes a detector: :class:`Frames` (snapshot,
stream), :class:`DeviceInformation`, :class:`CameraClock` (the clock offset) — which every kind
has, and :class:`Camera` composes — and :class:`Illumination` (the LED ring),
:class:`Parameters` (what ``vts camera setup`` sets) and :class:`RunningTime` (uptime), which a
kind implements only when it has them: callers ask ``isinstance(cam, Illumination)``, no kind
fakes a role it lacks. A camera kind (``drivers/axis.py``, ``drivers/mjpeg.py``,
``drivers/replay.py``...) is one module; ``vts_hw.drivers.registry.open_camera(cfg)`` picks it
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

from collections.abc import Callable, Iterator, Mapping
from copy import copy
from dataclasses import dataclass, field
from typing import (
    Any,
    ClassVar,
    Protocol,
    Self,
    Union,
    get_args,
    get_origin,
    runtime_checkable,
)

from pydantic import BaseModel, ConfigDict, ValidationError, create_model
from pydantic_core import PydanticUndefined

from vts_hw.config import CameraConfig
from vts_hw.errors import ConfigError, DeviceError

TORN = "torn"  # what a connection yields for a frame that arrived cut short (never a Frame)
TIME_SOURCES = ("camera", "receipt", "recording")


class CameraError(DeviceError):
    """A camera failed; ``camera`` names it. ``retry``: whether reconnecting can help (a
    refused password or a reply that is not a stream cannot)."""

    retry = True

    def __init__(self, camera: str, message: str):
        super().__init__(message)
        self.camera = camera


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


# -- the roles: a camera kind implements the ones it has (docs/decisions/0100-camera-roles.md) ----------


@runtime_checkable
class Stream(Protocol):
    """A reconnecting stream over one camera, as ``Frames.stream`` gives it: frames and gaps until
    it ends or is stopped (``vts_hw.camera_stream.FrameStream`` is the one there is; named here
    by what it offers, so this contract does not import what is built on it)."""

    stats: StreamStats

    def __iter__(self) -> Iterator[Frame | StreamGap]: ...

    def stop(self) -> None: ...

    def shortfall(self, interrupted: bool = False) -> str | None: ...


@runtime_checkable
class Frames(Protocol):
    """Frames: one now, or a stream. Every camera has this role."""

    name: str
    fps: float
    resolution: str
    clock: Callable[[], float]

    def snapshot(self, compression: int | None = None) -> Frame:
        """One frame, now. ``compression`` (0-100) is a hint for this request only; a kind
        that cannot change it ignores it."""

    def open_stream(
        self, *, fps: float, duration: float | None, nbrofframes: int | None, first_seq: int, stall_timeout: float
    ) -> Connection:
        """One connection of the camera's stream (the reconnecting stream is built on it)."""

    def stream(self, **kwargs) -> Stream:
        """A reconnecting stream (``vts_hw.camera_stream.FrameStream``) over this camera."""


@runtime_checkable
class DeviceInformation(Protocol):
    """What the camera says it is (brand, product, serial, firmware, or what a kind can tell)."""

    def device_info(self) -> dict[str, str]: ...


@runtime_checkable
class CameraClock(Protocol):
    """The camera's clock against the host's (``source`` says where it comes from: its own
    stamps, the frames' receipt, a recording)."""

    def clock_offset(self, samples: int = 5) -> ClockOffset: ...


@runtime_checkable
class Illumination(Protocol):
    """An LED ring (or other illumination) the camera switches, and reads back.

    A kind that has it switches what the camera sees; a kind without it (a replay, an MJPEG
    camera without an I/O port) does not implement it, and callers ask
    ``isinstance(cam, Illumination)``. ``led_state()`` reads the LED's state back (None: this
    camera cannot tell): a switch is only known to have taken when the camera says so."""

    def led_on(self) -> None: ...

    def led_off(self) -> None: ...

    def led_pulse(self, ms: int) -> None: ...

    def led_state(self) -> bool | None: ...


@runtime_checkable
class Parameters(Protocol):
    """Named parameters in groups, read and set (what ``vts camera setup`` sets and locks, and
    what the daily QA checks)."""

    def get_params(self, group: str) -> dict[str, str]: ...

    def set_params(self, values: Mapping[str, object]) -> None: ...


@runtime_checkable
class RunningTime(Protocol):
    """How long the camera has run since it started (the warm-up check); ``uptime()`` raises a
    :class:`CameraError` when this camera cannot tell after all (e.g. old firmware)."""

    def uptime(self) -> Uptime: ...


@dataclass
class SetupResult:
    """What a camera's setup set and read back (:class:`Setup`)."""

    camera: str
    locked: dict[str, str] = field(default_factory=dict)
    """Every parameter set or locked as read: the camera's ``locked_params``."""
    changed: list[str] = field(default_factory=list)
    """The parameters whose value the setup changed."""
    notes: list[str] = field(default_factory=list)


@runtime_checkable
class Setup(Protocol):
    """Set for the VTS by ``vts camera setup`` and commissioning, and read back: ``setup_plan``
    says what would be set (touching nothing), ``set_up`` sets it and returns what was locked.
    ``cfg`` is the camera's rig.yaml entry, ``setup`` the rig's ``camera_setup:`` section."""

    def setup_plan(self, cfg: Any, setup: Any) -> list[tuple[str, str, bool]]: ...

    def set_up(self, cfg: Any, setup: Any) -> SetupResult: ...


@runtime_checkable
class Camera(Frames, DeviceInformation, CameraClock, Protocol):
    """What every camera kind offers: frames, what it is, its clock; and ``close()`` (a context
    manager). The roles some kinds have are asked for with ``isinstance``:
    :class:`Illumination`, :class:`Parameters`, :class:`RunningTime`, :class:`Setup`."""

    def close(self) -> None: ...

    def __enter__(self) -> Camera: ...

    def __exit__(self, *exc) -> None: ...


#: the roles, by the name a report or a test gives them
ROLES: dict[str, type] = {
    "frames": Frames,
    "device information": DeviceInformation,
    "clock": CameraClock,
    "illumination": Illumination,
    "parameters": Parameters,
    "running time": RunningTime,
    "setup": Setup,
}


def roles_of(cam) -> tuple[str, ...]:
    """The names of the roles a camera implements, in :data:`ROLES`' order."""
    return tuple(name for name, role in ROLES.items() if isinstance(cam, role))


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
        raise NotWhole(
            camera, f"camera {camera} sent a JPEG that is not whole ({len(jpeg)} bytes: {why}); nothing was kept"
        )


class KindSettings(BaseModel):
    """A camera kind's settings: the keys of a rig.yaml camera entry it uses (``entry_keys``,
    defined once, by :class:`~vts_hw.config.CameraConfig`) and its own keys under ``options:``."""

    model_config = ConfigDict(extra="forbid")
    entry_keys: ClassVar[tuple[str, ...]] = ()

    @classmethod
    def from_entry(cls, cfg: CameraConfig) -> Self:
        """The settings of a camera entry; a missing, wrong or unknown key is a ConfigError naming
        the camera, the kind and the key (``options.X`` for the kind's own keys), exit 2."""
        where = f"camera {cfg.name!r} (kind {cfg.kind})"
        opts = dict(cfg.options)
        for key in opts:
            if key in cls.entry_keys:
                raise ConfigError(
                    f"{where}: options.{key}: {key} is a key of the camera entry itself, not of its options"
                )
        data = {k: getattr(cfg, k) for k in cls.entry_keys if getattr(cfg, k) is not None}
        try:
            return cls.model_validate({**data, **opts})
        except ValidationError as exc:
            err = exc.errors()[0]
            loc = [str(x) for x in err.get("loc", ())]
            msg = err.get("msg", "invalid")
            if loc and loc[0] in cls.entry_keys:
                if err.get("type") == "missing":
                    what = cls.model_fields[loc[0]].description
                    raise ConfigError(f"{where} needs a {loc[0]}" + (f" ({what})" if what else "")) from None
                raise ConfigError(f"{where}: {'.'.join(loc)}: {msg}") from None
            raise ConfigError(f"{where}: options.{'.'.join(loc) or 'options'}: {msg}") from None


def kind_settings(
    name: str,
    doc: str,
    entry_keys: tuple[str, ...] = (),
    *,
    required: tuple[str, ...] = (),
    options: type[BaseModel] | None = None,
) -> Any:
    """A camera kind's settings model (its driver's ``settings``): the entry keys it uses, as
    :class:`~vts_hw.config.CameraConfig` defines them (those in ``required`` must be given), and
    the fields of ``options``, its own keys under ``options:``. The rig.yaml reference page shows it.
    A :class:`KindSettings` made at run time: typed ``Any``, its fields being the kind's."""
    fields: dict = {}
    for key in entry_keys:
        info = copy(CameraConfig.model_fields[key])
        if key in required:
            info.default = PydanticUndefined
            info.annotation = _not_none(info.annotation)
        fields[key] = (info.annotation, info)
    for key, info in options.model_fields.items() if options is not None else ():
        fields[key] = (info.annotation, info)
    model = create_model(
        name, __base__=KindSettings, __doc__=doc, __module__=options.__module__ if options else __name__, **fields
    )
    model.entry_keys = tuple(entry_keys)
    return model


def _not_none(annotation):
    args = [a for a in get_args(annotation) if a is not type(None)]
    return args[0] if get_origin(annotation) is Union and len(args) == 1 else annotation


__all__ = [
    "Frames",
    "Stream",
    "DeviceInformation",
    "CameraClock",
    "Illumination",
    "Parameters",
    "RunningTime",
    "ROLES",
    "Setup",
    "SetupResult",
    "roles_of",
    "check_whole",
    "NotWhole",
    "StreamFellShort",
    "Camera",
    "CameraError",
    "ClockOffset",
    "Connection",
    "Frame",
    "Refused",
    "SourceEnded",
    "StreamGap",
    "StreamStats",
    "TORN",
    "TIME_SOURCES",
    "Uptime",
    "KindSettings",
    "kind_settings",
]
