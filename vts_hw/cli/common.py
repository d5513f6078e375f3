"""Options and helpers shared by the command modules."""

from __future__ import annotations

import functools
import json
import math

import click

from vts_hw.config import ENV_CONFIG, RigConfig, load_rig

config_option = click.option(
    "--config", "config_path", type=click.Path(dir_okay=False), envvar=ENV_CONFIG, default=None,
    help=f"rig.yaml of the room (default: ${ENV_CONFIG}, then ./rig.yaml).")

json_option = click.option("--json", "as_json", is_flag=True, help="Machine-readable JSON on stdout.")


class PositiveSeconds(click.ParamType):
    """A finite number greater than zero (refuses nan, inf, 0 and negatives with one sentence)."""

    name = "seconds"

    def __init__(self, what: str = "a duration in seconds"):
        self.what = what

    def convert(self, value, param, ctx):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            v = float(value)
        else:
            try:
                v = float(str(value).strip())
            except ValueError:
                self.fail(f"{value!r} is not a number (expected {self.what} greater than 0)", param, ctx)
        if not math.isfinite(v) or v <= 0:
            self.fail(f"{value!r} is not {self.what} greater than 0", param, ctx)
        return v


def with_rig(f):
    """Load the rig config named by --config and pass it as ``rig``."""
    @config_option
    @functools.wraps(f)
    def wrapper(*args, config_path=None, **kwargs):
        rig: RigConfig = load_rig(config_path)
        return f(*args, rig=rig, **kwargs)
    return wrapper


def echo_json(data) -> None:
    click.echo(json.dumps(data, indent=2, default=str))


def fmt_time(t: float | None) -> str:
    if t is None:
        return "-"
    import datetime as _dt
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-4] + "Z"
