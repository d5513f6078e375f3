"""`vts camera aim NAME`: aim and focus one camera, live or once (issue 24 §2).

Registered on the `camera` group (vts_hw/cli/camera.py) from a module of its own. It parses,
calls procedures/aim.py, prints and exits; the measuring and judging are vts_hw/vision/aim.py's.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import click

from vts_hw.cli.camera import camera
from vts_hw.cli.common import FiniteFloat, OutputFolder, with_rig

#: exit status: every item good (or not known); something to adjust (as a TOLERANCE)
EXIT_GOOD, EXIT_ADJUST = 0, 10
STYLE = {"good": "bold green", "adjust": "bold yellow", "unknown": "dim"}


def _reference(rig, name: str):
    """The drift baseline's marker positions (px) of camera ``name`` of this rig (another room's
    ``cam1`` is another camera, as the console reads it) from the rig's store; None when there is
    no store or no baseline (the aim is then judged by the picture's margins). A store that is not
    ours or cannot be read is refused (StoreError, exit 3) before the camera."""
    from vts_hw.cli.common import open_store
    from vts_hw.store.baselines import NoBaseline, load_baseline
    from vts_hw.store.errors import NoStore

    try:
        store = open_store(rig, "read")
    except NoStore:
        return None
    try:
        base = load_baseline(store, name, rig=rig.rig)
    except NoBaseline:
        return None
    finally:
        getattr(store, "close", lambda: None)()
    return base.points()


def _table(report, when: str):
    from rich.table import Table
    from rich.text import Text

    state = report.state
    title = Text.assemble((f"{report.camera}: ", "bold"), (state.upper(), STYLE[state]), f"  ({when})")
    t = Table(title=title, title_justify="left", expand=False)
    for col in ("item", "verdict", "figure", "goal", "what to do"):
        t.add_column(col, overflow="fold")
    for v in report.items:
        fig = "-" if v.value is None else f"{v.value:.1f} {v.unit}"
        t.add_row(v.label, Text(v.state.upper(), STYLE[v.state]), fig, v.goal, v.text)
    return t


def _write(out: Path | None, report) -> list[Path]:
    if out is None:
        return []
    from vts_hw.files import ensure_dir, write_atomic

    folder = ensure_dir(out, "aim output folder")
    png = write_atomic(folder / f"{report.camera}-aim.png", report.overlay_png())
    js = write_atomic(folder / f"{report.camera}-aim.json", json.dumps(report.to_dict(), indent=2) + "\n")
    return [png, js]


def _code(report) -> int:
    return EXIT_ADJUST if report.state == "adjust" else EXIT_GOOD


@camera.command("aim")
@click.argument("name")
@click.option("--once", is_flag=True, help="Check once, print the verdicts and exit (default: live until Ctrl-C).")
@click.option(
    "--out",
    type=OutputFolder("aim output folder"),
    default=None,
    help="Folder for NAME-aim.png (the picture with the markers, the SPECT FOV, the table and the "
    "gantry's opening drawn) and NAME-aim.json (the verdicts); live: rewritten each check.",
)
@click.option(
    "--interval",
    type=FiniteFloat(min=0.0, max=60.0),
    default=1.0,
    show_default=True,
    help="Live: seconds between checks.",
)
@click.option("--json", "as_json", is_flag=True, help="With --once: the verdicts as JSON on stdout.")
@with_rig
def aim(name: str, once: bool, out: str | None, interval: float, as_json: bool, rig) -> None:
    """Aim and focus camera NAME: each item with a verdict, GOOD or ADJUST (and how), or not known.

    \b
    Items: focus (the markers' edge width, px, and against their radius), marker size (px),
    LED on: markers over the background and the background; LED off: what the markers keep;
    aim (against the drift baseline's wall markers when the store has one: the turn back and
    the markers gone out of the picture; else every marker inside the picture's margins); with
    a VTS -> SPECT mapping and calibration in rig.yaml: the SPECT FOV's centre and the markers
    seen through the gantry's opening (without: "not known: no mapping"). Each check takes a
    picture with the LED on and one with it off; the LED is left on. Goals: rig.yaml's aim:
    section (docs/commission/aim-focus.md).

    \b
    Exit status: 0 every item good (items not known do not count); 10 something to adjust;
    2 bad input (unknown camera, bad config); 3 --out not writable; 4 the camera failed.
    Live (without --once): Ctrl-C stops, with the status of the last check.
    """
    from vts_hw.procedures.aim import check
    from vts_hw.room import Room

    cfg = rig.camera(name)  # an unknown camera: one sentence, exit 2, before anything
    cfg.password()
    out_dir = Path(out) if out else None
    reference = _reference(rig, name)
    with Room(rig) as room:
        cam = room.camera(name)
        if once or as_json:
            report = check(cam, rig, reference=reference)
            written = _write(out_dir, report)
            if as_json:
                click.echo(json.dumps(report.to_dict(), indent=2))
            else:
                _print_once(report, written)
            sys.exit(_code(report))
        sys.exit(_live(cam, rig, out_dir, interval, reference))


def _print_once(report, written) -> None:
    from rich.console import Console

    console = Console()
    console.print(_table(report, "once"))
    unknown = f"; not known: {', '.join(report.unknown)}" if report.unknown else ""
    click.echo(f"{report.camera}: {report.state.upper()}{unknown}")
    for p in written:
        click.echo(f"  wrote {p}")


def _live(cam, rig, out_dir, interval, reference) -> int:
    from rich.console import Console
    from rich.live import Live

    from vts_hw.procedures.aim import check

    console = Console()
    report, n = None, 0
    try:
        with Live(console=console, refresh_per_second=4, transient=False) as live:
            while True:
                report = check(cam, rig, reference=reference)
                n += 1
                _write(out_dir, report)
                live.update(_table(report, f"check {n}, {time.strftime('%H:%M:%S')}; Ctrl-C stops"))
                time.sleep(interval)
    except KeyboardInterrupt:
        pass
    if report is None:
        click.echo("vts: interrupted before the first check", err=True)
        return 130
    click.echo(f"{report.camera}: {report.state.upper()} (last of {n} checks)")
    return _code(report)
