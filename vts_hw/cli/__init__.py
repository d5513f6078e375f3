"""The ``vts`` command line. Each group lives in a module of its own."""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import signal
import sys
import threading

import click

from vts_hw import __version__
from vts_hw.errors import UsageError, VtsError

#: ctx.meta key of the global --store/--store-password-env (read by cli.common.store_target)
STORE_META = "vts.store"
#: ctx.meta key of the global --config (read by cli.common.config_option's callback)
CONFIG_META = "vts.config"

#: each command of `vts` and the modules of vts_hw.cli that define it and its subcommands,
#: imported when the command is asked for: `vts scan start` loads what a scan needs, not the
#: calibration's numerics (decision 0076; tests/house/test_cli_lazy.py checks the map is whole)
COMMANDS: dict[str, tuple[str, ...]] = {
    "calibrate": ("calibrate",),
    "camera": ("camera", "camera_aim", "camera_setup"),
    "commission": ("commission",),
    "console": ("console",),
    "demo": ("demo",),
    "discover": ("discover",),
    "motion": ("motion",),
    "qa": ("qa", "qa_steps"),
    "recording": ("recording",),
    "report": ("report",),
    "scan": ("scan",),
    "sim": ("sim",),
    "store": ("store",),
    "sync": ("sync",),
    "trigger": ("trigger", "trigger_flash"),
}


class _CommandsOnDemand(click.Group):
    """The top group: a command's modules are imported the first time it is looked up."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(set(COMMANDS) | set(self.commands))

    def get_command(self, ctx: click.Context, name: str) -> click.Command | None:
        # every module of the command, each time (an imported one is a dict lookup): a command
        # registered by one of its modules imported alone still gets the others' subcommands
        for module in COMMANDS.get(name, ()):
            importlib.import_module(f"{__name__}.{module}")
        return self.commands.get(name)


@click.group(cls=_CommandsOnDemand, context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="vts")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
@click.option(
    "--config",
    "config_path",
    metavar="FILE",
    type=click.Path(dir_okay=False),
    default=None,
    help="rig.yaml of the room, for a command that reads one (its own --config wins; default: "
    "$VTS_CONFIG, then ./rig.yaml). A command that reads no rig.yaml refuses it (exit 2).",
)
@click.option(
    "--store",
    "store_url",
    metavar="URL",
    default=None,
    help="Results store for every command: sqlite:////path/results.sqlite or "
    "postgresql://user@host[:port]/db (default: $VTS_STORE, then rig.yaml's store.url, then "
    "a per-user SQLite file). Never with a password in it (refused, exit 2).",
)
@click.option(
    "--store-password-env",
    metavar="NAME",
    default=None,
    help="Environment variable holding the store's database password (default: "
    "$VTS_STORE_PASSWORD_ENV with --store/$VTS_STORE, else rig.yaml's store.password_env; "
    "else libpq's PGPASSWORD or ~/.pgpass).",
)
@click.pass_context
def cli(
    ctx: click.Context, verbose: int, config_path: str | None, store_url: str | None, store_password_env: str | None
) -> None:
    """Control and QA of the stereo Visual Tracking System (VTS) used with SPECT.

    Every command that talks to the rig reads the room from --config FILE (the command's own,
    `vts qa daily --config FILE`, or `vts --config FILE qa daily`), else from the file named by
    $VTS_CONFIG, else ./rig.yaml. `vts sim up` brings up a simulated rig.
    Results go to the store named by --store, else $VTS_STORE, else rig.yaml's store.url.
    """
    if config_path is not None and ctx.invoked_subcommand is not None:
        _check_reads_a_rig(ctx.invoked_subcommand)
    ctx.meta[CONFIG_META] = config_path
    ctx.meta[STORE_META] = (store_url, store_password_env)
    if store_url or store_password_env or os.environ.get("VTS_STORE"):
        from vts_hw.store.target import resolve_target

        resolve_target(store_url, store_password_env)  # a bad URL (or one with a password): exit 2 now
    level = logging.WARNING - 10 * verbose
    logging.basicConfig(level=max(level, logging.DEBUG), format="%(levelname)s %(name)s: %(message)s")


def _register() -> None:
    """Every command registered (their help, the command tree); `vts` itself loads one."""
    for name in COMMANDS:
        cli.get_command(click.Context(cli), name)


def _check_reads_a_rig(name: str) -> None:
    """`vts --config FILE NAME ...` where no command of NAME reads a rig.yaml (`vts sim up`,
    `vts store ...`): UsageError (exit 2) rather than a --config silently not used."""
    top = cli.commands.get(name)
    if top is None:
        return
    if not any(p.name == "config_path" for _, c in command_tree(top, (name,)) for p in c.params):
        raise UsageError(f"vts --config: `vts {name}` reads no rig.yaml; leave --config out")


def command_tree(group: click.Command | None = None, path: tuple[str, ...] = ()):
    """Every group and command of `vts` (all registered), as (the names after ``vts``, the click
    command), groups before their commands, in name order (``group``: a command alone gives itself)."""
    if group is None:
        _register()
        group = cli
    yield path, group
    for name, c in sorted(getattr(group, "commands", {}).items()):
        if isinstance(c, click.Group):
            yield from command_tree(c, path + (name,))
        else:
            yield path + (name,), c


def _stop_on_sigterm(signum, frame):
    raise KeyboardInterrupt(f"stopped by {signal.Signals(signum).name}")


@contextlib.contextmanager
def _interruptible():
    """Ctrl-C (SIGINT) and SIGTERM (`timeout`, `kill`, a service manager) stop every command
    alike, as KeyboardInterrupt (exit 130, what was done kept and said interrupted, the
    hardware switched off: docs/security.md "Killed commands"), even when it was started with
    SIGINT ignored: a background job of a non-interactive shell is, and Python then installs no
    handler of its own (`kill -INT` would do nothing). A command may still install its own
    (uvicorn does while it serves); the handlers are as they were once the command ends."""
    if threading.current_thread() is not threading.main_thread():  # (signals are the main thread's)
        yield
        return
    old_int, old_term = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    if old_int is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    if old_term in (signal.SIG_DFL, None):
        signal.signal(signal.SIGTERM, _stop_on_sigterm)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old_int)
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)


def main(argv=None) -> None:
    """Entry point: user errors end in one sentence and a non-zero exit, never a traceback."""
    try:
        with _interruptible():
            cli.main(args=argv, prog_name="vts", standalone_mode=False)
    except VtsError as exc:
        click.echo(f"vts: {exc}", err=True)
        sys.exit(exc.exit_code)
    except click.exceptions.Abort:
        click.echo("vts: interrupted", err=True)
        sys.exit(130)
    except KeyboardInterrupt:
        click.echo("vts: interrupted", err=True)
        sys.exit(130)
    except click.ClickException as exc:
        exc.show()
        sys.exit(exc.exit_code)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
