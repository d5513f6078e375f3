"""`vts scan ...`: a scan session (trigger + recordings) with live status; see procedures/scan.py."""

from __future__ import annotations

import contextlib
import signal
import sys
import time
from pathlib import Path

import click
from rich.console import Console, Group
from rich.live import Live
from rich.markup import escape
from rich.table import Table

from vts_hw.cli import cli
from vts_hw.cli.common import OutputFolder, PositiveSeconds, echo_json, fmt_time, json_option, with_rig
from vts_hw.cli.live_view import live_line, live_table
from vts_hw.room import Room

REFRESH_S = 0.5  # the live table, about twice a second
PLAIN_EVERY_S = 2.0  # a status line this often when stderr is not a terminal


@cli.group()
def scan() -> None:
    """Start the VTS for a patient scan: cameras recording, trigger fired, live status."""


@scan.command()
@click.option(
    "-o",
    "--output",
    "out",
    type=OutputFolder("recording folder"),
    default=None,
    help="Session folder to create (default: ./scan-YYYYmmddTHHMMSSZ).",
)
@click.option(
    "--duration",
    type=PositiveSeconds(),
    default=None,
    help="Stop after S seconds from the trigger (default: until Ctrl-C).",
)
@click.option("--dry-run", is_flag=True, help="List the steps for this rig without touching it.")
@click.option(
    "--live/--no-live",
    default=True,
    show_default=True,
    help="Track the patient's markers live while recording (needs the rig's calibration): "
    "motion alerts per the rig's motion: section. With it on, a scan whose patient was not "
    "watched exits 4; --no-live for a scan without a patient (a sync check).",
)
@click.option(
    "--reference",
    "reference_s",
    type=PositiveSeconds(),
    default=10.0,
    show_default=True,
    help="Seconds of the first still period the live tracking learns as the reference.",
)
@json_option
@with_rig
def start(
    out: str | None, duration: float | None, dry_run: bool, live: bool, reference_s: float, as_json: bool, rig
) -> None:
    """Check cameras and trigger, record every camera, fire the trigger, show live status.

    Ctrl-C (or the duration) stops the square wave, closes the recordings, measures the
    camera clocks again and writes the manifest.

    \b
    The live view says at every moment whether the patient is watched: TRACKING, REFERENCE
    (learning), or NOT TRACKING with the reason (camera lost, too few markers, frames too
    late); NOT TRACKING for longer than motion.blind_alert_s (3 s) is an alert of its own.

    \b
    Exit status: 0 the session is complete and the patient was watched; 4 it is partial (a
    camera dropped, a trigger failed: the problems are listed) or failed, or the patient
    was not watched (no reference learned, or NOT TRACKING for more than
    motion.blind_max_share of the time: every frame is still recorded); 3 a file could not
    be written (disk full: the recording stops, every whole frame is kept); 2 bad input or a
    non-empty folder; 130 interrupted before the scan started.
    """
    from vts_hw.drivers.registry import check_camera_kinds
    from vts_hw.procedures.scan import default_folder

    folder = Path(out) if out else default_folder()
    check_camera_kinds(rig.cameras)
    with Room(rig) as room:  # the cameras and the trigger the session uses: closed with it, whatever happens
        _start(room, folder, duration, dry_run, live, reference_s, as_json)


def _start(
    room, folder: Path, duration: float | None, dry_run: bool, live: bool, reference_s: float, as_json: bool
) -> None:
    from vts_hw.procedures.scan import ScanSession

    rig = room.rig
    err = Console(stderr=True, highlight=False)
    cameras = [] if dry_run else room.cameras  # a dry run touches nothing
    motion = None if dry_run or not live else _live_motion(rig, reference_s, err)
    session = ScanSession(
        rig,
        folder,
        cameras,
        duration=duration,
        live=motion,
        trigger=lambda: room.trigger,
        on_step=lambda name, text: err.print(f"[green]ok[/]  {escape(name)}: {escape(text)}", soft_wrap=True),
    )
    if dry_run:
        steps = session.plan()
        if as_json:
            echo_json({"folder": str(folder), "steps": [s.__dict__ for s in steps]})
        else:
            click.echo(f"scan plan for rig {rig.rig} (dry run: nothing was touched)")
            for i, s in enumerate(steps, 1):
                click.echo(f"  {i}. {s.name}: {s.text}")
        return
    try:
        session.start()
    except KeyboardInterrupt:
        with _no_interrupts():
            session.stop("interrupted")
        click.echo(
            f"vts: interrupted before the scan started"
            f"{f'; what was recorded is in {folder}' if session.recorder else ''}",
            err=True,
        )
        sys.exit(130)
    if session.trigger.info.get("no_watchdog"):  # a trigger that cannot stop its wave by itself
        click.echo(f"vts: note: {session.trigger.info['no_watchdog']}", err=True)
    reason = "error"
    try:
        reason = _live(session, err)
    except KeyboardInterrupt:
        reason = "interrupted"
    finally:
        with _no_interrupts():
            err.print(f"stopping ({reason}) ...")
            manifest = session.stop(reason)
    if as_json:
        echo_json(manifest)
    else:
        _summary(folder, manifest)
    from vts_hw.procedures.scan_summary import verdict

    last, code = verdict(folder, manifest, session.recorder.write_failure if session.recorder is not None else None)
    if code:
        click.echo(f"vts: {last}", err=True)
        sys.exit(code)


# -- live status -------------------------------------------------------------------------------------


def _live_motion(rig, reference_s: float, err: Console):
    from vts_hw.procedures.scan_live import LiveMotion
    from vts_hw.tracking.live.estimator import LiveSettings

    def alert(text: str) -> None:  # one line and the bell
        if err.is_terminal:
            err.print(f"[bold red]ALERT[/] {escape(text)}", soft_wrap=True)
            err.bell()
        else:
            click.echo(f"ALERT {text}\a", err=True)

    return LiveMotion(
        rig,
        settings=LiveSettings(reference_s=reference_s),
        on_alert_text=alert,
        on_note=lambda text: click.echo(f"vts: {text}", err=True),
    )


def _views(session):
    """Read afresh at each refresh (by rich's own thread): the figures shown carry their age
    and status as of that moment, whatever the rest of the program is doing."""
    st = session.status()
    if session.live is None:
        return _table(st, session.folder)
    return Group(_table(st, session.folder), live_table(session.live.snapshot()))


def _live(session, console: Console) -> str:
    if console.is_terminal:
        with Live(
            console=console, get_renderable=lambda: _views(session), refresh_per_second=1 / REFRESH_S, transient=False
        ):
            return session.wait(None, REFRESH_S)
    last = [0.0]

    def plain(st):
        if time.monotonic() - last[0] >= PLAIN_EVERY_S:
            last[0] = time.monotonic()
            cams = ", ".join(f"{c.name} {c.frames} frames {c.fps:.1f} fps {c.dropped} dropped" for c in st.cameras)
            click.echo(f"[{st.elapsed_s:6.1f} s] {cams}; {_trigger_text(st.trigger)}", err=True)
            if session.live is not None:
                click.echo(f"[{st.elapsed_s:6.1f} s] {live_line(session.live.snapshot())}", err=True)

    return session.wait(plain, REFRESH_S)


def _table(st, folder) -> Table:
    of = f" of {st.duration_s:g} s" if st.duration_s else ""
    t = Table(
        title=f"scan {folder}  {st.elapsed_s:6.1f} s{of}  (Ctrl-C stops)",
        title_justify="left",
        caption=_trigger_text(st.trigger),
        caption_justify="left",
    )
    for col in ("camera", "frames", "fps", "dropped", "reconnects", "state"):
        t.add_column(col, justify="left" if col in ("camera", "state") else "right")
    for c in st.cameras:
        state = c.state if c.state in ("ok", "waiting") else f"[red]{c.state}[/]"
        t.add_row(c.name, str(c.frames), f"{c.fps:.1f}", str(c.dropped), str(c.reconnects), state)
    return t


def _trigger_text(tr: dict) -> str:
    if tr.get("backend") == "none":
        return "trigger: none (recording only)"
    parts = [f"trigger: {tr.get('backend')}"]
    if tr.get("fired"):
        parts.append(f"fired ({tr.get('mode')}) at {fmt_time(tr.get('fire_time'))}")
        if tr.get("edges") is not None:
            parts.append(f"{tr['edges']} rising edge(s)")
    elif tr.get("fired") is None:
        parts.append("fire state unknown")
    else:
        parts.append("not fired")
    if tr.get("errors"):
        parts.append(f"ERROR {tr['errors'][-1]}")
    return ", ".join(parts)


def _summary(folder: Path, m: dict) -> None:
    from vts_hw.procedures.scan_summary import summary_lines

    for line in summary_lines(folder, m):
        click.echo(line)


# -- signals -----------------------------------------------------------------------------------------


@contextlib.contextmanager
def _no_interrupts():
    """While the session is being closed, a second Ctrl-C must not cut the manifest short."""
    old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
    old_term = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
