"""Fuzz every parser of outside bytes; print inputs and crashes per parser (issue 10).

    .venv/bin/python bench/fuzz.py                      # 100,000 inputs per parser
    .venv/bin/python bench/fuzz.py --runs 2000 --only manifest,rig_yaml --crashes crashes/

The parsers: the files (MJPEG, Axis JPEG, recording index and manifest, list-mode, Interfile,
DICOM, .npz, calibration and mapping JSON, rig.yaml, trigger.csv, SPECT points, trajectories,
a step session's positions.json, unsaved runs, list-mode failure records) and the devices' replies, each input a
transcript of what the device answers a driver's session (bench/fuzzkit/devices.py: the Axis
camera's VAPIX replies, the trigger box's serial lines, the 33500's SCPI replies, QATrack+'s
JSON). Each parser (bench/fuzzkit/targets.py) is fed ``--runs`` inputs by a coverage-guided fuzzer,
atheris (libFuzzer), seeded with real and generated valid inputs (bench/fuzzkit/seeds.py);
where atheris cannot be imported, hypothesis generates and mutates the inputs instead
(``--engine hypothesis``). A ``VtsError`` (ConfigError, DataError, ...) is the answer the
project promises for a bad input: it counts as handled. Any other exception is a crash: it is
counted per crash site (exception type and the innermost line of our code), the first inputs
of each site are saved under ``--crashes`` with their traceback, and the run goes on, so the
table's figures are real. A hang (``--timeout`` s on one input) or running out of memory ends
the fuzzing process: it counts as a crash, its input is saved, and a new process carries on
with the rest of the inputs.

atheris runs one ``Fuzz()`` per process, so every target runs in a child process of its own
(``--child NAME``). Exit status: 0 when no parser crashed, 1 otherwise.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import struct
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

from fuzzkit.targets import TARGETS, Scratch, import_parsers  # noqa: E402

STATS = struct.Struct("<QQQ")  # inputs run, inputs answered with a typed error, crashes
OURS = ("vts_hw/", "drivers/", "procedures/", "sim_devices/")


# ------------------------------------------------------------------------------ the child


class CrashRecorder:
    """Runs one input through a target and keeps the counts where the parent can read them,
    also when libFuzzer ends the process without returning (it does, after -runs)."""

    def __init__(self, name: str, work: Path, crashes: Path, runs: int, keep: int):
        self.target = TARGETS[name]
        self.scratch = Scratch(work / "fixtures" / name, self.target.fixtures)
        self.runs, self.keep = runs, keep
        self.crash_dir = crashes / name
        self.sites_path = work / f"{name}.sites.json"
        self.sites: dict[str, dict] = json.loads(self.sites_path.read_text()) if self.sites_path.exists() else {}
        self.fd = os.open(work / f"{name}.stats", os.O_RDWR | os.O_CREAT | os.O_TRUNC, 0o644)
        self.n = self.handled = self.crashes = 0
        self.saved = sum(min(s["count"], keep) for s in self.sites.values())

    def __call__(self, data: bytes) -> None:
        self.n += 1
        before = self.scratch.handled
        try:
            self.target.run(data, self.scratch)
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # noqa: BLE001 - every escape is what we count
            self.crash(data, exc)
        if self.scratch.handled > before:
            self.handled += 1
        os.pwrite(self.fd, STATS.pack(self.n, self.handled, self.crashes), 0)
        if self.n >= self.runs or self.n % 2000 == 0:
            self.flush()

    def crash(self, data: bytes, exc: BaseException) -> None:
        self.crashes += 1
        site, where = crash_site(exc)
        s = self.sites.get(site)
        new = s is None
        if new:
            s = self.sites[site] = {
                "count": 0,
                "message": f"{type(exc).__name__}: {exc}"[:300],
                "where": where,
                "inputs": [],
            }
        s["count"] += 1
        if len(s["inputs"]) < self.keep and self.saved < 10 * self.keep:
            self.crash_dir.mkdir(parents=True, exist_ok=True)
            stem = f"{hashlib.sha1(site.encode()).hexdigest()[:8]}-{len(s['inputs'])}"
            (self.crash_dir / f"{stem}.bin").write_bytes(data)
            (self.crash_dir / f"{stem}.txt").write_text(f"{site}\n\n" + "".join(traceback.format_exception(exc)))
            s["inputs"].append(str(self.crash_dir / f"{stem}.bin"))
            self.saved += 1
        if new:
            self.flush()

    def flush(self) -> None:
        tmp = self.sites_path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.sites, indent=1))
        os.replace(tmp, self.sites_path)


def crash_site(exc: BaseException) -> tuple[str, str]:
    """(site, where): the exception type at the innermost line of our own code, and the last
    frames of the traceback in short."""
    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if any(o in f.filename.replace(os.sep, "/") for o in OURS)]
    f = (ours or frames or [None])[-1]
    at = "?" if f is None else f"{_short(f.filename)}:{f.lineno}"
    where = " <- ".join(f"{_short(x.filename)}:{x.lineno} {x.name}" for x in reversed(frames[-4:]))
    return f"{type(exc).__name__} at {at}", where


def _short(filename: str) -> str:
    p = filename.replace(os.sep, "/")
    for o in OURS:
        i = p.rfind("/" + o)
        if i >= 0:
            return p[i + 1 :]
    return p.rsplit("site-packages/", 1)[-1]


def child(args) -> None:
    import warnings

    warnings.simplefilter("ignore")  # pydicom and numpy warn about bad files: not crashes
    work, name = Path(args.work), args.child
    target = TARGETS[name]
    if args.engine == "atheris":
        import atheris

        with atheris.instrument_imports(include=list(target.instrument)):
            import_parsers(target.uses)
        rec = CrashRecorder(name, work, Path(args.crashes), args.runs, args.keep)
        live = work / "live" / name
        live.mkdir(parents=True, exist_ok=True)
        art = work / "artifacts" / name
        art.mkdir(parents=True, exist_ok=True)
        dict_path = work / f"{name}.dict"
        dict_path.write_text("".join('"' + "".join(f"\\x{b:02x}" for b in tok) + '"\n' for tok in target.tokens))
        flags = [
            f"-runs={args.runs}",
            f"-seed={args.seed}",
            f"-max_len={target.max_len}",
            f"-timeout={args.timeout}",
            "-rss_limit_mb=3072",
            f"-artifact_prefix={art}/",
            "-use_value_profile=1",
            "-print_final_stats=1",
        ]
        if target.tokens:
            flags.append(f"-dict={dict_path}")
        atheris.Setup([sys.argv[0], *flags, str(live), str(work / "seeds" / name)], rec)
        atheris.Fuzz()  # does not return: libFuzzer exits after -runs
    else:
        import_parsers(target.uses)
        rec = CrashRecorder(name, work, Path(args.crashes), args.runs, args.keep)
        from fuzzkit.mutate import run_hypothesis

        run_hypothesis(rec, work / "seeds" / name, target, args.runs, args.seed, args.timeout)
        rec.flush()


# ------------------------------------------------------------------------------ the parent


def fuzz_target(name: str, args, work: Path, crashes: Path) -> dict:
    """Fuzz one target with ``args.runs`` inputs, over as many child processes as it takes."""
    stats = work / f"{name}.stats"
    log = work / f"{name}.log"
    art = work / "artifacts" / name
    for p in (stats, work / f"{name}.sites.json"):
        p.unlink(missing_ok=True)
    shutil.rmtree(work / "live" / name, ignore_errors=True)
    shutil.rmtree(art, ignore_errors=True)
    done = handled = crashed = 0
    fatal: dict[str, dict] = {}
    stalls = 0
    t0 = time.monotonic()
    with open(log, "w") as logf:
        while done < args.runs:
            cmd = [
                sys.executable,
                str(Path(__file__).resolve()),
                "--child",
                name,
                "--runs",
                str(args.runs - done),
                "--work",
                str(work),
                "--crashes",
                str(crashes),
                "--engine",
                args.engine,
                "--seed",
                str(args.seed + done),
                "--keep",
                str(args.keep),
                "--timeout",
                str(args.timeout),
            ]
            logf.write(f"$ {' '.join(cmd)}\n")
            logf.flush()
            rc = subprocess.call(cmd, stdout=logf, stderr=logf, cwd=work)
            n, h, c = (
                STATS.unpack(stats.read_bytes()[: STATS.size])
                if stats.exists() and stats.stat().st_size >= STATS.size
                else (0, 0, 0)
            )
            done, handled, crashed = done + n, handled + h, crashed + c
            if rc == 0 and n > 0:
                continue
            if rc != 0:  # a hang, out of memory or a fatal signal: libFuzzer saved the input
                kind = _fatal_kind(art, rc)
                s = fatal.setdefault(
                    f"{kind} (the fuzzing process ended)",
                    {"count": 0, "message": f"exit status {rc}; see {log}", "where": "", "inputs": []},
                )
                s["count"] += 1
                crashed += 1
                for a in sorted(art.glob("*")):
                    dest = crashes / name / f"{kind}-{a.name}"
                    dest.parent.mkdir(parents=True, exist_ok=True)
                    shutil.move(str(a), dest)
                    s["inputs"].append(str(dest))
            stalls = stalls + 1 if n == 0 else 0
            if stalls >= 3:
                raise SystemExit(f"fuzz.py: the {name} fuzzer does not run (see {log})")
    sites = json.loads((work / f"{name}.sites.json").read_text()) if (work / f"{name}.sites.json").exists() else {}
    sites.update(fatal)
    return {
        "target": name,
        "inputs": done,
        "handled": handled,
        "crashes": crashed,
        "sites": sites,
        "seconds": round(time.monotonic() - t0, 1),
    }


def _fatal_kind(art: Path, rc: int) -> str:
    names = [a.name for a in art.glob("*")]
    for prefix, kind in (("timeout-", "timeout"), ("oom-", "out of memory"), ("slow-unit-", "timeout")):
        if any(n.startswith(prefix) for n in names):
            return kind
    return f"fatal error (exit {rc})"


def print_table(results: list[dict], engine: str, runs: int) -> None:
    print(
        f"\nfuzz.py: {engine}, {runs:,} inputs per parser; a typed error (VtsError) is handled, "
        "any other exception a crash"
    )
    w = max([16, *(len(r["target"]) for r in results)])
    head = f"{'parser':<{w}} {'inputs':>9} {'typed errors':>12} {'crash sites':>11} {'crashes':>8} {'seconds':>8}"
    print(head)
    print("-" * len(head))
    for r in results:
        print(
            f"{r['target']:<{w}} {r['inputs']:>9} {r['handled']:>12} {len(r['sites']):>11} "
            f"{r['crashes']:>8} {r['seconds']:>8.1f}"
        )
    total = sum(r["crashes"] for r in results)
    print("-" * len(head))
    print(
        f"{'total':<{w}} {sum(r['inputs'] for r in results):>9} "
        f"{sum(r['handled'] for r in results):>12} {sum(len(r['sites']) for r in results):>11} "
        f"{total:>8} {sum(r['seconds'] for r in results):>8.1f}"
    )
    for r in results:
        for site, s in sorted(r["sites"].items(), key=lambda kv: -kv[1]["count"]):
            print(f"\n[{r['target']}] {site}: {s['count']} input(s)\n    {s['message']}")
            if s["where"]:
                print(f"    {s['where']}")
            for p in s["inputs"][:3]:
                print(f"    saved: {p}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=100_000, help="inputs per parser (100,000)")
    ap.add_argument("--only", default="", help=f"comma-separated targets: {', '.join(TARGETS)}")
    ap.add_argument("--crashes", default="crashes", help="folder for crashing inputs (./crashes)")
    ap.add_argument("--work", default=None, help="working folder (default: a temporary one)")
    ap.add_argument(
        "--engine",
        choices=("atheris", "hypothesis"),
        default=None,
        help="default: atheris when it can be imported, else hypothesis",
    )
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=int, default=10, help="seconds one input may take")
    ap.add_argument("--keep", type=int, default=3, help="crashing inputs saved per crash site")
    shared = Path(os.environ.get("VTS_SHARED_DATA", ROOT.parent / "shared" / "data"))
    ap.add_argument(
        "--frames",
        default=str(shared / "axis-frames"),
        help="the real Axis frames (../shared/data/axis-frames, or $VTS_SHARED_DATA)",
    )
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        child(args)
        return 0
    if args.engine is None:
        try:
            import atheris  # noqa: F401

            args.engine = "atheris"
        except ImportError:
            args.engine = "hypothesis"
    names = [n.strip() for n in args.only.split(",") if n.strip()] or list(TARGETS)
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        ap.error(f"unknown target(s) {', '.join(unknown)}; known: {', '.join(TARGETS)}")
    crashes = Path(args.crashes).resolve()
    own_work = args.work is None
    work = Path(args.work or tempfile.mkdtemp(prefix="vts-fuzz-work-")).resolve()
    work.mkdir(parents=True, exist_ok=True)
    from fuzzkit.seeds import make_seeds

    counts = make_seeds(work, Path(args.frames))
    print(f"seeds: {', '.join(f'{k} {v}' for k, v in counts.items())}; engine {args.engine}", flush=True)
    results = []
    for name in names:
        r = fuzz_target(name, args, work, crashes)
        print(f"  {name}: {r['inputs']} inputs, {r['crashes']} crashes, {r['seconds']} s", flush=True)
        results.append(r)
    print_table(results, args.engine, args.runs)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    if own_work:
        shutil.rmtree(work, ignore_errors=True)
    return 1 if any(r["crashes"] for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
