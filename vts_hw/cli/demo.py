"""`vts demo`: the main job on a simulated rig, end to end."""

from __future__ import annotations

from pathlib import Path

import click

from vts_hw.cli import cli
from vts_hw.cli.common import FiniteFloat, OutputFolder, PositiveSeconds


@cli.command()
@click.option(
    "-o",
    "--output",
    "out",
    type=OutputFolder("demo folder"),
    default="demo-out",
    show_default=True,
    help="Folder for what the demo writes (its results store is made afresh).",
)
@click.option("--days", type=click.IntRange(1, 730), default=60, show_default=True, help="Simulated days of daily QA.")
@click.option(
    "--seconds", type=PositiveSeconds(max=600), default=3.0, show_default=True, help="Length of the camera recording."
)
@click.option(
    "--frames", type=click.IntRange(1, 50), default=5, show_default=True, help="LED-on snapshots per camera and day."
)
@click.option(
    "--scan-seconds",
    type=FiniteFloat(0, 600, what="seconds"),
    default=20.0,
    show_default=True,
    help="Length of the simulated scan (0: no scan).",
)
@click.option(
    "--patient-seconds",
    type=FiniteFloat(0, 600, what="seconds"),
    default=30.0,
    show_default=True,
    help="Length of the simulated patient scan (0: none; else at least 24).",
)
def demo(out: str, days: int, seconds: float, frames: int, scan_seconds: float, patient_seconds: float) -> None:
    """The simulated rig, end to end, in six numbered sections (those skipped by --scan-seconds 0
    or --patient-seconds 0 leave the numbering consecutive):

    \b
    1. The cameras: a simulated rig of two Axis cameras on 127.0.0.1; device info, clock offset,
       LED on and off snapshots, and a short recording of both through the real driver.
    2. The daily QA: baseline on day 0, then the daily set once per simulated day for --days
       days on a virtual clock (cam2 drifts past its tolerance along the way), stored in a
       fresh results store, each day's measured drift compared with the drift the scene injected.
    3. The 7-sphere step test on the same rig: stereo calibration from rendered checkerboards,
       the VTS -> SPECT mapping, then 22 table positions, scored against the truth.
    4. The QA report (drift trend and step test), HTML and PDF, and the rooms page.
    5. A scan: `vts scan start` against a rig with the trigger-box firmware in the emulator and a
       source marker moved along the table; the simulated SPECT writes list-mode following the
       trigger the box emitted; `vts sync analyze` lines the two up, scored against the truth.
    6. A patient scan: a breathing patient who moves once; the live tracking alerts during the
       scan; `vts motion analyze` separates breathing from body motion on the SPECT clock and
       writes the report and the exports for reconstruction (CASToR, 6-DOF series, subsets),
       every figure scored against the simulated patient's truth.
    """
    if 0 < patient_seconds < 24:
        raise click.BadParameter("a patient scan needs at least 24 s (or 0: none)", param_hint="--patient-seconds")
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    section = _Sections()
    section("the cameras")
    _cameras(out_dir, seconds)
    section(f"the daily QA, {days} simulated days")
    _daily(out_dir, days, frames, section)
    if scan_seconds > 0:
        section(f"a scan of {scan_seconds:g} s and the sync check")
        _scan(out_dir, scan_seconds)
    if patient_seconds > 0:
        section(f"a patient scan of {patient_seconds:g} s: breathing, a body move, the live alert")
        _patient(out_dir, patient_seconds)
    click.echo("\n" + console_hint(out_dir))


def console_hint(out_dir: Path) -> str:
    """How to see the room live in a browser after the demo (the last lines it prints): a
    simulated rig left running, and `vts console` on it with the demo's results store, so the
    History page holds the demo's runs."""
    live = out_dir / "live"
    return "\n".join(
        [
            "the room console, live in a browser (Chromium or Firefox):",
            f"  vts sim up --dir {live} --detach      # simulated cameras, left running",
            f"  source {live / 'sim.env'}",
            f"  VTS_STORE={out_dir / 'results.sqlite'} vts console --config {live / 'rig.yaml'}",
            "  then open the address vts console prints (http://127.0.0.1:8040/): Room shows the cameras live,",
            f"  History the demo's runs and reports; Ctrl-C stops vts console, vts sim down --dir {live} the cameras",
        ]
    )


class _Sections:
    """``== N. title`` headers numbered in the order they are shown."""

    def __init__(self):
        self.n = 0

    def __call__(self, title: str) -> None:
        self.n += 1
        click.echo(f"{'' if self.n == 1 else chr(10)}== {self.n}. {title}")


def _cameras(out_dir: Path, seconds: float) -> None:
    from vts_hw.cli.progress import record_with_progress
    from vts_hw.sim_devices.scenarios.demo_rig import camera_tour

    tour = camera_tour(out_dir, seconds, record=record_with_progress, say=click.echo)
    for c in tour.cameras:
        click.echo(
            f"{c.name}: {c.product} firmware {c.firmware}, VAPIX {c.vapix}, clock "
            f"{c.clock_offset_s:+.3f} s against this host"
        )
        click.echo(f"  wrote {c.lit} and {c.dark.name} ({c.lit_bright_px} vs {c.dark_bright_px} bright pixels)")
    for s in tour.streams:
        gaps = sum(g["missing"] for g in s.gaps)
        click.echo(f"  {tour.recording / (s.source + '.mjpeg')}: {s.frames} frames at {s.fps} fps, {gaps} missing")
    click.echo(f"  {tour.recording / 'manifest.json'}: status {tour.manifest['status']}")


def _daily(out_dir: Path, days: int, frames: int, section) -> None:
    """Sections: the daily QA (its rows as they come, then how far from the truth), the step test
    and the reports, each header printed when its part starts."""
    from vts_hw.sim_devices.scenarios.demo_days import REPORTS_START, STEPS_START, run_demo

    cams: list[str] = []
    rows = []

    def on_day(row):
        rows.append(row)
        if not cams:
            cams.extend(row.cameras)
            head = "  day  state     " + "".join(f"{c + ' dx, dy px (truth)':<40}" for c in cams)
            click.echo(head)
        changed = row.state != getattr(on_day, "last", None)
        on_day.last = row.state
        if row.day % 5 == 0 or changed or row.day == 1:
            cells = []
            for c in cams:
                v = row.cameras.get(c, {})
                if "dx" in v:
                    cells.append(
                        f"{v['dx']:+.3f}, {v['dy']:+.3f} ({v['truth_dx']:+.3f}, {v['truth_dy']:+.3f}) "
                        f"{v['state'][:3]:<3}"
                    )
                else:
                    cells.append(f"{v.get('state', '?')}")
            click.echo(f"  {row.day:>3}  {row.state:<9} " + "".join(f"{x:<40}" for x in cells))

    def daily_summary():
        err: dict[str, tuple[float, float]] = {}
        for r in rows:
            for cam, v in r.cameras.items():
                if "dx" in v:
                    px, py = err.get(cam, (0.0, 0.0))
                    err[cam] = (max(px, abs(v["dx"] - v["truth_dx"])), max(py, abs(v["dy"] - v["truth_dy"])))
        click.echo("\nmeasured drift minus injected drift, largest over all days (goal <= 0.05 px):")
        for cam, (ex, ey) in err.items():
            click.echo(f"  {cam}: x {ex:.4f} px, y {ey:.4f} px  {'OK' if max(ex, ey) <= 0.05 else 'OVER'}")
        states = [r.state for r in rows]
        click.echo(
            f"\n{len(states)} daily runs: {states.count('OK')} OK, {states.count('TOLERANCE')} TOLERANCE, "
            f"{states.count('ACTION')} ACTION"
        )

    summarised = []

    def on_step(message: str) -> None:
        if message == STEPS_START:
            daily_summary()
            summarised.append(True)
            section("the 7-sphere step test (after the daily QA, same rig)")
        elif message == REPORTS_START:
            section("the QA reports: drift trend and step test, and the rooms page")
        click.echo(message)

    res = run_demo(out_dir, days=days, frames=frames, on_day=on_day, on_step=on_step)
    if not summarised:
        daily_summary()
    click.echo(f"results store: {res.store_path}")
    click.echo(f"report:        {res.report_html}")
    click.echo(f"               {res.report_pdf}")
    if res.rooms_html is not None:
        click.echo(f"rooms page:    {res.rooms_html} (every rig in the store; `vts report rooms`)")


def _scenario(run, out_dir: Path, seconds: float):
    """Run a demo scenario; its RuntimeError (the simulated rig failed) is the CLI's one sentence."""
    try:
        return run(out_dir, seconds, say=click.echo)
    except RuntimeError as exc:
        raise click.ClickException(str(exc)) from None


def _scan(out_dir: Path, seconds: float) -> None:
    from vts_hw.sim_devices.scenarios.demo_rig import demo_scan

    res = _scenario(demo_scan, out_dir, seconds)
    data, run = res.data, res.run
    g = data["gating"]
    click.echo(
        f"  state {data['summary']['state']}; {len(data['events'])} motion event(s); SPECT start delay "
        f"{g['start_delay_s'] * 1e3:.2f} ms (true {run.spect.start_delay_s * 1e3:.2f} ms)"
    )
    click.echo("  per move, event time minus the true mid-move time (host clock; goal within 20 ms):")
    ms = lambda v: "  -  " if v is None else f"{v * 1e3:+.1f} ms"  # noqa: E731
    for k, row in enumerate(res.moves, 1):
        head = f"    move {k} ({row['step_mm']:+5.1f} mm at {row['t_mid'] - run.fire_host:5.2f} s)"
        if not row["found"]:
            click.echo(f"{head}: not found")
            continue
        click.echo(f"{head}: VTS {ms(row['vts_err_s'])}, SPECT {ms(row['spect_err_s'])}, seen by {row['seen_by']}")
    click.echo(f"  report: {res.report}; trajectories (SPECT frame, SPECT time): {', '.join(data['export'])}")


def _patient(out_dir: Path, seconds: float) -> None:
    from vts_hw.sim_devices.scenarios.demo_patient import demo_patient_scan

    res = _scenario(demo_patient_scan, out_dir, seconds)
    d, mv = res.data, res.move
    click.echo(f"  {d['summary']['state']}; times: {d['clock']}")
    click.echo(
        f"  the true move: {mv['translation_mm']:.1f} mm and {mv['rotation_deg']:.1f} deg at "
        f"{mv['t_start_list']:.2f} s (list-mode)"
    )
    for a in res.alerts:
        click.echo(f"  live alert {a['delay_s']:.2f} s after the move started: {a['text']}")
    if not res.alerts:
        click.echo(
            f"  no live alert: {res.no_alert_why}"
            if res.no_alert_why
            else "  NO LIVE ALERT for the move although the live tracking was watching: a missed alert"
        )
    if res.found:
        f = res.found
        click.echo(
            f"  found by the analysis: start {f['start_error_s'] * 1e3:+.0f} ms off the truth, 6-DOF change off "
            f"by {f['translation_error_mm']:.2f} mm and {f['rotation_error_deg']:.2f} deg "
            f"({f['events']} event(s) in all)"
        )
    else:
        click.echo("  the analysis found no body-motion event")
    rate, true_rate = res.rate_per_min
    sm = d["summary"]
    rng = sm.get("breathing_rate_range_per_min")
    said = (
        f"{rate:.1f} /min, {sm.get('breathing')}" + (f" {rng[0]:.1f}-{rng[1]:.1f} /min" if rng else "")
        if rate == rate
        else sm.get("breathing_why", "unknown")
    )
    click.echo(f"  time: {d['summary'].get('time', '')}")
    click.echo(
        f"  breathing {said} (true {true_rate:.1f} /min); body pose against the truth in still frames: "
        f"RMS {res.pose_error[0]:.3f} mm, {res.pose_error[1]:.3f} deg (goals 0.3 mm, 0.2 deg)"
    )
    click.echo(
        f"  report: {res.report}; for reconstruction: {res.export}/castor_motion.dyn, castor_motion_rigid.txt, "
        "motion_6dof.csv, respiration.csv, subsets.json"
    )
