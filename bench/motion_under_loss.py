#!/usr/bin/env python3
"""Simulated patient scans with frames lost in bursts, through the real path: live and offline
figures against the truth (issue 20 §3/§5).

    .venv/bin/python bench/motion_under_loss.py                  # seeds 1 2, 2 and 4 cameras, 0/5/20/35 %, + load
    .venv/bin/python bench/motion_under_loss.py --quick          # a smoke run (~2 min): seed 1, 2 cameras, 20 %
    .venv/bin/python bench/motion_under_loss.py --seeds 3 --cameras 2 --losses 10 30 --seconds 45 --no-load

Per seed, the simulated rig's cameras (Axis over HTTP on 127.0.0.1) watch a breathing patient
who moves a few times (2.5-8 mm, 0.3-2 deg) after the live reference; their frames are made
ahead of time, so the renderer adds no loss of its own (the table says how many frames were
missing that the fault did not drop, and how many had to be rendered live). Per loss share,
every camera drops bursts of about a second (the simulated cameras' declared fault, at the same
moments in every camera) and `vts scan start` records the scan with the live tracking on, once
per camera count, those of one share at the same time; `vts motion analyze --export` then
reads each session (at lower priority, beside the next scans). One more share (``--load-loss``)
runs under a CPU load the bench starts: a spinning process per core (``--per-core``), stopped
at the end and on Ctrl-C.

Per case: frames lost (the fault's share; + frames missing it did not drop); time covered
(the analysis' share of the scan with a pose / the true share with frames); breathing rate
(measured, ``bounded [a, b]`` with whether the truth is inside, or ``unknown``) and the true
rate; body pose RMS against the truth in still frames; moves found with their start measured /
true moves (>= 2 mm or 1 deg), ``b``: start bounded (the truth inside), and the largest start
error; the live alert's delay after each move's true start (max; ``b`` an onset given as a
range, ``-`` none raised); NOT TRACKING reported in the manifest / the time truly without a
frame set of two cameras (stretches > 0.5 s), how much of the latter was not reported, and how
much of the former was only "frames too late" (the live path behind on a busy host: reported,
but no frame was lost); the figures reported unknown or bounded; the figures outside their goal NOT flagged (listed below
the table). Then a verdict per goal, counted from the rows. Exit status 1 when any figure is
outside its goal and not flagged, or when blind time went unreported.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import signal
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from losskit.rows import score, slot_truth  # noqa: E402
from losskit.scans import REFERENCE_S, PatientRig, analyze, burst_faults, cpu_load  # noqa: E402
from losskit.table import header, row_line, verdicts  # noqa: E402

ANALYSES = 2  # `vts motion analyze` runs at once (niced, beside the scans; then the tail on both cores)


def _interrupt(*_):
    raise KeyboardInterrupt


def parse(argv=None):
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog="Exit status: 0 every figure within its goal or flagged; 1 a figure outside its "
        "goal not flagged, or blind time unreported; 2 bad arguments; 130 interrupted.",
    )
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2], help="patients (and loss layouts): default 1 2")
    ap.add_argument("--cameras", type=int, nargs="+", default=[2, 4], choices=(2, 3, 4), help="default 2 4")
    ap.add_argument("--losses", type=float, nargs="+", default=[0, 5, 20, 35], help="%% of the time lost in bursts")
    ap.add_argument("--seconds", type=float, default=60.0, help="scan duration (patient time), default 60")
    ap.add_argument("--load-loss", type=float, default=20.0, help="%% lost in the case run under CPU load (default 20)")
    ap.add_argument("--no-load", action="store_true", help="no case under CPU load")
    ap.add_argument("--per-core", type=int, default=1, help="spinning processes per core in the load case (default 1)")
    ap.add_argument("--quick", action="store_true", help="smoke run: seed 1, 2 cameras, 20 %%, 30 s, no load case")
    ap.add_argument(
        "--keep", type=Path, default=None, help="work in DIR and keep the sessions (default: a temporary folder)"
    )
    a = ap.parse_args(argv)
    if a.quick:
        a.seeds, a.cameras, a.losses, a.seconds, a.no_load = [1], [2], [20.0], 30.0, True
    if a.seconds < REFERENCE_S + 15 or any(not 0 <= x < 100 for x in [*a.losses, a.load_loss]) or a.per_core < 1:
        ap.error(
            f"--seconds must be at least {REFERENCE_S + 15:g} (the reference, then a move), losses 0 to <100 %, "
            "--per-core at least 1"
        )
    return a


def main(argv=None) -> int:
    a = parse(argv)
    signal.signal(signal.SIGTERM, _interrupt)
    work = a.keep or Path(tempfile.mkdtemp(prefix="vts-under-loss-"))
    work.mkdir(parents=True, exist_ok=True)
    cores = os.cpu_count() or 2
    print(header(a, cores, os.getloadavg()), flush=True)
    t_all = time.monotonic()
    jobs, running, rows = [], [], []
    pool = ThreadPoolExecutor(ANALYSES)
    try:
        for seed in a.seeds:
            prig = PatientRig(seed, a.seconds, a.cameras, work / f"seed{seed}")
            try:
                t0 = time.monotonic()
                st = prig.prerender()
                _say(f"seed {seed}: {st.line()} (wall {time.monotonic() - t0:.0f} s)")
                slots = [(x, False) for x in a.losses] + (
                    [(a.load_loss, True)] if not a.no_load and seed == a.seeds[0] else []
                )
                for loss, load in slots:
                    faults = burst_faults(loss / 100.0, seed)
                    label = f"s{seed}-{loss:g}pc" + ("-load" if load else "")
                    with cpu_load(a.per_core * cores) if load else contextlib.nullcontext() as pids:
                        if load:
                            _say(f"  CPU load: {len(pids)} spinning process(es) (pids {', '.join(map(str, pids))})")
                        scans = prig.scan(faults, work / f"seed{seed}", label)
                    bank_live = sum(prig.rig.bank.missed.values())
                    for s in scans:
                        s.truth = slot_truth(prig, s)
                        jobs.append((s, loss, load, seed, bank_live, pool.submit(analyze, s, prig.env, 10, running)))
                    _say(
                        f"  seed {seed}, {loss:g} % lost{' under load' if load else ''} ({faults}): "
                        + "; ".join(f"{s.cameras} cameras exit {s.returncode} in {s.wall_s:.0f} s" for s in scans)
                        + f"; frames rendered live {bank_live}"
                    )
            finally:
                prig.stop()
        _say(f"scans done in {time.monotonic() - t_all:.0f} s; waiting for the analyses ...")
        for s, loss, load, seed, bank_live, fut in jobs:
            fut.result()
            rows.append(score(s, loss, load, seed, bank_live))
    except KeyboardInterrupt:
        for p in list(running):
            p.terminate()
        pool.shutdown(wait=False, cancel_futures=True)
        print("interrupted: the CPU load and the simulated rig are stopped", file=sys.stderr)
        return 130
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if a.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    print()
    for line in row_line(None):
        print(line)
    for r in rows:
        for line in row_line(r):
            print(line)
    print()
    lines, failed = verdicts(rows)
    for line in lines:
        print(line)
    print(
        f"\nrun time {time.monotonic() - t_all:.0f} s; load average at the end {os.getloadavg()[0]:.2f} "
        f"{os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f} ({cores} cores)"
        + (f"; sessions kept in {work}" if a.keep else "")
    )
    return 1 if failed else 0


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


if __name__ == "__main__":
    sys.exit(main())
