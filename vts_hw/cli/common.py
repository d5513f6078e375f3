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


def rig_if_any(config_path) -> RigConfig | None:
    """The rig config when there is one (--config, $VTS_CONFIG, ./rig.yaml); None when none was
    named and none is found. A config named explicitly that cannot be read is its error."""
    from vts_hw.errors import VtsError
    try:
        return load_rig(config_path)
    except VtsError:
        if config_path is not None:
            raise
        return None


def store_qa_result(rig: RigConfig | None, result, data: dict | None = None, **kw):
    """Store a QA result the one way (vts_hw.store.results) in the rig's store (the per-user
    one without a rig config); ``data`` (the --json output) gets a ``stored`` key."""
    from vts_hw.store.results import store_result
    stored = store_result(rig.results.url if rig is not None else None, result,
                          rig=rig.rig if rig is not None else "",
                          config_digest=rig.digest if rig is not None else "", **kw)
    if data is not None:
        data["stored"] = {"run_id": stored.run_id, "unsaved_file": str(stored.unsaved) if stored.unsaved else None}
    return stored


def say_stored(stored, result, what: str, as_json: bool) -> int:
    """Say where a stored result went (stdout, or stderr under --json); a result the store did
    not take is one sentence on stderr naming the fallback file, and exit status 3."""
    if stored.ok:
        click.echo(f"stored: run {stored.run_id} ({result.procedure}) in the results store", err=as_json)
        return 0
    where = (f"its figures are above and in {stored.unsaved} (`vts qa import {stored.unsaved}` stores them "
             "later)" if stored.unsaved else "its figures are above only: no fallback file could be written")
    click.echo(f"vts: the {what} was NOT stored: {stored.error}; {where}", err=True)
    return 3
