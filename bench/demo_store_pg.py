"""The demo's store on PostgreSQL: the drift report from the copy equals the SQLite original's.

Fills a SQLite store with the demo's daily QA (sim_devices/scenarios/demo_days.run_demo: the
baseline, --days of daily QA and the step test), or takes an existing one (--store FILE, e.g.
demo-out/results.sqlite from `vts demo`); starts a throwaway PostgreSQL server (tests/pgserver.py);
copies the store there with `vts store migrate` twice (the second copy must add nothing); then
builds the drift report of every rig from both stores at the same moment (what
`vts --store URL report drift --rig all` writes) and compares every number. Prints the figures; exit 1 when the reports differ or the second copy
added rows.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from pgserver import PgServer  # noqa: E402


def vts(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "vts_hw.cli.__main__", *args], capture_output=True, text=True)


def differences(a, b, path="") -> list[str]:
    """Where two JSON trees differ (numbers compared exactly)."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = [f"{path}/{k}: only in one" for k in set(a) ^ set(b)]
        for k in set(a) & set(b):
            out += differences(a[k], b[k], f"{path}/{k}")
        return out
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{path}: {len(a)} vs {len(b)} items"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in differences(x, y, f"{path}[{i}]")]
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return []
    return [] if a == b else [f"{path}: {a!r} vs {b!r}"]


def count_numbers(x) -> int:
    if isinstance(x, dict):
        return sum(count_numbers(v) for v in x.values())
    if isinstance(x, list):
        return sum(count_numbers(v) for v in x)
    return int(isinstance(x, (int, float)) and not isinstance(x, bool))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--store", type=Path, help="an existing SQLite store (default: run the demo's days afresh)")
    ap.add_argument("--days", type=int, default=60, help="simulated days when the demo is run here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        if args.store is None:
            from vts_hw.sim_devices.scenarios.demo_days import run_demo

            t0 = time.monotonic()
            res = run_demo(tmp / "demo", days=args.days, frames=3)
            db = res.store_path
            print(f"demo: {args.days} simulated days of daily QA and a step test in {time.monotonic() - t0:.0f} s")
        else:
            db = args.store.resolve()
        src = f"sqlite:///{db}"
        pg = PgServer().start()
        try:
            dst = pg.url(pg.new_database())
            copies = []
            for i in (1, 2):
                t0 = time.monotonic()
                r = vts("store", "migrate", "--from", src, "--to", dst)
                copies.append((r.returncode, time.monotonic() - t0, r.stdout.strip().splitlines()))
                if r.returncode != 0:
                    print(f"copy {i}: exit {r.returncode}: {r.stderr.strip()}")
                    return 1
            for i, (code, secs, lines) in enumerate(copies, 1):
                print(f"copy {i} (exit {code}, {secs:.1f} s):")
                for line in lines:
                    print(f"    {line}")
            # the same "now" for both (a report's band edges are found by bisection from now)
            from vts_hw.report.build import build_drift_report_every_rig
            from vts_hw.store import ResultsStore

            now = time.time()
            reports = {}
            for name, url in (("sqlite", src), ("postgresql", dst)):
                with ResultsStore(url) as store:
                    reps = build_drift_report_every_rig(store, tmp / f"drift-{name}.html", now=now)
                data = [r.results_data() for r in reps]
                for room in data:
                    room.pop("out", None)
                reports[name] = data
        finally:
            pg.stop()
        diff = differences(reports["sqlite"], reports["postgresql"])
        print(
            f"drift report (every rig, all runs): {count_numbers(reports['sqlite'])} numbers from SQLite, "
            f"{len(diff)} differ in the PostgreSQL copy's report"
        )
        for d in diff[:10]:
            print(f"    {d}")
        second = copies[1][2][-1] if copies[1][2] else ""
        print(f"second copy: {second}")
        return 1 if diff or not second.startswith("0 new") else 0


if __name__ == "__main__":
    sys.exit(main())
