"""`vts sim ...`: bring the simulated rig up and down."""

from __future__ import annotations

from pathlib import Path

import click

from vts_hw.cli import cli
from vts_hw.cli.common import FiniteFloat, OutputFolder, positive

WARMUP_LINE = "cameras just switched on: their pictures drift for minutes as they warm (--warmup-drift)"
# the simulated cameras share one password (each camera's variable in sim.env holds it)
ANNOUNCE_LINE = (
    "cameras announced on loopback (mDNS and SSDP): after `source DIR/sim.env`, "
    "vts discover --interface 127.0.0.1 --password-env VTS_SIM_CAM1_PASSWORD finds and confirms them"
)


@cli.group()
def sim() -> None:
    """The simulated rig: Axis cameras on 127.0.0.1 that see one simulated room."""


@sim.command()
@click.option(
    "--cameras",
    "n_cameras",
    type=click.IntRange(1, 16),
    default=2,
    show_default=True,
    help="How many cameras: in pairs, the first pair over the patient's head, the second "
    "at the foot end, further pairs alternating (2: the reference rig's stereo pair).",
)
@click.option(
    "--gantry",
    is_flag=True,
    help="The SPECT heads in the room, turning step-and-shoot (3 deg every 3 s) for as long "
    "as the rig runs: they hide markers from some cameras at some angles.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the scene (poses, drift, noise).")
@click.option(
    "--vapix",
    type=click.Choice(["3", "2"]),
    default="3",
    show_default=True,
    help="Firmware generation the cameras answer as (2: as --model axis211).",
)
@click.option(
    "--model",
    type=click.Choice(["p1375", "axis211"]),
    default=None,
    help="The camera model and firmware: p1375 (AXIS P1375, current firmware; the default) or "
    "axis211 (AXIS 211 on firmware 4.47, VAPIX 2: the reference system's camera).",
)
@click.option(
    "--https",
    is_flag=True,
    help="HTTPS cameras with basic authentication and a self-signed certificate (written to "
    "--dir and named in rig.yaml as ca_cert).",
)
@click.option(
    "--rate",
    type=positive("a speed", max=1e6),
    default=1.0,
    show_default=True,
    help="Speed of the simulated clock, greater than 0 and at most 1e6 (e.g. 86400: a day per second, for drift).",
)
@click.option(
    "--trigger",
    type=click.Choice(["none", "triggerbox", "visa"]),
    default="none",
    show_default=True,
    help="A simulated trigger generator: our firmware in the emulator behind a pty, or a "
    "Keysight 33522B function generator on a TCP socket on 127.0.0.1 (reached through VISA "
    "as TCPIP::127.0.0.1::PORT::SOCKET; its settings last while the rig runs).",
)
@click.option(
    "--spect",
    is_flag=True,
    help="A simulated SPECT beside the rig (needs --trigger triggerbox and --dir): a source "
    "marker on the table moves every ~15 s once the box sends its SPECT start pulse, and "
    "each scan's list-mode is written to DIR/spect/ when the square wave stops (for "
    "`vts sync analyze`). With --patient: no source marker, the counts come from the "
    "patient's heart, moving with the body and a little with the breathing.",
)
@click.option(
    "--patient",
    is_flag=True,
    help="A simulated patient on the table from the start: a torso with a chest and an abdomen "
    "band of 4 marker spheres each, breathing, and sudden body moves after 15 s still. Its "
    "truth goes to DIR/truth/ (with --dir); with --spect the counts come from its heart.",
)
@click.option("--patient-seed", type=int, default=None, help="Seed of the patient (default: --seed).")
@click.option(
    "--patient-moves",
    type=click.IntRange(0, 50),
    default=None,
    help="How many sudden body moves over the plan [default: 2].",
)
@click.option(
    "--patient-minutes",
    type=FiniteFloat(0.1, 240.0, what="minutes"),
    default=None,
    help="How long the patient's plan lasts (moves are spread over it; after it the patient "
    "lies still and no longer breathes) [default: 10].",
)
@click.option("--no-breathing", is_flag=True, help="The patient does not breathe (body moves only).")
@click.option(
    "--qatrack",
    is_flag=True,
    help="A simulated QATrack+ beside the rig (127.0.0.1, one unit, the test lists of the daily QA "
    "and the step test), named in rig.yaml's qatrack: section (its token only in sim.env), so "
    "that `vts qa push` can be tried. It keeps what it is sent in memory, until the rig stops.",
)
@click.option(
    "--ahead",
    type=FiniteFloat(0, 3600, what="seconds"),
    default=0.0,
    metavar="SECONDS",
    help="Make SECONDS of every camera's frames ahead of time, before serving: they start "
    "playing at the first stream (the patient's plan moved to that instant), so a scan's "
    "streams are whole however busy this machine is. Rendering live, a busy machine makes "
    "them late (sent late, up to 10 s behind; then skipped).",
)
@click.option(
    "--warmup-drift",
    is_flag=True,
    help="Every camera starts as if just switched on (its uptime from 0) and its picture drifts as "
    "it warms: 2-4 px along a direction of its own, settling with a time constant of 8-15 min "
    "(seeded by --seed; decision 0072). For trying the commissioning's warm-up step (with "
    "--rate 60 a simulated minute passes each second).",
)
@click.option(
    "--announce",
    is_flag=True,
    help="The cameras announce themselves on loopback as Axis cameras do (mDNS and SSDP), so that "
    "`vts discover --interface 127.0.0.1` and `vts commission` find them.",
)
@click.option("--detach", is_flag=True, help="Run in the background (needs --dir).")
@click.option(
    "--dir",
    "folder",
    type=OutputFolder("simulated rig folder"),
    default=None,
    help="Where to write rig.yaml and sim.env (and sim.pid, sim.log when detached).",
)
def up(
    n_cameras: int,
    gantry: bool,
    seed: int,
    vapix: str,
    model: str | None,
    https: bool,
    rate: float,
    trigger: str,
    spect: bool,
    patient: bool,
    patient_seed: int | None,
    patient_moves: int | None,
    patient_minutes: float | None,
    no_breathing: bool,
    qatrack: bool,
    ahead: float,
    warmup_drift: bool,
    announce: bool,
    detach: bool,
    folder: str | None,
) -> None:
    """Run the simulated rig (foreground: Ctrl-C stops it).

    With --dir DIR it writes DIR/rig.yaml pointing at the simulated cameras and DIR/sim.env
    with the password variables that rig.yaml names: `source DIR/sim.env` and every `vts`
    command then talks to the simulated rig. A DIR that cannot be created or written ends the
    command before anything starts (exit 3); a detached rig that fails to start says why (the
    last line of DIR/sim.log).
    """
    fw = model or ("vapix3" if vapix == "3" else "vapix2")
    person = _patient(
        patient,
        seed if patient_seed is None else patient_seed,
        patient_moves,
        patient_minutes,
        no_breathing,
        patient_seed is not None,
    )
    if spect and (trigger != "triggerbox" or not folder):
        raise click.UsageError("--spect needs --trigger triggerbox and --dir DIR")
    if detach:
        if not folder:
            raise click.UsageError("--detach needs --dir DIR (where rig.yaml and sim.env go)")
        from vts_hw.sim_devices.rig_detached import start_detached  # starts a process: none of the scene here

        pid = start_detached(
            folder,
            n_cameras,
            seed,
            fw,
            rate,
            trigger=trigger,
            spect=spect,
            https=https,
            gantry=gantry,
            patient=person,
            qatrack=qatrack,
            ahead=ahead,
            warmup_drift=warmup_drift,
            announce=announce,
        )
        _describe(Path(folder))
        if qatrack:
            click.echo(f"simulated QATrack+: {_qatrack_url(Path(folder))} (rig.yaml's qatrack:; its token in sim.env)")
        if person is not None:
            click.echo(f"simulated patient: its truth in {Path(folder) / 'truth'}")
        if warmup_drift:
            click.echo(WARMUP_LINE)
        if announce:
            click.echo(ANNOUNCE_LINE)
        if ahead:
            click.echo(
                f"{ahead:g} s of frames made ahead of time: they start playing at the first stream "
                f"(what rendering cost: {Path(folder) / 'sim.log'})"
            )
        click.echo(f"simulated rig running in the background (pid {pid}); stop it with: vts sim down --dir {folder}")
        return

    def ready(rig):
        for name, srv in rig.servers.items():
            click.echo(f"{name}: {srv.url}")
        if rig.trigger_box is not None:
            click.echo(f"trigger box: {rig.trigger_box.port} (firmware in the emulator)")
        if rig.function_generator is not None:
            click.echo(f"function generator: {rig.function_generator.resource} (a simulated Keysight 33522B)")
        if rig.qatrack_site is not None:
            click.echo(
                f"simulated QATrack+: {rig.qatrack_site.url} (unit {rig.config().qatrack.unit!r}"
                + ("; rig.yaml's qatrack:, its token in sim.env)" if folder else ")")
            )
        if folder:
            _describe(Path(folder))
        if spect:
            click.echo(f"simulated SPECT: each scan's list-mode goes to {Path(folder) / 'spect'}")
        if rig.patient is not None:
            click.echo(_patient_line(rig.patient, folder))
        if warmup_drift:
            click.echo(WARMUP_LINE)
        if announce:
            click.echo(ANNOUNCE_LINE)
        click.echo("simulated rig up; Ctrl-C stops it")

    from vts_hw.sim_devices import rig as simrig  # imports the scene only when asked

    simrig.serve(
        folder,
        n_cameras,
        seed,
        fw,
        rate,
        on_ready=ready,
        trigger=trigger,
        spect=spect,
        https=https,
        gantry=gantry,
        patient=person,
        qatrack=qatrack,
        ahead=ahead,
        warmup_drift=warmup_drift,
        announce=announce,
    )
    click.echo("simulated rig stopped")


def _patient(on: bool, seed: int, moves: int | None, minutes: float | None, no_breathing: bool, seed_given: bool):
    """The patient options, or None; an option that needs --patient without it is a usage error."""
    from vts_hw.sim_devices.patient_rig import PatientOptions

    if not on:
        given = [
            name
            for name, v in (
                ("--patient-seed", seed_given),
                ("--patient-moves", moves is not None),
                ("--patient-minutes", minutes is not None),
                ("--no-breathing", no_breathing),
            )
            if v
        ]
        if given:
            raise click.UsageError(f"{', '.join(given)} needs --patient")
        return None
    options = PatientOptions(
        seed=seed,
        moves=2 if moves is None else moves,
        minutes=10.0 if minutes is None else minutes,
        breathing=not no_breathing,
    )
    try:
        options.check()
    except ValueError as e:
        raise click.UsageError(f"--patient-minutes/--patient-moves: {e}") from None
    return options


def _patient_line(patient, folder) -> str:
    moves = ", ".join(f"{m.t_start - patient.breathing.t0:.0f} s" for m in patient.motion.moves) or "none"
    where = f"; truth in {Path(folder) / 'truth'}" if folder else ""
    return (
        f"simulated patient: breathing {'on' if patient.breathing.enabled else 'off'}, body moves at "
        f"{moves} after the start, plan {patient.breathing.duration_s / 60:g} min{where}"
    )


def _qatrack_url(folder: Path) -> str:
    from vts_hw.config import load_rig

    rig = load_rig(folder / "rig.yaml")
    return rig.qatrack.url if rig.qatrack is not None else "?"


def _describe(folder: Path) -> None:
    click.echo(f"wrote {folder / 'rig.yaml'} and {folder / 'sim.env'}")
    click.echo(f"use it with: source {folder / 'sim.env'}")


@sim.command()
@click.option(
    "--dir",
    "folder",
    type=click.Path(file_okay=False),
    required=True,
    help="The folder given to `vts sim up --detach`.",
)
def down(folder: str) -> None:
    """Stop the simulated rig running in the background for DIR."""
    from vts_hw.sim_devices.rig_detached import stop_detached  # stops a process: none of the scene here

    if stop_detached(folder):
        click.echo(f"simulated rig in {folder} stopped")
    else:
        click.echo(f"no simulated rig was running in {folder}")
    from vts_hw.spect.listmode.failures import read_failure_records

    failed = read_failure_records(Path(folder) / "spect")  # what the simulated SPECT could not record
    for rec in failed:
        click.echo(f"{rec.describe()} ({rec.path})")
