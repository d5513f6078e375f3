"""Open the rig's trigger generator from the config's ``trigger`` section."""

from __future__ import annotations

from pathlib import Path

from vts_hw.config import TriggerConfig
from vts_hw.drivers.trigger import TriggerGenerator, TriggerLog
from vts_hw.errors import ConfigError


def open_trigger(cfg: TriggerConfig, log_path: str | Path | None = None, clock=None) -> TriggerGenerator:
    """The backend the config names, logging to ``log_path`` (trigger.csv) when given."""
    import time
    if cfg.backend == "none":
        raise ConfigError("the rig config has no trigger generator (trigger: backend: none)")
    log = TriggerLog(log_path, clock=clock or time.time)
    if cfg.backend == "triggerbox":
        from vts_hw.drivers.trigger_box import TriggerBox
        return TriggerBox(cfg.address, log=log)
    if cfg.backend == "visa":
        from vts_hw.drivers.function_generator import FunctionGenerator
        return FunctionGenerator(cfg.address, sim=cfg.simulated, log=log)
    if cfg.backend == "daqmx":
        from vts_hw.drivers.daqmx import DaqmxTrigger
        return DaqmxTrigger(cfg.address, lines=cfg.lines, fire_trigger=cfg.fire_trigger,
                            fire_pulse_ms=cfg.pulse_ms, log=log)
    raise ConfigError(f"unknown trigger backend {cfg.backend!r}")  # pragma: no cover (validated)


# -- cameras -----------------------------------------------------------------------------
# kind (rig.yaml cameras[].kind) -> "module:class"; the class has from_config(cfg, clock=...)
# and implements vts_hw.camera.Camera. A new kind is one module in drivers/ and one line here.
from vts_hw.camera import Camera  # noqa: E402  (the camera block keeps its imports with it)
from vts_hw.config import CameraConfig  # noqa: E402

CAMERA_KINDS = {
    "axis": "vts_hw.drivers.axis:AxisCamera",
    "mjpeg": "vts_hw.drivers.mjpeg:MjpegCamera",
    "replay": "vts_hw.drivers.replay:ReplayCamera",
}


def camera_class(kind: str, camera: str = "?"):
    """The class of a camera kind; ConfigError naming the camera and the kind when unknown."""
    import importlib
    if kind not in CAMERA_KINDS:
        raise ConfigError(f"camera {camera!r}: unknown kind {kind!r} (known: {', '.join(sorted(CAMERA_KINDS))})")
    module, cls = CAMERA_KINDS[kind].split(":")
    return getattr(importlib.import_module(module), cls)


def open_camera(cfg: CameraConfig, clock=None) -> Camera:
    """The camera a rig.yaml camera entry names, of its ``kind`` (default ``axis``); ``clock``
    is the host clock (a simulation on a virtual clock passes its own)."""
    import time
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


def check_camera_kinds(cameras) -> None:
    """Every camera entry names a known kind (ConfigError, exit 2, before anything is touched)."""
    for cfg in cameras:
        if cfg.kind not in CAMERA_KINDS:
            camera_class(cfg.kind, cfg.name)
