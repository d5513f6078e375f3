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
