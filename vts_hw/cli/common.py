"""Options and helpers shared by the command modules."""

from __future__ import annotations

import functools
import json
import math
import sys
import time
from pathlib import Path

import click
from click.core import ParameterSource

from vts_hw.cli import CONFIG_META
from vts_hw.config import ENV_CONFIG, RigConfig, load_rig
from vts_hw.errors import UsageError
from vts_hw.files import check_folder, check_target


def _config_or_global(ctx: click.Context, param: click.Parameter, value):
    """A command's --config, else `vts --config` (before the command's name), else
    $VTS_CONFIG (None: ./rig.yaml)."""
    given = ctx.meta.get(CONFIG_META)
    if given is not None and ctx.get_parameter_source(param.name) is not ParameterSource.COMMANDLINE:
        return given
    return value


config_option = click.option(
    "--config",
    "config_path",
    type=click.Path(dir_okay=False),
    envvar=ENV_CONFIG,
    default=None,
    callback=_config_or_global,
    help=f"rig.yaml of the room (default: vts --config, ${ENV_CONFIG}, then ./rig.yaml).",
)

json_option = click.option("--json", "as_json", is_flag=True, help="Machine-readable JSON on stdout.")


class FiniteFloat(click.FloatRange):
    """The type of every float option: a finite number, optionally within ``min``/``max``
    (``min_open``/``max_open`` leave the end out). ``nan``, ``inf``, ``1e309`` and numbers out of
    range are refused as bad input: click's one sentence naming the option, exit 2.
    tests/integration/test_cli_numbers.py walks the command tree: no float option has another type."""

    name = "number"

    def __init__(
        self,
        min: float | None = None,
        max: float | None = None,
        min_open: bool = False,
        max_open: bool = False,
        what: str = "a number",
    ):
        super().__init__(min, max, min_open=min_open, max_open=max_open, clamp=False)
        self.what = what

    def _expected(self) -> str:
        """``a duration in seconds greater than 0``, ``a number from 0 to 3600``."""
        parts = []
        if self.min is not None:
            parts.append(f"{'greater than' if self.min_open else 'at least'} {self.min:g}")
        if self.max is not None:
            parts.append(f"{'less than' if self.max_open else 'at most'} {self.max:g}")
        if len(parts) == 2 and not self.min_open and not self.max_open:
            return f"{self.what} from {self.min:g} to {self.max:g}"
        return " ".join([self.what, " and ".join(parts)]).strip()

    def convert(self, value, param, ctx):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            v = float(value)
        else:
            try:
                v = float(str(value).strip())
            except ValueError:
                self.fail(f"{value!r} is not a number (expected {self._expected()})", param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number (expected {self._expected()})", param, ctx)
        if (self.min is not None and (v < self.min or (self.min_open and v == self.min))) or (
            self.max is not None and (v > self.max or (self.max_open and v == self.max))
        ):
            self.fail(f"{value!r} is out of range (expected {self._expected()})", param, ctx)
        return v


class OutputFile(click.Path):
    """The type of every option naming a file a command writes (``-o``, ``--plot``, ``--log``):
    a name that exists and is not a regular file (a device such as /dev/full, a FIFO, a socket,
    a folder) or is a symbolic link is refused when the command line is read, before a device
    is opened or a library loaded (vts_hw.files.check_target: one sentence, exit 3); the writer
    checks again when it writes. docs/decisions/0081-writers-replace-only-regular-files.md."""

    def __init__(self):
        super().__init__(dir_okay=False)

    def convert(self, value, param, ctx):
        check_target(value)
        return super().convert(value, param, ctx)


class OutputFolder(click.Path):
    """The type of every option naming a folder a command writes into (``recording -o DIR``,
    ``--export``, ``sim up --dir``): a file, device, FIFO or socket of that name, or a symbolic
    link, is refused when the command line is read (vts_hw.files.check_folder, exit 3)."""

    def __init__(self, what: str = "output folder"):
        super().__init__(file_okay=False)
        self.what = what

    def convert(self, value, param, ctx):
        check_folder(value, self.what)
        return super().convert(value, param, ctx)


def positive(what: str = "a number", max: float | None = None) -> FiniteFloat:
    """A finite number greater than 0 (and at most ``max``)."""
    return FiniteFloat(0, max, min_open=True, what=what)


class PositiveSeconds(FiniteFloat):
    """A finite duration greater than zero (refuses nan, inf, 0 and negatives with one sentence)."""

    name = "seconds"

    def __init__(self, what: str = "a duration in seconds", max: float | None = None):
        super().__init__(0, max, min_open=True, what=what)


def listmode_options(f):
    """The list-mode options of every command that takes a scan's SPECT list-mode (`vts sync
    analyze`, `vts motion analyze`), one rule for all (docs/decisions/0025-which-listmode.md):
    `--listmode FILE` (repeatable) and further files after the session, so the shell's
    expansion of `--listmode sim/spect/scan-*.vtslm` parses as it reads; the one whose
    acquisition belongs to the session is taken (`--clock-slack`). The command gets ``more``,
    ``listmode`` and ``clock_slack``; :func:`listmode_candidates` joins them."""
    f = click.option(
        "--clock-slack",
        type=FiniteFloat(0, 3600, what="seconds"),
        default=None,
        metavar="SECONDS",
        help="How far the SPECT's wall clock may be off the host's when matching a list-mode to "
        "the session (default: 10 s).",
    )(f)
    f = click.option(
        "--listmode",
        "listmode",
        type=click.Path(),
        multiple=True,
        metavar="FILE",
        help="The SPECT list-mode file of the same scan. Several files may follow it (a shell "
        "glob such as sim/spect/scan-*.vtslm): the one whose acquisition started on the "
        "session's start pulse (or overlaps it) is taken; none or two is refused (exit 3).",
    )(f)
    return click.argument("more", nargs=-1, type=click.Path(), metavar="[LISTMODE]...")(f)


def listmode_candidates(listmode, more) -> list[str]:
    """The list-mode files given to a command of :func:`listmode_options`, in order."""
    return [*listmode, *more]


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

    return _dt.datetime.fromtimestamp(t, _dt.UTC).strftime("%Y-%m-%d %H:%M:%S.%f")[:-4] + "Z"


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


def store_target(rig: RigConfig | None = None, url: str | None = None):
    """The store a command uses: ``url`` (a command's own --store), else the global
    ``vts --store``, else $VTS_STORE, else the rig config's ``store:``, else the per-user
    default (vts_hw.store.target). UsageError for a URL holding a password."""
    from vts_hw.cli import STORE_META
    from vts_hw.store.target import resolve_target

    ctx = click.get_current_context(silent=True)
    g_url, g_pw = ctx.meta.get(STORE_META, (None, None)) if ctx is not None else (None, None)
    return resolve_target(url or g_url, g_pw, rig)


def open_store(rig, mode: str = "create"):
    """The results store: `vts --store`, $VTS_STORE, the config's store section, else a per-user
    SQLite file (cli.common.store_target). ``mode`` (vts_hw.store.identity): ``read`` for a
    command that only reads (or updates) an existing store, ``create`` for one that writes
    results (a new file becomes a store); a database that is not a vts-hw store is never used."""
    from vts_hw.store import ResultsStore

    return ResultsStore(store_target(rig), mode=mode)


def store_qa_result(rig: RigConfig | None, result, data: dict | None = None, **kw):
    """Record a QA result the one way (vts_hw.store.recorder) in the rig's store (the per-user
    one without a rig config), judged by the rig's tolerance windows; ``data`` (the --json
    output) gets a ``stored`` key."""
    from vts_hw.store.recorder import record

    stored = record(
        store_target(rig),
        result,
        rig=rig.rig if rig is not None else "",
        config_digest=rig.digest if rig is not None else "",
        tolerances=rig.tolerances if rig is not None else None,
        **kw,
    )
    if data is not None:
        data["stored"] = {"run_id": stored.run_id, "unsaved_file": str(stored.unsaved) if stored.unsaved else None}
    return stored


def say_stored(stored, result, what: str, as_json: bool) -> int:
    """Say where a stored result went (stdout, or stderr under --json); a result the store did
    not take is one sentence on stderr naming the fallback file, and exit status 3."""
    if stored.ok:
        click.echo(f"stored: run {stored.run_id} ({result.procedure}) in the results store", err=as_json)
        return 0
    where = (
        f"its figures are above and in {stored.unsaved} (`vts qa import {stored.unsaved}` stores them later)"
        if stored.unsaved
        else "its figures are above only: no fallback file could be written"
    )
    click.echo(f"vts: the {what} was NOT stored: {stored.error}; {where}", err=True)
    return 3


def calibration_files(config_path, calibration, mapping):
    """--calibration/--mapping, else the rig config's calibration section (relative paths from
    the rig.yaml's folder), and the rig config (None without one).
    ConfigError when there is no stereo calibration at all."""
    from vts_hw.config import load_rig
    from vts_hw.errors import ConfigError, VtsError

    why = ""
    rig = None
    try:
        rig = load_rig(config_path)
    except VtsError as exc:
        if config_path is not None:  # named explicitly: its error is the answer
            raise
        why = f" (no rig config: {exc})"
    if calibration and mapping:
        return Path(calibration), Path(mapping), rig
    # (a relative path in rig.yaml is beside it: config.load_rig)
    cal = Path(calibration) if calibration else (rig.calibration.cameras if rig else None)
    mp = Path(mapping) if mapping else (rig.calibration.mapping if rig else None)
    if cal is None:
        raise ConfigError(f"no camera calibration: give --calibration FILE or set calibration.cameras in rig.yaml{why}")
    return cal, mp, rig


class FramesProgress:
    """Frame pairs processed, on stderr: a line per 10 % (and the last)."""

    def __init__(self):
        self.last = -1
        self.t0 = time.monotonic()

    def __call__(self, done: int, total: int) -> None:
        step = int(10 * done / max(total, 1))
        if step != self.last or done == total:
            self.last = step
            click.echo(
                f"processing the recording: {done}/{total} frame pairs ({time.monotonic() - self.t0:.1f} s)", err=True
            )


def finish_analysis(
    rig: RigConfig | None,
    result,
    data: dict,
    what: str,
    as_json: bool,
    *,
    notes: str = "",
    artifacts=(),
    lines=(),
    outputs=None,
) -> None:
    """The end of every `... analyze` command: store the result the one way, print it (the
    --json data, or its text and ``lines``), say where it was stored, and exit by its state
    (procedures.daily's codes: 0 OK, 10 TOLERANCE, 20 ACTION; 3 when the store did not take it).

    ``outputs`` (vts_hw.files.Outputs): the report, plot and export files the command tried to
    write. One that could not be written never costs the result: it is still stored (its note
    names the file) and printed, then one sentence names the file and the exit status is 3."""
    import sys

    from vts_hw.procedures.daily import EXIT_CODES
    from vts_hw.tolerance import State

    failed = bool(outputs is not None and outputs.failed)
    if failed:
        data["not_written"] = [str(e) for e in outputs.failed]
        notes = "; ".join(x for x in (notes, f"not written: {outputs.sentence()}") if x)
    stored = store_qa_result(rig, result, data, notes=notes, artifacts=list(artifacts))
    if as_json:
        echo_json(data)
    else:
        click.echo(result.results())
        for line in lines:
            click.echo(line)
    sys.stdout.flush()
    store_failed = say_stored(stored, result, what, as_json)
    if failed:
        kept = (
            f"the {what} is stored as run {stored.run_id} and its figures are above"
            if stored.ok
            else f"the {what}'s figures are above"
        )
        click.echo(f"vts: {outputs.sentence()}; {kept}", err=True)
        sys.exit(3)
    if store_failed:
        sys.exit(3)
    code = EXIT_CODES[State(data["summary"]["state"])]
    if code:
        sys.exit(code)


class NoTerminal(UsageError):
    """A step asks a person at the table and no one can answer (stdin is not a terminal)."""


def _terminal() -> bool:
    stdin = sys.stdin
    try:
        return stdin is not None and not stdin.closed and stdin.isatty()
    except (ValueError, OSError):
        return False


def ask_a_person(text: str, who: str, instead: str) -> str:
    """The operator's answer (Enter) to a request of ``who`` (a command: "commissioning", "the step
    test") at a terminal only: without one (stdin closed, /dev/null, a pipe) no one is there to do
    what it asks: NoTerminal (exit 2, one sentence saying ``instead``), never an "interrupted" that
    looks like Ctrl-C. Ctrl-C or Ctrl-D at the prompt is an interrupt (exit 130)."""
    if not _terminal():
        raise NoTerminal(f"{who} asks a person at the table ({text!r}) and stdin is not a terminal: {instead}")
    try:
        return click.prompt(text, default="", show_default=False, prompt_suffix=" ", err=True)
    except click.exceptions.Abort:
        raise KeyboardInterrupt("interrupted at the prompt") from None


def ask_password(text: str, instead: str) -> str:
    """A password typed twice at a terminal, not shown; without a terminal, NoTerminal saying
    ``instead`` (exit 2), never an "interrupted" that looks like Ctrl-C."""
    if not _terminal():
        raise NoTerminal(f"the password is asked for at a terminal and stdin is not one: {instead}")
    try:
        return click.prompt(text, hide_input=True, confirmation_prompt=True, err=True)
    except click.exceptions.Abort:
        raise KeyboardInterrupt("interrupted at the prompt") from None
