"""`vts sim ...`: bring the simulated rig up and down."""

from __future__ import annotations

from pathlib import Path

import click

from vts_hw.cli import cli


@cli.group()
def sim() -> None:
    """The simulated rig: Axis cameras on 127.0.0.1 that see one simulated room."""


@sim.command()
@click.option("--cameras", "n_cameras", type=click.IntRange(1, 16), default=2, show_default=True,
              help="How many cameras: in pairs, the first pair over the patient's head, the second "
                   "at the foot end, further pairs alternating (2: the reference rig's stereo pair).")
@click.option("--gantry", is_flag=True,
              help="The SPECT heads in the room, turning step-and-shoot (3 deg every 3 s) for as long "
                   "as the rig runs: they hide markers from some cameras at some angles.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the scene (poses, drift, noise).")
@click.option("--vapix", type=click.Choice(["3", "2"]), default="3", show_default=True,
              help="Firmware generation the cameras answer as (2: as --model axis211).")
@click.option("--model", type=click.Choice(["p1375", "axis211"]), default=None,
              help="The camera model and firmware: p1375 (AXIS P1375, current firmware; the default) or "
                   "axis211 (AXIS 211 on firmware 4.47, VAPIX 2: the reference system's camera).")
@click.option("--https", is_flag=True,
              help="HTTPS cameras with basic authentication and a self-signed certificate (written to "
                   "--dir and named in rig.yaml as ca_cert).")
@click.option("--rate", type=float, default=1.0, show_default=True,
              help="Speed of the simulated clock (e.g. 86400: a day per second, for drift).")
@click.option("--trigger", type=click.Choice(["none", "triggerbox", "visa"]), default="none", show_default=True,
              help="A simulated trigger generator: our firmware in the emulator behind a pty, or a "
                   "Keysight 33522B function generator on a TCP socket on 127.0.0.1 (reached through VISA "
                   "as TCPIP::127.0.0.1::PORT::SOCKET; its settings last while the rig runs).")
@click.option("--spect", is_flag=True,
              help="A simulated SPECT beside the rig (needs --trigger triggerbox and --dir): a source "
                   "marker on the table moves every ~15 s once the box sends its SPECT start pulse, and "
                   "each scan's list-mode is written to DIR/spect/ when the square wave stops (for "
                   "`vts sync analyze`).")
@click.option("--detach", is_flag=True, help="Run in the background (needs --dir).")
@click.option("--dir", "folder", type=click.Path(file_okay=False), default=None,
              help="Where to write rig.yaml and sim.env (and sim.pid, sim.log when detached).")
def up(n_cameras: int, gantry: bool, seed: int, vapix: str, model: str | None, https: bool, rate: float,
       trigger: str, spect: bool, detach: bool, folder: str | None) -> None:
    """Run the simulated rig (foreground: Ctrl-C stops it).

    With --dir DIR it writes DIR/rig.yaml pointing at the simulated cameras and DIR/sim.env
    with the password variables that rig.yaml names: `source DIR/sim.env` and every `vts`
    command then talks to the simulated rig. A DIR that cannot be created or written ends the
    command before anything starts (exit 3); a detached rig that fails to start says why (the
    last line of DIR/sim.log).
    """
    from vts_hw.sim_devices import rig as simrig  # imports the scene only when asked

    fw = model or ("vapix3" if vapix == "3" else "vapix2")
    if spect and (trigger != "triggerbox" or not folder):
        raise click.UsageError("--spect needs --trigger triggerbox and --dir DIR")
    if detach:
        if not folder:
            raise click.UsageError("--detach needs --dir DIR (where rig.yaml and sim.env go)")
        pid = simrig.start_detached(folder, n_cameras, seed, fw, rate, trigger=trigger, spect=spect, https=https,
                                    gantry=gantry)
        _describe(Path(folder))
        click.echo(f"simulated rig running in the background (pid {pid}); stop it with: vts sim down --dir {folder}")
        return

    def ready(rig):
        for name, srv in rig.servers.items():
            click.echo(f"{name}: {srv.url}")
        if rig.trigger_box is not None:
            click.echo(f"trigger box: {rig.trigger_box.port} (firmware in the emulator)")
        if rig.function_generator is not None:
            click.echo(f"function generator: {rig.function_generator.resource} (a simulated Keysight 33522B)")
        if folder:
            _describe(Path(folder))
        if spect:
            click.echo(f"simulated SPECT: each scan's list-mode goes to {Path(folder) / 'spect'}")
        click.echo("simulated rig up; Ctrl-C stops it")

    simrig.serve(folder, n_cameras, seed, fw, rate, on_ready=ready, trigger=trigger, spect=spect, https=https,
                 gantry=gantry)
    click.echo("simulated rig stopped")


def _describe(folder: Path) -> None:
    click.echo(f"wrote {folder / 'rig.yaml'} and {folder / 'sim.env'}")
    click.echo(f"use it with: source {folder / 'sim.env'}")


@sim.command()
@click.option("--dir", "folder", type=click.Path(file_okay=False), required=True,
              help="The folder given to `vts sim up --detach`.")
def down(folder: str) -> None:
    """Stop the simulated rig running in the background for DIR."""
    from vts_hw.sim_devices import rig as simrig

    if simrig.stop_detached(folder):
        click.echo(f"simulated rig in {folder} stopped")
    else:
        click.echo(f"no simulated rig was running in {folder}")
    from vts_hw.spect.listmode.failures import read_failure_records
    failed = read_failure_records(Path(folder) / "spect")     # what the simulated SPECT could not record
    for rec in failed:
        click.echo(f"{rec.describe()} ({rec.path})")
