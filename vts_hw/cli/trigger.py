"""`vts trigger ...`: the square wave and the start pulses, as the device confirms them."""

from __future__ import annotations

import contextlib

import click

from vts_hw.cli import cli
from vts_hw.cli.common import OutputFile, echo_json, json_option, with_rig
from vts_hw.errors import DeviceError
from vts_hw.room import Room

log_option = click.option(
    "--log",
    "log_path",
    type=OutputFile(),
    default="trigger.csv",
    show_default=True,
    help="trigger.csv to append every command, reply and edge to.",
)


@cli.group()
def trigger() -> None:
    """The trigger and sync generator of the rig's `trigger:` section (trigger box, VISA
    function generator or NI-DAQmx). Every command prints what the device confirms."""


def _show(st, as_json: bool) -> None:
    if as_json:
        echo_json(st.__dict__)
        return
    parts = [f"{st.device}: output {'ON' if st.running else 'OFF'}"]
    if st.frequency_hz is not None:
        parts.append(f"{st.frequency_hz:g} Hz")
    if st.duty is not None:
        parts.append(f"duty {st.duty * 100:g} %")
    if st.high_v is not None and st.low_v is not None:
        parts.append(f"{st.low_v:g}..{st.high_v:g} V")
    if st.edges is not None:
        parts.append(f"{st.edges} rising edge(s)")
    click.echo(", ".join(parts))
    for note in st.notes:
        click.echo(f"  {note}")
    for e in st.errors:
        click.echo(f"  device error: {e}")


def _no_errors(st) -> None:
    """A device that reports errors in its queue failed at something: exit 4 in one sentence (the
    status printed above lists them), never a status that looks fine."""
    if st.errors:
        raise DeviceError(
            f"{st.device} reports {len(st.errors)} error(s) in its queue (read off it now): {'; '.join(st.errors)}"
        )


@contextlib.contextmanager
def _session(rig, log_path):
    """The room's trigger for one command (closed with the room); a trigger.csv that stopped
    taking lines is said at the end (exit 3): the device did what was printed, the log file is short."""
    with Room(rig, trigger_log=log_path) as room:
        gen = room.trigger
        yield gen
    if gen.log.write_error is not None:
        raise gen.log.write_error


def _configure(gen, t) -> None:
    """Frequency and duty from the config, and the levels where the device has them. The wave
    outlives this command by design, so a device's watchdog is switched off for it (the trigger
    box's status says so; `vts trigger stop` ends the wave)."""
    from vts_hw.drivers.trigger import LEVELS, WATCHDOG

    if WATCHDOG in gen.capabilities:
        gen.watchdog_s = 0
    levels = (t.high_v, t.low_v) if LEVELS in gen.capabilities else (None, None)
    gen.configure(t.frequency_hz, t.duty, *levels)


@trigger.command()
@log_option
@json_option
@with_rig
def start(log_path, as_json, rig) -> None:
    """Configure the square wave from the config (frequency, duty, levels) and start it."""
    with _session(rig, log_path) as gen:
        _configure(gen, rig.trigger)
        _show(st := gen.start(), as_json)
    _no_errors(st)


@trigger.command()
@log_option
@json_option
@with_rig
def stop(log_path, as_json, rig) -> None:
    """Stop the square wave (on a whole period where the device can)."""
    with _session(rig, log_path) as gen:
        _show(st := gen.stop(), as_json)
    _no_errors(st)


@trigger.command()
@log_option
@json_option
@with_rig
def status(log_path, as_json, rig) -> None:
    """What the device says it is doing."""
    with _session(rig, log_path) as gen:
        _show(st := gen.status(), as_json)
    _no_errors(st)


@trigger.command()
@click.argument("channel", type=click.IntRange(1, 2))
@click.argument("ms", type=click.IntRange(1, 10000), required=False)
@log_option
@with_rig
def pulse(channel, ms, log_path, rig) -> None:
    """A start pulse (contact closure) on CHANNEL: 1 = VTS start, 2 = SPECT start."""
    ms = ms or rig.trigger.pulse_ms
    with _session(rig, log_path) as gen:
        gen.pulse(channel, ms)
    click.echo(
        f"{gen.name}: start pulse on channel {channel} for {ms} ms sent: the device accepted it (a pulse "
        "is not read back)"
    )


@trigger.command()
@log_option
@json_option
@with_rig
def fire(log_path, as_json, rig) -> None:
    """Configure, then start the square wave and both start pulses together, and say what went
    out as the device confirms it. A backend without start pulses (the function generator) says
    so and changes nothing."""
    import inspect

    from vts_hw.drivers.settings import Setting
    from vts_hw.drivers.trigger import CHANNELS, FIRE, LEVELS

    t = rig.trigger
    with _session(rig, log_path) as gen:
        if FIRE in gen.capabilities:  # else fire() below refuses, in the driver's words, before anything is sent
            _configure(gen, t)
        kw = {"pulse_ms": t.pulse_ms} if "pulse_ms" in inspect.signature(gen.fire).parameters else {}
        st = gen.fire(**kw)
        width = getattr(gen, "fire_pulse_ms", None)
        # a device setting (the trigger box: PULSE:WIDTH?) is read back from the device
        confirmed = isinstance(getattr(type(gen), "fire_pulse_ms", None), Setting)
        fixed_levels = LEVELS not in gen.capabilities
    pulses = {"channels": {str(c): what for c, what in CHANNELS.items()}, "width_ms": width}
    if as_json:
        echo_json({**st.__dict__, "start_pulses": pulses})
        _no_errors(st)
        return
    _show(st, False)
    if fixed_levels:
        click.echo("  square wave at the device's fixed TTL levels")
    both = " and ".join(f"channel {c} ({what})" for c, what in CHANNELS.items())
    how = f"the device confirms {width} ms" if confirmed else f"{width} ms timed by the host"
    click.echo(
        f"start pulses: {both}, {width} ms each, sent with the square wave's first rising edge "
        f"({st.device} accepted the fire; {how})"
    )
    _no_errors(st)
