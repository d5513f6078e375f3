"""The base of every section of rig.yaml: unknown keys refused (a typo is an error naming the
key, never a setting silently ignored), the values frozen once read. vts_hw/config.py and the
sections kept in modules of their own (config_warmup.py, vision/aim_settings.py) build on it."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict

__all__ = ["Strict"]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
