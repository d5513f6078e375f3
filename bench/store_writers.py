"""Many writers into one results store, on SQLite and on PostgreSQL (issue 13, part 1).

    .venv/bin/python bench/store_writers.py [--procs 8] [--runs 50] [--kills 10] [--seed 1]

Per back end (an SQLite file in a temporary folder, synchronous=FULL; a throwaway PostgreSQL
server started for the run with its durable defaults (fsync on), tests/pgserver.py, as
`nobody` when run as root; both on the same disk), two rounds:
  1. PROCS writer processes write RUNS runs each at once (a few measurements and an artifact
     per run; one in 20 aborted by the "operator");
  2. the same with KILLS writers killed with SIGKILL at random moments (each replaced by a
     fresh writer, so the load goes on).
After each round the store is reopened (marking killed writers' runs aborted) and every run
checked (tests/store_writers.py). Prints runs/s (finished runs over the writing time),
finish() commit latency p50/p95, and the runs lost, duplicated and half-written (goal: 0).
Exit status 1 when any run is lost, duplicated or half-written.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from pgserver import PgServer  # noqa: E402
from store_writers import run_writers  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--procs", type=int, default=8)
    ap.add_argument("--runs", type=int, default=50, help="runs per writer")
    ap.add_argument("--kills", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    bad = 0
    print(
        f"{'back end':<11} {'round':<10} {'finished':>8} {'runs/s':>7} {'p50 ms':>7} {'p95 ms':>7} "
        f"{'lost':>4} {'dup':>4} {'half':>4} {'kills':>5} {'dead':>4}"
    )
    with tempfile.TemporaryDirectory(prefix="vts-bench-writers-") as tmp:
        server = PgServer(durable=True).start()
        try:
            for backend in ("sqlite", "postgresql"):
                for label, kills in (("at once", 0), ("kill -9", args.kills)):
                    folder = Path(tmp) / f"{backend}-{kills}"
                    url = (
                        f"sqlite:///{folder / 'results.sqlite'}"
                        if backend == "sqlite"
                        else server.url(server.new_database())
                    )
                    out = run_writers(url, folder, n_procs=args.procs, per_proc=args.runs, kills=kills, seed=args.seed)
                    bad += out.lost + out.duplicated + out.half_written + len(out.problems)
                    print(
                        f"{backend:<11} {label:<10} {out.finished_reported:>8} {out.runs_per_s:>7.0f} "
                        f"{1e3 * out.percentile(0.5):>7.2f} {1e3 * out.percentile(0.95):>7.2f} "
                        f"{out.lost:>4} {out.duplicated:>4} {out.half_written:>4} {out.kills:>5} {out.dead:>4}",
                        flush=True,
                    )
                    for p in out.problems[:5]:
                        print(f"    {p}")
        finally:
            server.stop()
    print("dead: killed writers' runs found running and marked aborted on the reopen, none with data")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
