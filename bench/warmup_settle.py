#!/usr/bin/env python3
"""Commissioning's warm-up on the simulated cameras: how well it says how long to wait, and how
late it says "settled" (decision 0072). Prints figures from one run; asserts nothing.

Four cameras with the seeded warm-up drift (2-4 px, tau 8-15 min), restarted together; the
simulated time moves only when the step sleeps (a sample a minute, 6 samples, 3 snapshots:
the defaults of a real room), every camera's warmup_min 0 so that the rate alone decides:

* ``--no-wait`` 5 minutes after the start (a window of minutes 0-5): the wait it says against
  the true time until the rate falls below the limit;
* waiting from the start: the age at which it says "settled" against the age at which the
  true rate fell below the limit (the window's mean rate lags by about half a window).

The cameras' clocks warm up too (seeded: a rate departing 100-300 ppm, tau 5-12 min): beside the
picture's figures, the clock's: how fast its rate changes (ppm/min) and the wait said against the
true time until it changes slower than the limit (5 ppm/min); and when the waiting step's last
clock truly crossed it. ``--samples 12`` (a longer window) lets the clock's slowing be measured.

Run: .venv/bin/python bench/warmup_settle.py [--seed N] [--samples N]
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from tempfile import mkdtemp

from vts_hw.config import parse_rig
from vts_hw.procedures import commission_steps as steps
from vts_hw.procedures.commission import Context, Inputs
from vts_hw.sim_devices.clock import VirtualClock
from vts_hw.sim_devices.rig import SimRig

LIMIT = 0.05
CLOCK_LIMIT = 5.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--samples", type=int, default=6)
    args = ap.parse_args()
    clock = VirtualClock(rate=1e-9)
    out = Path(mkdtemp(prefix="vts-warmup-bench-"))
    with SimRig(n_cameras=4, seed=args.seed, clock=clock, warmup_drift=True, clock_warmup=True) as rig, rig.env():
        data = rig.config().model_dump(mode="json", exclude_none=True, exclude_defaults=True)
        for c in data["cameras"]:
            c["warmup_min"] = 0
        data["warmup"] = {"samples": args.samples}
        cfg = parse_rig(data, "bench rig")

        def run(wait: bool):
            for srv in rig.servers.values():
                srv.reboot()
            ctx = Context(cfg, Inputs(out=out, wait=wait), clock=clock.now, sleep=clock.advance)
            return steps.warmup(ctx)

        o = run(False)
        print(
            f"--no-wait after a {args.samples - 1}-minute window (limit {LIMIT} px/min; clock {CLOCK_LIMIT} ppm/min):"
        )
        print(
            f"{'camera':8}{'amp px':>8}{'tau min':>9}{'rate px/min':>13}{'says min':>10}{'true min':>10}"
            f"{'clk ppm':>9}{'tau min':>9}{'chg ppm/min':>13}{'says min':>10}{'true min':>10}"
        )
        for name, d in o.result.data["warmup"].items():
            w = rig.scene.warmups[name]
            age = clock.now() - rig.servers[name].booted_at
            true = max(0.0, (w.settled_after_s(LIMIT) - age) / 60)
            says = "-" if d.get("wait_min") is None else f"{d['wait_min']:.1f}"
            c, cw = d["clock"], rig.scene.clock_warmups[name]
            ctrue = max(0.0, (cw.settled_after_s(CLOCK_LIMIT) - age) / 60)
            csays = ("-" if c["state"] == "OK" else "?") if c.get("wait_min") is None else f"{c['wait_min']:.1f}"
            chg = "not known" if not c["known"] else f"{c['change_ppm_min']:.2f}±{c['change_se_ppm_min']:.2f}"
            print(
                f"{name:8}{w.amplitude_px:8.2f}{w.tau_s / 60:9.1f}{d['rate_px_min']:13.3f}{says:>10}{true:10.1f}"
                f"{cw.amplitude_ppm:9.0f}{cw.tau_s / 60:9.1f}{chg:>13}{csays:>10}{ctrue:10.1f}"
            )
        t0 = clock.now()
        o = run(True)
        print(
            f"waiting from the start: settled after {(clock.now() - t0) / 60:.0f} simulated min "
            f"({'passed' if o.passed else 'NOT passed'})"
        )
        for name in rig.scene.warmups:
            w = rig.scene.warmups[name]
            cw = rig.scene.clock_warmups[name]
            age = clock.now() - rig.servers[name].booted_at
            print(
                f"  {name}: its true rate fell below {LIMIT} px/min {w.settled_after_s(LIMIT) / 60:.1f} min after "
                f"the start; now {w.rate_px_min(age):.3f} px/min; its clock's change below {CLOCK_LIMIT} ppm/min "
                f"{cw.settled_after_s(CLOCK_LIMIT) / 60:.1f} min after, now {cw.change_ppm_min(age):.2f} ppm/min "
                f"({o.result.data['warmup'][name]['clock']['why']})"
            )
        said = re.findall(r"rate not slowing", o.advice)
        if said:
            print(f"  ({len(said)} camera(s) whose slowing was not measurable)")


if __name__ == "__main__":
    main()
