"""Record N simulated cameras at 25 fps and print dropped frames and frames per second.

    .venv/bin/python bench/record_cameras.py [--seconds 60] [--cameras 1 2 4 8]

The simulated rig runs in a process of its own (as a real rig is other machines), the recorder
in this one, both on this machine. Per N it prints, per camera, frames recorded, frames
dropped (from the cameras' own timestamps), frames per second, and the ratio of frames
recorded to frames the cameras' clocks say they sent in that time. Goal: 0 dropped at N = 8.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from vts_hw.config import load_rig
from vts_hw.drivers.registry import open_cameras
from vts_hw.recording.capture import Recorder
from vts_hw.recording.folder import info
from vts_hw.sim_devices.rig import load_env_file, start_detached, stop_detached


def run(n: int, seconds: float, work: Path) -> list[dict]:
    simdir = work / f"sim{n}"
    start_detached(simdir, n_cameras=n, seed=n)
    try:
        os.environ.update(load_env_file(simdir / "sim.env"))
        rig = load_rig(simdir / "rig.yaml")
        cams = open_cameras(rig.cameras)
        rec_dir = work / f"rec{n}"
        rec = Recorder(cams, rec_dir, seconds=seconds)
        t0 = time.monotonic()
        rec.start()
        rec.wait()
        wall = time.monotonic() - t0
        manifest = rec.finish()
    finally:
        stop_detached(simdir)
    rows = []
    for s in info(rec_dir):
        m = manifest["cameras"][s.source]
        span = (s.last_time - s.first_time) if s.frames > 1 else 0.0
        expected = round(span * 25) + 1 if s.frames else 0
        rows.append({"n": n, "camera": s.source, "frames": s.frames,
                     "dropped": sum(g["missing"] for g in s.gaps), "reported_dropped": m["dropped_frames"],
                     "fps": s.frames / wall, "ratio": s.frames / expected if expected else 0.0})
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--cameras", type=int, nargs="+", default=[1, 2, 4, 8])
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="vts-bench-") as tmp:
        print(f"recording simulated cameras at 25 fps for {args.seconds:g} s each, on {os.cpu_count()} cores")
        print(f"{'N':>3} {'camera':>7} {'frames':>7} {'dropped':>8} {'fps':>7} {'recorded/sent':>14}")
        for n in args.cameras:
            rows = run(n, args.seconds, Path(tmp))
            for r in rows:
                print(f"{r['n']:>3} {r['camera']:>7} {r['frames']:>7} {r['dropped']:>8} {r['fps']:>7.2f} "
                      f"{r['ratio']:>14.4f}")
            total = sum(r["dropped"] for r in rows)
            print(f"{n:>3} {'all':>7} {sum(r['frames'] for r in rows):>7} {total:>8} "
                  f"{sum(r['fps'] for r in rows):>7.2f}  {'OK' if total == 0 else 'DROPPED FRAMES'}")


if __name__ == "__main__":
    main()
