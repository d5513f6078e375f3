"""Many processes writing runs into one store at once, some killed with SIGKILL at random
moments; then a check that no run was lost, duplicated or half-written.

Used by tests/integration/test_store_writers.py and bench/store_writers.py. Run as a script it is one
writer: ``python store_writers.py URL SEED COUNT DONE_FILE FRAME``. A writer opens the store,
prints ``open``, then writes COUNT runs (a few measurements and an artifact each; one in 20
aborted by the operator); after finish() returns it appends ``uid latency`` to DONE_FILE and
fsyncs it, so a run listed there was reported finished to its writer.
"""

from __future__ import annotations

import os
import random
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve()


def writer_main(url: str, seed: int, count: int, done_file: str, frame: str) -> None:
    from vts_hw.store import ResultsStore

    rng = random.Random(seed)
    store = ResultsStore(url)
    print("open", time.time(), flush=True)
    fd = os.open(done_file, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    for _ in range(count):
        n = rng.randint(2, 6)
        run = store.begin_run("writer", rig=f"w{seed}", notes=f"n={n}")
        for k in range(n):
            run.measure(f"cam{k % 2}", "drift_x_px", rng.uniform(-3.0, 3.0), status="OK")
        run.artifact(frame)
        if rng.random() < 0.05:
            run.abort("operator cancelled")
            continue
        t0 = time.perf_counter()
        r = run.finish()
        latency = time.perf_counter() - t0
        os.write(fd, f"{r.uid} {latency:.6f} {time.time():.6f}\n".encode())
        os.fsync(fd)
    os.close(fd)
    store.close()


@dataclass
class Outcome:
    finished_reported: int = 0  # runs the writers were told finished
    complete: int = 0  # finished runs in the store with all their data
    aborted: int = 0  # aborted runs (operator or dead writer), no data
    dead: int = 0  # of those: a killed writer's, marked aborted on the reopen
    lost: int = 0  # reported finished, not in the store
    duplicated: int = 0  # reported finished, more than once in the store
    half_written: int = 0  # in the store with part of its data, or still "running"
    kills: int = 0
    wall_s: float = 0.0
    latencies: list[float] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)

    @property
    def runs_per_s(self) -> float:
        return self.finished_reported / self.wall_s if self.wall_s else 0.0

    def percentile(self, q: float) -> float:
        xs = sorted(self.latencies)
        return xs[min(len(xs) - 1, int(q * len(xs)))] if xs else float("nan")


def _spawn(url, seed, count, done, frame) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, str(HERE), url, str(seed), str(count), str(done), str(frame)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def run_writers(url: str, folder: Path, n_procs: int = 8, per_proc: int = 50, kills: int = 0, seed: int = 1) -> Outcome:
    """``n_procs`` writers of ``per_proc`` runs each at once; with ``kills``, that many SIGKILLs
    at random moments (each killed writer replaced by a fresh one), then the check."""
    from vts_hw.store import ResultsStore

    rng = random.Random(seed)
    folder.mkdir(parents=True, exist_ok=True)
    frame = folder / "frame.jpg"
    frame.write_bytes(os.urandom(2048))
    ResultsStore(url).close()  # the schema first: the writers measure writing, not creating
    done = folder / "done.txt"
    done.write_text("")
    out = Outcome()
    procs = [_spawn(url, seed * 1000 + i, per_proc, done, frame) for i in range(n_procs)]
    opened = [float(p.stdout.readline().split()[1]) for p in procs]
    next_seed = seed * 1000 + n_procs
    while out.kills < kills:
        time.sleep(rng.uniform(0.02, 0.25))
        alive = [p for p in procs if p.poll() is None]
        if not alive:
            break
        victim = rng.choice(alive)  # anywhere: starting, opening, inside a run, between runs
        victim.kill()
        victim.wait()
        out.kills += 1
        procs.append(_spawn(url, next_seed, per_proc // 2, done, frame))  # the load goes on
        next_seed += 1
    for p in procs:
        _, err = p.communicate(timeout=300)
        if p.returncode not in (0, -9):
            out.problems.append(f"writer exit {p.returncode}: {err.strip()[-500:]}")
    lines = [ln.split() for ln in done.read_text().splitlines() if ln.strip()]
    out.finished_reported = len(lines)
    out.latencies = [float(x[1]) for x in lines]
    out.wall_s = (max(float(x[2]) for x in lines) - min(opened)) if lines else 0.0
    check(url, frame, [x[0] for x in lines], out)
    return out


def check(url: str, frame: Path, reported: list[str], out: Outcome) -> None:
    """Open the store (which marks dead writers' runs aborted) and check every run."""
    import hashlib

    from vts_hw.store import ResultsStore

    sha = hashlib.sha256(frame.read_bytes()).hexdigest()
    with ResultsStore(url) as store:
        runs = store.runs(procedure="writer")
        ms = {}
        for m in store.measurements(procedure="writer"):
            ms[m.run_id] = ms.get(m.run_id, 0) + 1
        by_uid = {}
        for r in runs:
            by_uid.setdefault(r.uid, []).append(r)
            n = int(r.notes.split("=")[1].split()[0]) if r.notes.startswith("n=") else -1
            arts = store.artifacts(r.id)
            if r.status == "aborted":
                if ms.get(r.id, 0) or arts:
                    out.half_written += 1
                    out.problems.append(f"aborted run {r.uid} has data")
                else:
                    out.aborted += 1
                    out.dead += "ended without finishing" in r.notes
            elif r.status == "running" or ms.get(r.id, 0) != n or [a.sha256 for a in arts] != [sha]:
                out.half_written += 1
                out.problems.append(
                    f"run {r.uid}: {r.status}, {ms.get(r.id, 0)} of {n} measurements, {len(arts)} artifacts"
                )
            else:
                out.complete += 1
    for uid in reported:
        got = by_uid.get(uid, [])
        if not got:
            out.lost += 1
            out.problems.append(f"run {uid} reported finished but not stored")
        elif len(got) > 1:
            out.duplicated += 1
    if len(set(reported)) != len(reported):
        out.duplicated += len(reported) - len(set(reported))
        out.problems.append("a uid reported finished twice")


if __name__ == "__main__":
    a = sys.argv[1:]
    writer_main(a[0], int(a[1]), int(a[2]), a[3], a[4])
