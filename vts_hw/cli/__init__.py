"""The ``vts`` command line. Each group lives in a module of its own."""

from __future__ import annotations

import logging
import sys

import click

from vts_hw import __version__
from vts_hw.errors import VtsError


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="vts")
@click.option("-v", "--verbose", count=True, help="More log output (-vv for debug).")
def cli(verbose: int) -> None:
    """Control and QA of the stereo Visual Tracking System (VTS) used with SPECT.

    Every command that talks to the rig reads the room from --config FILE, else from the
    file named by $VTS_CONFIG, else ./rig.yaml. `vts sim up` brings up a simulated rig.
    """
    level = logging.WARNING - 10 * verbose
    logging.basicConfig(level=max(level, logging.DEBUG), format="%(levelname)s %(name)s: %(message)s")


def _register() -> None:
    from vts_hw.cli import (calibrate, camera, demo, motion, qa, qa_push, qa_steps, recording, report, scan,  # noqa: F401
                   sim, sync, trigger)


def main(argv=None) -> None:
    """Entry point: user errors end in one sentence and a non-zero exit, never a traceback."""
    _register()
    try:
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
