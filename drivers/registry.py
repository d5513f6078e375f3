"""Open the rig's devices from the config: the trigger generator of the ``trigger`` section."""

from __future__ import annotations

import importlib
import time
from pathlib import Path

from pydantic import ValidationError

from vts_hw.camera import Camera
from vts_hw.config import CameraConfig, RigConfig, TriggerConfig, validation_message
from vts_hw.drivers.trigger import TriggerBackend, TriggerGenerator, TriggerLog
from vts_hw.errors import ConfigError

# ---- trigger backends -------------------------------------------------------------------------------
# A backend is one module that declares ``BACKEND = TriggerBackend(name, what, Settings, open)``
# (its own pydantic settings model and its constructor) and one line here: its name in rig.yaml
# (``trigger: backend:``) and where it is. A string is imported when the backend is first used,
# so a rig without NI-DAQmx or VISA never imports them; a TriggerBackend may stand here directly.

TRIGGER_BACKENDS: dict[str, TriggerBackend | str] = {
    "triggerbox": "vts_hw.drivers.trigger_box:BACKEND",
    "visa": "vts_hw.drivers.function_generator:BACKEND",
    "daqmx": "vts_hw.drivers.daqmx:BACKEND",
}


def _source(rig: RigConfig | None) -> str:
    src = getattr(rig, "_source", None) if rig is not None else None
    return str(src) if src is not None else "rig.yaml"


def trigger_backend(cfg: TriggerConfig, source: str = "rig.yaml") -> TriggerBackend | None:
    """The registered backend ``cfg.backend`` names (None for ``none``); ConfigError naming
    the file and the key for a name that is not registered."""
    if cfg.backend == "none":
        return None
    entry = TRIGGER_BACKENDS.get(cfg.backend)
    if entry is None:
        known = ", ".join(["none", *sorted(TRIGGER_BACKENDS)])
        raise ConfigError(f"{source}: trigger.backend {cfg.backend!r} is not a trigger backend (known: {known})")
    if isinstance(entry, str):
        module, _, attr = entry.partition(":")
        entry = getattr(importlib.import_module(module), attr or "BACKEND")
    return entry


def trigger_settings(cfg: TriggerConfig, source: str = "rig.yaml"):
    """(backend, its settings): the section's own keys validated by the backend's model;
    ConfigError naming the file and the key (``trigger.lines``) when they do not fit."""
    backend = trigger_backend(cfg, source)
    if backend is None:
        if cfg.options:
            raise ConfigError(
                f"{source}: trigger.{sorted(cfg.options)[0]} is not a known key (trigger backend none has no settings)"
            )
        return None, None
    try:
        return backend, backend.settings.model_validate(cfg.options)
    except ValidationError as exc:
        raise ConfigError(validation_message(source, exc, ("trigger",))) from None


def open_trigger(
    cfg: TriggerConfig | RigConfig, log_path: str | Path | None = None, clock=None, *, source: str | None = None
) -> TriggerGenerator:
    """The backend the config names (the rig's, or its ``trigger`` section), logging to
    ``log_path`` (trigger.csv) when given."""
    rig = cfg if isinstance(cfg, RigConfig) else None
    t = cfg.trigger if isinstance(cfg, RigConfig) else cfg
    where = source or _source(rig)
    if t.backend == "none":
        raise ConfigError("the rig config has no trigger generator (trigger: backend: none)")
    backend, settings = trigger_settings(t, where)
    log = TriggerLog(log_path, clock=clock or time.time)
    return backend.open(t, settings, log)


# -- cameras -----------------------------------------------------------------------------
# kind (rig.yaml cameras[].kind) -> "module:class"; the class has ``settings`` (its
# vts_hw.camera.kind_settings model) and from_config(cfg, clock=...), and implements
# vts_hw.camera.Camera and the roles it has. A new kind is one module in drivers/ and one line here.

CAMERA_KINDS = {
    "axis": "vts_hw.drivers.axis:AxisCamera",
    "mjpeg": "vts_hw.drivers.mjpeg:MjpegCamera",
    "replay": "vts_hw.drivers.replay:ReplayCamera",
}


def camera_class(kind: str, camera: str = "?"):
    """The class of a camera kind; ConfigError naming the camera and the kind when unknown."""
    if kind not in CAMERA_KINDS:
        raise ConfigError(f"camera {camera!r}: unknown kind {kind!r} (known: {', '.join(sorted(CAMERA_KINDS))})")
    module, cls = CAMERA_KINDS[kind].split(":")
    return getattr(importlib.import_module(module), cls)


def kind_has(cfg: CameraConfig, role: type) -> bool:
    """Whether the cameras of an entry's kind have ``role`` (one of vts_hw.camera's roles that a
    kind has whatever its options: Parameters, RunningTime, Setup), asked before anything is opened."""
    return issubclass(camera_class(cfg.kind, cfg.name), role)


def open_camera(cfg: CameraConfig, clock=None) -> Camera:
    """The camera a rig.yaml camera entry names, of its ``kind`` (default ``axis``); ``clock``
    is the host clock (a simulation on a virtual clock passes its own)."""
    return camera_class(cfg.kind, cfg.name).from_config(cfg, clock=clock or time.time)


def open_cameras(cfgs, clock=None) -> list[Camera]:
    """``open_camera`` for each entry (e.g. ``rig.cameras``); every kind is checked first, and
    the ones opened are closed again if a later one cannot be."""
    cfgs = list(cfgs)
    check_camera_kinds(cfgs)
    out: list[Camera] = []
    try:
        for cfg in cfgs:
            out.append(open_camera(cfg, clock=clock))
    except BaseException:
        for cam in out:
            cam.close()
        raise
    return out


def camera_settings(cfg: CameraConfig):
    """A camera entry's settings, checked by its kind's own model (ConfigError naming the camera,
    the kind and the key, exit 2)."""
    return camera_class(cfg.kind, cfg.name).settings.from_entry(cfg)


def check_camera_kinds(cameras) -> None:
    """Every camera entry names a known kind and fits its kind's settings (ConfigError, exit 2,
    before anything is touched)."""
    for cfg in cameras:
        camera_settings(cfg)
