"""`vts trigger flash`: build the trigger box firmware, upload it through the bootloader, ask the box."""

from __future__ import annotations

import sys
from pathlib import Path

import click

from vts_hw.cli.common import FiniteFloat, echo_json, json_option
from vts_hw.cli.trigger import trigger

_PHASES = {
    "building": "building the firmware (make -C firmware)",
    "reading": "reading the firmware",
    "uploading": "uploading through the bootloader (avrdude)",
    "writing": "writing",
    "verifying": "verifying",
    "confirming": "asking the box its version (*IDN?)",
}


class _Progress:
    """Phases as lines on stderr; writing/verifying as a percentage (redrawn on a terminal)."""

    def __init__(self, quiet: bool):
        self.quiet = quiet
        self.tty = sys.stderr.isatty()
        self.phase: str | None = None
        self.shown = -1

    def __call__(self, phase: str, fraction: float) -> None:
        if self.quiet:
            return
        if phase != self.phase:
            if self.tty and self.phase in ("writing", "verifying"):
                click.echo("", err=True)
            self.phase, self.shown = phase, 0
            if phase not in ("writing", "verifying"):
                click.echo(f"{_PHASES.get(phase, phase)} ...", err=True)
        if phase in ("writing", "verifying"):
            pct = int(fraction * 100)
            if self.tty:
                click.echo(f"\r  {phase} {pct:3d} %", err=True, nl=False)
            elif pct // 50 > self.shown // 50 or (pct == 100 and self.shown < 100):
                click.echo(f"  {phase} {pct} %", err=True)
            self.shown = pct

    def end(self) -> None:
        if self.tty and self.phase in ("writing", "verifying"):
            click.echo("", err=True)


@trigger.command()
@click.option(
    "--port",
    default="/dev/ttyACM0",
    show_default=True,
    help="The box's USB serial port (an Uno: /dev/ttyACM0; a Nano with a CH340 or FTDI: /dev/ttyUSB0).",
)
@click.option(
    "--hex",
    "hex_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="The firmware (Intel HEX) to flash instead of building it; needed by an installed vts-hw, "
    "which has no firmware sources.",
)
@click.option(
    "--programmer",
    default="arduino",
    show_default=True,
    help="avrdude's programmer for the board's bootloader: arduino (Uno/Nano optiboot, STK500 v1), "
    "stk500v1, urclock, avr109 (32u4 boards), wiring (Mega 2560).",
)
@click.option(
    "--baud",
    type=click.IntRange(300, 2_000_000),
    default=115200,
    show_default=True,
    help="The bootloader's baud rate (115200: Uno optiboot; 57600: Nanos with the old bootloader).",
)
@click.option(
    "--attempts",
    type=click.IntRange(1, 10),
    default=3,
    show_default=True,
    help="How often avrdude tries to reach the arduino bootloader (about 5.6 s each when nothing answers).",
)
@click.option(
    "--confirm-timeout",
    type=FiniteFloat(1, 120, what="seconds"),
    default=15,
    show_default=True,
    help="Seconds to wait for the flashed box to answer *IDN?.",
)
@click.option(
    "--dry-run",
    is_flag=True,
    help="Build (or read --hex), check avrdude and the programmer, print the command; touch no port.",
)
@json_option
def flash(port, hex_path, programmer, baud, attempts, confirm_timeout, dry_run, as_json) -> None:
    """Build the trigger box firmware and upload it through the board's bootloader with avrdude
    (ATmega328P, -c arduino by default), verified page by page, then ask the box its version and
    check it is the one just written. avrdude's output goes to <hex>.avrdude.log beside the hex
    (shown only when it fails).

    Exit status: 0 flashed and confirmed; 2 bad input or setup (no avrdude, no sources without
    --hex, a file that is not trigger box firmware); 4 the device failed (port missing or busy,
    bootloader not answering, verify failed, wrong or no version after flashing); 130 interrupted."""
    from vts_hw.drivers import trigger_box_flash as tbf
    from vts_hw.drivers.avrdude import UploadFailed

    if dry_run:
        fw, cmd, version = tbf.dry_run(hex_path, programmer, baud, port, attempts)
        if as_json:
            echo_json(
                {
                    "hex": str(fw.hex),
                    "version": fw.version,
                    "bytes": fw.size,
                    "command": cmd,
                    "avrdude": version,
                    "dry_run": True,
                }
            )
            return
        click.echo(
            f"{fw.hex}: trigger box firmware {fw.version}, {fw.size} bytes ({'built now' if fw.built else 'given'})"
        )
        click.echo(f"avrdude {version} would run: {' '.join(cmd)}")
        click.echo("dry run: nothing was sent to any port")
        return
    progress = _Progress(as_json)
    try:
        done = tbf.flash(port, hex_path, programmer, baud, attempts, confirm_timeout, progress)
    except UploadFailed as e:
        progress.end()
        lines = [ln for ln in e.output.splitlines() if "error" in ln.lower() and "TIOCM" not in ln]
        for ln in lines[-5:]:
            click.echo(f"  {ln.strip()}", err=True)
        raise
    progress.end()
    up = done.upload
    if as_json:
        echo_json(
            {
                "port": port,
                "hex": str(done.firmware.hex),
                "version": done.firmware.version,
                "written": up.written,
                "verified": up.verified,
                "log": str(up.log),
                "avrdude": up.version,
                "identity": done.identity,
                "serial": done.serial,
                "confirm_s": round(done.confirm_s, 2),
            }
        )
        return
    click.echo(
        f"{port}: wrote {up.written} bytes of {done.firmware.hex.name} and verified {up.verified} "
        f"(avrdude {up.version}, log {up.log})"
    )
    click.echo(
        f"{port}: the box answers {done.identity!r} after {done.confirm_s:.1f} s: firmware "
        f"{done.firmware.version} confirmed, serial {done.serial}"
    )
