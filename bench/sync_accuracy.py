"""The sync check's acceptance figures on the simulated rig (issue 6, part 5).

    .venv/bin/python bench/sync_accuracy.py [--duration 60] [--moves 4] [--seed 1] [--keep DIR]

One run: a simulated rig (2 Axis cameras over HTTP, the trigger-box firmware in the emulator),
a source marker in its scene, ``vts scan start --duration D`` in a subprocess, the source
moved ``--moves`` times along the table axis (clear of the SPECT head rotations), the
simulated SPECT following the start pulse and square wave the emulator emitted, then
``vts sync analyze SESSION --listmode FILE --json``. The calibration is the simulated
cameras' truth (rig.yaml's calibration section written by the sim; the VTS → SPECT mapping
from camera 1's true pose).

Prints per motion event the VTS and SPECT event times minus the true move middle (host
clock), their difference, and the SPECT start delay's error; the goals are 20 ms per event
and 10 ms for the start delay. Exit status 1 when a goal is missed.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scenarios import sync_session as sync_sim

EVENT_GOAL_S = 0.020
DELAY_GOAL_S = 0.010


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--moves", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--keep", type=Path, default=None, help="keep the session, list-mode and report here")
    args = ap.parse_args()
    tmp = tempfile.TemporaryDirectory() if args.keep is None else None
    work = Path(tmp.name) if tmp else args.keep
    work.mkdir(parents=True, exist_ok=True)
    rig = SimRig(n_cameras=2, seed=3, trigger="triggerbox").start()
    try:
        rig_yaml, _ = rig.write(work / "rig")
        marker = sync_sim.prepare(rig)
        t0 = time.monotonic()
        run = sync_sim.cli_scan(rig, rig_yaml, work / "scan", args.duration, marker, n=args.moves, seed=args.seed)
        scan_s = time.monotonic() - t0
    finally:
        rig.stop()
    t0 = time.monotonic()
    cmd = [
        sys.executable,
        "-m",
        "vts_hw.cli.__main__",
        "sync",
        "analyze",
        str(run.session),
        "--listmode",
        str(run.listmode),
        "--config",
        str(rig_yaml),
        "--json",
        "-o",
        str(work / "sync_report.html"),
    ]
    p = subprocess.run(cmd, capture_output=True, text=True)
    analyze_s = time.monotonic() - t0
    if p.returncode != 0:
        print(p.stderr, file=sys.stderr)
        return 2
    data = json.loads(p.stdout)
    print(
        f"scan {args.duration:g} s ({scan_s:.1f} s wall), analysis {analyze_s:.1f} s wall; "
        f"{len(run.source.moves)} moves; command: {' '.join(cmd[3:])}"
    )
    ok = True
    events = data["events"]
    f = lambda v: "   -   " if v is None else f"{v * 1e3:+7.2f}"  # noqa: E731
    for k, row in enumerate(sync_sim.match_moves(events, run.source.moves), 1):
        head = f"  move {k} at {row['t_mid'] - run.fire_host:6.2f} s ({row['step_mm']:+5.1f} mm)"
        if not row["found"]:
            print(f"{head}: NOT FOUND")
            ok = False
            continue
        print(
            f"{head}: VTS {f(row['vts_err_s'])} ms, SPECT {f(row['spect_err_s'])} ms, "
            f"VTS-SPECT {f(row['dt_s'])} ms (seen by {row['seen_by']})"
        )
        ok &= (
            row["seen_by"] == "both"
            and max(abs(row["vts_err_s"]), abs(row["spect_err_s"]), abs(row["dt_s"])) <= EVENT_GOAL_S
        )
    extra = len(events) - len(run.source.moves)
    delay_err = data["summary"]["start_delay_s"] - run.spect.start_delay_s
    print(
        f"  events reported {len(events)} (extra {extra}); offset VTS-SPECT (median) "
        f"{data['summary']['offset_s'] * 1e3:+.2f} ms, SD {(data['summary']['spread_sd_s'] or 0) * 1e3:.2f} ms"
    )
    print(
        f"  SPECT start delay: measured {data['summary']['start_delay_s'] * 1e3:.2f} ms, true "
        f"{run.spect.start_delay_s * 1e3:.2f} ms, error {delay_err * 1e3:+.3f} ms"
    )
    ok &= extra == 0 and abs(delay_err) <= DELAY_GOAL_S
    print(
        f"goals (every event within {EVENT_GOAL_S * 1e3:.0f} ms, start delay within {DELAY_GOAL_S * 1e3:.0f} ms): "
        f"{'met' if ok else 'MISSED'}; report state {data['summary']['state']}"
    )
    if tmp:
        tmp.cleanup()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
