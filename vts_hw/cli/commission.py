"""`vts commission`: the guided commissioning of a room (issue 24 §3). It parses, calls
procedures/commission.py with the store's ledger (vts_hw/store/commission.py), prints, writes the
report through the report door and exits."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import click

from vts_hw.catalog import COMMISSION_STEPS
from vts_hw.cli import cli
from vts_hw.cli.common import OutputFolder, PositiveSeconds, ask_a_person, config_option, positive
from vts_hw.errors import UsageError
from vts_hw.files import check_folder
from vts_hw.procedures.commission import NAMES as STEP_NAMES
from vts_hw.rig_file import check_rewritable


def _ask(text: str):
    return ask_a_person(
        text,
        "commissioning",
        "run it at a terminal (`vts commission --resume`), or for the drift baseline give --room-clear",
    )


def _pattern(ctx, param, value: str) -> tuple[int, int]:
    from vts_hw.cli.calibrate import _pattern as parse

    return parse(ctx, param, value)


@cli.command()
@config_option
@click.option("--resume", is_flag=True, help="Continue the room's current commissioning after its last good step.")
@click.option(
    "--from",
    "from_step",
    type=click.Choice(STEP_NAMES),
    default=None,
    help="Run again from this step (and every later one) in the current commissioning.",
)
@click.option(
    "--skip",
    "skips",
    type=click.Choice(STEP_NAMES),
    multiple=True,
    help="Leave this step out (repeatable); needs --why. The report says so.",
)
@click.option("--why", default=None, help="Why the --skip steps are left out (in the report).")
@click.option(
    "--sign-off",
    "sign_off",
    metavar="NAME",
    default=None,
    help="Who signs the commissioning off (recorded with the time in the report).",
)
@click.option(
    "-o",
    "--out",
    "out_dir",
    type=OutputFolder("commissioning folder"),
    default=None,
    help="Folder for what the steps write (calibration, mapping, step test, aim pictures, the report) "
    "[default: commission-RIG].",
)
@click.option(
    "--checkerboards",
    multiple=True,
    type=click.Path(),
    help="Calibration: checkerboard images of the "
    "cameras (folders or files, as `vts calibrate cameras` takes them; repeatable).",
)
@click.option("--pattern", default="9x6", show_default=True, callback=_pattern, help="Inner corners, COLSxROWS.")
@click.option(
    "--square",
    "square_mm",
    type=positive("a length in mm"),
    default=30.0,
    show_default=True,
    help="Side of a checkerboard square, mm.",
)
@click.option(
    "--phantom-volume",
    type=click.Path(dir_okay=False),
    default=None,
    help="Mapping: the SPECT's reconstruction of the 7-sphere phantom as the cameras see it now.",
)
@click.option(
    "--step-volumes",
    type=click.Path(file_okay=False),
    default=None,
    help="Step test: the folder of the SPECT's reconstructions of the positions.",
)
@click.option(
    "--vertical", type=click.IntRange(0, 50), default=10, show_default=True, help="Step test: vertical steps."
)
@click.option("--axial", type=click.IntRange(0, 50), default=10, show_default=True, help="Step test: axial steps.")
@click.option(
    "--sync-session",
    type=click.Path(file_okay=False),
    default=None,
    help="Sync check: a scan session recorded with a moving source marker (`vts scan start`).",
)
@click.option("--listmode", multiple=True, type=click.Path(dir_okay=False), help="Sync check: its SPECT list-mode.")
@click.option(
    "--frames",
    type=click.IntRange(1, 100),
    default=10,
    show_default=True,
    help="Snapshots per camera for the mapping and each step-test position.",
)
@click.option(
    "--listen",
    "listen_s",
    type=PositiveSeconds(
        max=120,
    ),
    default=3.0,
    show_default=True,
    help="Seconds to listen for cameras announcing themselves (mDNS, SSDP).",
)
@click.option(
    "--interface",
    "interfaces",
    multiple=True,
    metavar="ADDRESS",
    help="Listen from this IPv4 address of this host only (repeatable).",
)
@click.option(
    "--no-wait",
    is_flag=True,
    help="Warm-up: do not wait for the pictures to settle. A camera started less than its warmup_min ago "
    "stops the step at once (no sample taken), saying how long to wait at least; else the rate is "
    "measured over one window (warmup.samples x warmup.interval_s, 5 min by default: a rate takes "
    "that long to measure) and a camera not settled stops the step, saying how long to wait.",
)
@click.option(
    "--room-clear",
    is_flag=True,
    help="Drift baseline: the table and the room are clear and the LED rings on (do not ask; for a run "
    "without a terminal). The step test always needs a person at a terminal.",
)
@click.option("--operator", default=lambda: os.environ.get("USER", ""), help="Who runs it.")
def commission(
    config_path,
    resume,
    from_step,
    skips,
    why,
    sign_off,
    out_dir,
    checkerboards,
    pattern,
    square_mm,
    phantom_volume,
    step_volumes,
    vertical,
    axial,
    sync_session,
    listmode,
    frames,
    listen_s,
    interfaces,
    no_wait,
    room_clear,
    operator,
) -> None:
    """Commission a room, step by step, each step a stored run; resumable where it stopped.

    \b
    Steps: 1 cameras (discover, set up, lock into rig.yaml) · 2 trigger (the box's version;
    flashing is `vts trigger flash`) · 3 aim and focus · 4 warm-up (the wall markers' rate
    settled, rig.yaml's warmup: and warmup_rate_px_min) · 5 calibration
    (--checkerboards) · 6 VTS -> SPECT mapping (--phantom-volume); each, once passed, is
    pointed at in rig.yaml (calibration.cameras, calibration.mapping; the previous text in
    rig.yaml.bak) · 7 step test
    (--step-volumes; the table moved when asked) · 8 sync check (--sync-session,
    --listmode) · 9 drift baseline. A step that needs what is not given stops and says what.
    At the end: the commissioning report (OUT/commissioning.html and .pdf), stored as a run;
    the rooms page shows "commissioned on DATE".

    \b
    Exit status: 0 commissioned (every figure OK); 10 commissioned with a figure in TOLERANCE
    or a step skipped, or stopped at a camera to adjust (aim) or still warming up (--no-wait);
    20 stopped at a figure in ACTION, or the report of a commissioning with a step that has not
    passed; 4 a device failed; 2 bad input, an input a step needs is missing, or a question
    for a person with no terminal to ask it at; 3 the store or a file could not be written;
    130 interrupted (Ctrl-C, SIGTERM). After a stop, fix what it says and run again with
    --resume (or --from STEP). Each step is recorded as it starts: a commissioning killed in
    a step is found by the next start and said; the newest attempt of each step decides.
    """
    from vts_hw.cli.common import store_target
    from vts_hw.config import load_rig
    from vts_hw.procedures import commission as proc
    from vts_hw.procedures.commission_sequence import failure_reason, run_sequence  # the steps: numpy, scipy, cv2
    from vts_hw.procedures.daily import EXIT_CODES
    from vts_hw.room import Room
    from vts_hw.store.commission import Ledger, load_state

    if bool(skips) != bool(why):
        raise UsageError("--skip STEP needs --why TEXT (and --why a --skip): the report says why a step was left out")
    if resume and from_step:
        raise UsageError("give --resume or --from STEP, not both")
    rig = load_rig(config_path)
    source = getattr(rig, "_source", None)
    out = (
        Path(out_dir)
        if out_dir
        else Path(source).parent / f"commission-{rig.rig}"
        if source
        else Path(f"commission-{rig.rig}")
    )
    check_folder(out, "commissioning folder")  # the default too, before any step (decision 0081)
    if source:
        check_rewritable(source)  # the steps write their results into rig.yaml
    inputs = proc.Inputs(
        out=out,
        checkerboards=tuple(checkerboards),
        pattern=pattern,
        square_mm=square_mm,
        phantom_volume=phantom_volume,
        step_volumes=step_volumes,
        vertical=vertical,
        axial=axial,
        sync_session=sync_session,
        listmode=tuple(listmode),
        frames=frames,
        listen_s=listen_s,
        interfaces=tuple(interfaces),
        wait=not no_wait,
        room_clear=room_clear,
    )
    say = lambda m: click.echo(m, err=True)  # noqa: E731
    with Room(rig, store=store_target(rig)) as room:  # its store and devices closed with it, however it ends
        store = room.store  # opened first, closed last (after the cameras and the trigger)
        state = load_state(store, rig.rig)
        for s in state.unfinished():  # killed, interrupted or failed in it: the next start says so
            say(f"commissioning {state.cid}: its {s.label} step of {_when(s.started)} did not finish ({s.why()})")
        carry = resume or from_step is not None
        if carry and state.cid is None:
            say("no commissioning of this room in the store yet: a new one begins")
        before = None if carry else state.standing(store)  # None: no commissioning yet
        if before is not None and not before.complete:
            say(f"a new commissioning begins (commissioning {state.cid} stopped unfinished: --resume continues it)")
        todo = proc.plan(from_step, state.done if carry else {})
        ledger = Ledger(store, rig, cid=state.cid if carry else None, operator=operator)
        ctx = proc.Context(
            rig,
            inputs,
            say=say,
            ask=_ask,
            reload=lambda: load_rig(config_path),
            camera=lambda cfg: room.camera(cfg.name),
            trigger=lambda: room.trigger,
        )
        try:
            end = run_sequence(ctx, todo, ledger, {s: why for s in skips})
        except KeyboardInterrupt as exc:
            say(
                f"commissioning {ledger.cid or '(new)'} {failure_reason(exc)}: the step under way is recorded as "
                "aborted; `vts commission --resume` runs it again"
            )
            raise
        o = end.stopped
        if o is not None:  # (not done)
            click.echo(f"commissioning stopped at {proc.step(o.step).label}: {o.advice or o.state}")
            sys.exit(EXIT_CODES[o.state] or 10)
        report, standing = _report(store, rig, ledger, sign_off, out)
    click.echo(
        f"commissioning {report.cid} of {rig.rig}: {_verdict(standing)}"
        + ("" if report.signed_by else " (not signed off)")
    )
    sys.exit(EXIT_CODES[report.state])


def _when(t: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M", time.localtime(t))


def _verdict(standing) -> str:
    """The state in words with what was skipped and what has not passed (vts_hw.store.commission.Standing)."""
    labels = dict(COMMISSION_STEPS)
    word = standing.word if standing.complete else "incomplete, not commissioned"
    parts = []
    if standing.not_passed:
        parts.append("not passed: " + ", ".join(labels[n] for n in standing.not_passed))
    if standing.skipped:
        parts.append(
            f"{len(standing.skipped)} of {len(labels)} steps skipped: " + ", ".join(labels[n] for n in standing.skipped)
        )
    return word + (f" ({'; '.join(parts)})" if parts else "")


def _report(store, rig, ledger, sign_off, out):
    from vts_hw.procedures.commission import STEPS
    from vts_hw.report.commission import build_commission_report
    from vts_hw.report.renderers import write_report
    from vts_hw.store.commission import load_state

    state = load_state(store, rig.rig)
    ledger.cid = state.cid
    report = build_commission_report(
        store,
        state,
        [(s.name, s.label) for s in STEPS],
        signed_by=sign_off or "",
        signed_at=time.time() if sign_off else None,
    )
    files = [write_report("commission", out / f"commissioning{suffix}", report) for suffix in (".html", ".pdf")]
    notes = (f"signed off by {sign_off}" if sign_off else "not signed off") + "".join(
        f"; skipped {label}: {why}" for label, why in report.skipped
    )
    run_id = ledger.finish_report(report.state, state.steps, signed_by=sign_off or "", artifacts=files, notes=notes)
    for f in files:
        click.echo(f"report: {f}")
    click.echo(f"stored: run {run_id} (commissioning)")
    return report, load_state(store, rig.rig).standing(store)
