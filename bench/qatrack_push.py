"""Push the demo's 60 days to (a simulated) QATrack+, then push again: nothing twice (issue 13, part 3).

    .venv/bin/python bench/qatrack_push.py [--days 60] [--from DEMO_DIR] [--no-attachments]

Fills a store with the demo (``run_demo``: a baseline, ``--days`` daily QA runs of the
simulated rig and a step test; or copies DEMO_DIR/results.sqlite of an earlier
``vts demo -o DEMO_DIR``), brings up the simulated QATrack+ on 127.0.0.1 (its daily and
step-test lists made from the mapping below), and measures:

1. the first push of every run (values, times, comment, and as attachments the drift plot per
   camera and the HTML drift report as of each run): runs pushed, instances created, seconds;
2. the second push (`vts qa push` again): "second push: N new" (the goal is 0);
3. a push from a copy of the store taken before the first push (its outbox knows nothing):
   every run found in QATrack+ by its key, "copy's push: N new" (the goal is 0).

Exit status 1 when a goal is missed.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

from vts_hw.config import parse_rig
from vts_hw.qatrack import push_runs, select_runs
from vts_hw.sim_devices.qatrack_server import QATrackSim
from vts_hw.store import ResultsStore

RIG = "sim-demo"


def macro(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", name)


def mapping(store) -> dict:
    """The qatrack.lists of the bench: every camera-level daily measurement and every step-test
    measurement under a macro named after it; the per-marker ones ignored."""
    lists = {}
    for proc, title in (("daily", "VTS daily"), ("sphere-steps", "VTS step test")):
        runs = store.runs(procedure=proc)
        names = sorted({f"{m.subject}/{m.metric}" for r in runs[-1:] for m in store.measurements(run_id=r.id)
                        if m.subject.count("/") == 0})
        lists[proc] = {"test_list": title, "macros": {n: macro(n) for n in names}, "ignore": ["*/M*/*"]}
    return lists


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", type=int, default=60)
    ap.add_argument("--from", dest="from_dir", type=Path, default=None,
                    help="use DIR/results.sqlite of an earlier `vts demo -o DIR`")
    ap.add_argument("--no-attachments", action="store_true", help="no plot and report attachments")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="vts-bench-qatrack-"))
    try:
        db = tmp / "results.sqlite"
        t = time.monotonic()
        if args.from_dir:
            shutil.copy(args.from_dir / "results.sqlite", db)
            print(f"store: a copy of {args.from_dir / 'results.sqlite'}")
        else:
            from vts_hw.sim_devices.scenarios.demo_days import run_demo
            res = run_demo(tmp / "demo", days=args.days)
            shutil.copy(res.store_path, db)
            print(f"store: the demo's {args.days} days ({time.monotonic() - t:.0f} s to simulate)")
        copy = tmp / "copy.sqlite"
        shutil.copy(db, copy)
        with ResultsStore(db) as store:
            lists = mapping(store)
        qlists = {v["test_list"]: sorted(v["macros"].values()) for v in lists.values()}
        with QATrackSim(qlists, {"SPECT room 1": list(qlists)}, token="bench-token") as peer:
            os.environ["BENCH_QATRACK_TOKEN"] = "bench-token"
            cfg = parse_rig({"rig": RIG, "cameras": [{"name": "cam1", "host": "127.0.0.1"}],
                             "qatrack": {"url": peer.url, "unit": "SPECT room 1", "time_zone": "America/Toronto",
                                         "token_env": "BENCH_QATRACK_TOKEN",
                                         "report": "none" if args.no_attachments else "html",
                                         "plots": not args.no_attachments, "lists": lists}}, "bench").qatrack
            with ResultsStore(db) as store:
                runs = select_runs(store, cfg, RIG)
                t0 = time.monotonic()
                out = push_runs(store, cfg, runs)
                first_s = time.monotonic() - t0
                sent = sum(o.state == "sent" for o in out)
                made = peer.posts
                kb = sum(i["attachment_bytes"] for i in peer.instances) / 1024
                print(f"first push: {len(runs)} runs ({sum(r.procedure == 'daily' for r in runs)} daily, "
                      f"{sum(r.procedure == 'sphere-steps' for r in runs)} step test), {sent} sent, "
                      f"{made} instances created in {first_s:.1f} s ({first_s / max(len(runs), 1):.2f} s a run; "
                      f"attachments {kb:.0f} kB base64 in all)")
                bad = [o.line() for o in out if o.state != "sent"]
                for line in bad[:5]:
                    print("  not sent:", line)
                t0 = time.monotonic()
                again = push_runs(store, cfg, select_runs(store, cfg, RIG))
                second_new = peer.posts - made
                print(f"second push: {second_new} new ({len(again)} runs left to send; {time.monotonic() - t0:.2f} s)")
            with ResultsStore(copy) as store:
                t0 = time.monotonic()
                before = peer.posts
                out3 = push_runs(store, cfg, select_runs(store, cfg, RIG))
                copy_new = peer.posts - before
                there = sum(o.how == "already there" for o in out3)
                print(f"copy's push: {copy_new} new, {there} of {len(out3)} found in QATrack+ by their key "
                      f"({time.monotonic() - t0:.1f} s)")
        ok = not bad and made == len(runs) and second_new == 0 and copy_new == 0 and len(peer.instances) == len(runs)
        print("goals met" if ok else "GOAL MISSED")
        return 0 if ok else 1
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
