"""Push the demo's 60 days to QATrack+ (the simulated one, or with --real the real QATrack+ 3.1
of ../shared/interop), then push again: nothing twice (issues 13 and 19).

    .venv/bin/python bench/qatrack_push.py [--days 60] [--from DEMO_DIR] [--no-attachments]
    .venv/bin/python bench/qatrack_push.py --real [--zone Australia/Sydney]

Fills a store with the demo (``run_demo``: a baseline, ``--days`` daily QA runs of the
simulated rig and a step test; or copies DEMO_DIR/results.sqlite of an earlier
``vts demo -o DEMO_DIR``) and measures:

1. the first push of every run (values, times, comment, and as attachments the drift plot per
   camera and the HTML drift report as of each run): runs pushed, instances created, seconds;
2. the second push (`vts qa push` again): "second push: N new" (the goal is 0);
3. a push from a copy of the store taken before the first push (its outbox knows nothing):
   every run found in QATrack+ by its key, "copy's push: N new" (the goal is 0).

The simulated QATrack+ gets lists made from the mapping below (every camera-level measurement
under a macro named after it). ``--real`` starts the real server (run-qatrack.sh, cached after
its first start) in ``--zone`` and maps the demo onto the lists that server's setup_site.py
makes ("VTS daily": cam1_dx ... cam3_dx, "VTS step test": x_slope ... diff_max), as a site's
physicist would; every instance made is counted through QATrack+'s own API, and each run's
work start is read back and compared with the run's instant.

Exit status 1 when a goal is missed.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import math
import os
import re
import shutil
import sys
import tempfile
import time
from pathlib import Path

from vts_hw.config import parse_rig
from vts_hw.qatrack import push_runs, run_key, select_runs
from vts_hw.store import ResultsStore

RIG = "sim-demo"
UNIT = "SPECT room 1"
REAL_LISTS = {
    "daily": {
        "test_list": "VTS daily",
        "ignore": ["*/M*/*", "cam?/*"],
        "macros": {
            "cam1/drift_x_px": "cam1_dx",
            "cam1/drift_y_px": "cam1_dy",
            "cam2/drift_x_px": "cam2_dx",
            "cam2/drift_y_px": "cam2_dy",
            "cam1/drift_sd_px": "cam1_sd",
            "cam2/drift_sd_px": "cam2_sd",
            "cam1/markers_missing": "cam1_missing",
            "cam2/markers_missing": "cam2_missing",
            "cam3/drift_x_px": "cam3_dx",
        },
    },
    "sphere-steps": {
        "test_list": "VTS step test",
        "ignore": ["*"],
        "macros": {
            "x/steps_slope": "x_slope",
            "y/steps_slope": "y_slope",
            "z/steps_slope": "z_slope",
            "all/steps_diff_max_mm": "diff_max",
        },
    },
}


def macro(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_]", "_", name)


def mapping(store) -> dict:
    """The qatrack.lists of the bench: every camera-level daily measurement and every step-test
    measurement under a macro named after it; the per-marker ones ignored."""
    lists = {}
    for proc, title in (("daily", "VTS daily"), ("sphere-steps", "VTS step test")):
        runs = store.runs(procedure=proc)
        names = sorted(
            {
                f"{m.subject}/{m.metric}"
                for r in runs[-1:]
                for m in store.measurements(run_id=r.id)
                if m.subject.count("/") == 0
            }
        )
        lists[proc] = {"test_list": title, "macros": {n: macro(n) for n in names}, "ignore": ["*/M*/*"]}
    return lists


class SimPeer:
    """The simulated QATrack+: instances counted in memory."""

    def __init__(self, store_path: Path):
        from vts_hw.sim_devices.qatrack_server import QATrackSim

        with ResultsStore(store_path) as store:
            self.lists = mapping(store)
        qlists = {v["test_list"]: sorted(v["macros"].values()) for v in self.lists.values()}
        self.zone = "America/Toronto"
        self.sim = QATrackSim(qlists, {UNIT: list(qlists)}, token="bench-token").up()
        self.url, self.token = self.sim.url, "bench-token"

    def count(self) -> int:
        return len(self.sim.instances)

    def shown_start(self, key: str) -> list[str]:
        return [i["work_started"] for i in self.sim.instances if i["user_key"] == key]

    def close(self) -> None:
        self.sim.down()


class RealPeer:
    """The real QATrack+ (tests/qatrack_real.py's RealQATrack): instances counted through its API."""

    def __init__(self, zone: str):
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
        from qatrack_real import RealQATrack

        self.site = RealQATrack()
        t = time.monotonic()
        self.site.restart(zone) if self.site.answering() else (self.site.start_in_background(zone), self.site.wait())
        print(f"real QATrack+ 3.1 at {self.site.url}, TIME_ZONE {zone} ({time.monotonic() - t:.0f} s to start)")
        self.zone, self.url, self.token, self.lists = zone, self.site.url, self.site.tokens["QATRACK_TOKEN"], REAL_LISTS

    def count(self) -> int:
        return self.site.get("qa/testlistinstances/", limit=1)["count"]

    def shown_start(self, key: str) -> list[str]:
        return [i["work_started"] for i in self.site.instances(key)]

    def close(self) -> None:
        pass


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--days", type=int, default=60)
    ap.add_argument(
        "--from",
        dest="from_dir",
        type=Path,
        default=None,
        help="use DIR/results.sqlite of an earlier `vts demo -o DIR`",
    )
    ap.add_argument("--no-attachments", action="store_true", help="no plot and report attachments")
    ap.add_argument("--real", action="store_true", help="push into the real QATrack+ of ../shared/interop")
    ap.add_argument("--zone", default="America/Toronto", help="--real: the site's TIME_ZONE (default America/Toronto)")
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="vts-bench-qatrack-"))
    peer = None
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
        peer = RealPeer(args.zone) if args.real else SimPeer(db)
        os.environ["BENCH_QATRACK_TOKEN"] = peer.token
        cfg = parse_rig(
            {
                "rig": RIG,
                "cameras": [{"name": "cam1", "host": "127.0.0.1"}],
                "qatrack": {
                    "url": peer.url,
                    "unit": UNIT,
                    "time_zone": peer.zone,
                    "token_env": "BENCH_QATRACK_TOKEN",
                    "timeout_s": 60,
                    "report": "none" if args.no_attachments else "html",
                    "plots": not args.no_attachments,
                    "lists": peer.lists,
                },
            },
            "bench",
        ).qatrack
        start = peer.count()
        with ResultsStore(db) as store:
            runs = select_runs(store, cfg, RIG)
            t0 = time.monotonic()
            out = push_runs(store, cfg, runs)
            first_s = time.monotonic() - t0
            sent = sum(o.state == "sent" for o in out)
            made = peer.count() - start
            print(
                f"first push: {len(runs)} runs ({sum(r.procedure == 'daily' for r in runs)} daily, "
                f"{sum(r.procedure == 'sphere-steps' for r in runs)} step test), {sent} sent, "
                f"{made} instances created in {first_s:.1f} s ({first_s / max(len(runs), 1):.2f} s a run)"
            )
            bad = [o.line() for o in out if o.state != "sent"]
            for line in bad[:5]:
                print("  not sent:", line)
            wrong_time = 0
            for run in runs:
                shown = peer.shown_start(run_key(run))
                if len(shown) != 1 or _dt.datetime.fromisoformat(shown[0]).timestamp() != math.floor(run.started):
                    wrong_time += 1
            print(
                f"work start as QATrack+ shows it: {len(runs) - wrong_time} of {len(runs)} at the run's instant "
                f"(to the second, site zone {peer.zone})"
            )
            t0 = time.monotonic()
            again = push_runs(store, cfg, select_runs(store, cfg, RIG))
            second_new = peer.count() - start - made
            print(f"second push: {second_new} new ({len(again)} runs left to send; {time.monotonic() - t0:.2f} s)")
        with ResultsStore(copy) as store:
            t0 = time.monotonic()
            before = peer.count()
            out3 = push_runs(store, cfg, select_runs(store, cfg, RIG))
            copy_new = peer.count() - before
            there = sum(o.how == "already there" for o in out3)
            print(
                f"copy's push: {copy_new} new, {there} of {len(out3)} found in QATrack+ by their key "
                f"({time.monotonic() - t0:.1f} s)"
            )
        ok = not bad and made == len(runs) and second_new == 0 and copy_new == 0 and wrong_time == 0
        print("goals met" if ok else "GOAL MISSED")
        return 0 if ok else 1
    finally:
        if peer is not None:
            peer.close()
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
