"""Record N simulated cameras at 25 fps and print dropped frames and frames per second.

    .venv/bin/python bench/record_cameras.py [--seconds 60] [--cameras 1 2 4 8] [--render live]

The simulated rig runs in a process of its own (as a real rig is other machines), the recorder
in this one, both on this machine. Per N it prints, per camera, frames recorded, frames
dropped (from the cameras' own timestamps), frames per second, and the ratio of frames
recorded to frames the cameras' clocks say they sent in that time. Goal: 0 dropped at N = 8.

The cameras' frames are made ahead of time (``vts sim up --ahead``) and served from memory, so
that the figures measure the recorder, as with real cameras, which cost the host nothing; what
rendering them costs is printed per N (ms of CPU per frame per camera, and the share of a core
rendering them live would take). ``--render live`` renders them as they are asked for instead.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from vts_hw.config import load_rig
from vts_hw.drivers.registry import open_cameras
from vts_hw.recording.capture import FrameRecorder
from vts_hw.recording.promised import info
from vts_hw.sim_devices.rig_detached import load_env_file, start_detached, stop_detached


def run(n: int, seconds: float, work: Path, ahead: bool = True) -> list[dict]:
    simdir = work / f"sim{n}"
    start_detached(simdir, n_cameras=n, seed=n, ahead=seconds + 5.0 if ahead else 0.0)
    try:
        if ahead:
            made = [ln for ln in (simdir / "sim.log").read_text().splitlines() if ln.startswith("frames made ahead")]
            print(f"{n:>3} {'':>7} rendering: {made[-1][len('frames made ahead: ') :] if made else 'not said'}")
        os.environ.update(load_env_file(simdir / "sim.env"))
        rig = load_rig(simdir / "rig.yaml")
        cams = open_cameras(rig.cameras)
        for cam in cams:
            cam.led_on()  # as a scan does (the frames made ahead have the LED rings on)
        rec_dir = work / f"rec{n}"
        rec = FrameRecorder(cams, rec_dir, seconds=seconds)
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
        rows.append(
            {
                "n": n,
                "camera": s.source,
                "frames": s.frames,
                "dropped": sum(g["missing"] for g in s.gaps),
                "reported_dropped": m["dropped_frames"],
                "fps": s.frames / wall,
                "ratio": s.frames / expected if expected else 0.0,
            }
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--cameras", type=int, nargs="+", default=[1, 2, 4, 8])
    ap.add_argument(
        "--render",
        choices=("ahead", "live"),
        default="ahead",
        help="the cameras' frames made ahead of time (default), or rendered live as they are asked for",
    )
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="vts-bench-") as tmp:
        print(
            f"recording simulated cameras at 25 fps for {args.seconds:g} s each, on {os.cpu_count()} cores, "
            f"frames {'made ahead of time' if args.render == 'ahead' else 'rendered live'}"
        )
        print(f"{'N':>3} {'camera':>7} {'frames':>7} {'dropped':>8} {'fps':>7} {'recorded/sent':>14}")
        for n in args.cameras:
            rows = run(n, args.seconds, Path(tmp), args.render == "ahead")
            for r in rows:
                print(
                    f"{r['n']:>3} {r['camera']:>7} {r['frames']:>7} {r['dropped']:>8} {r['fps']:>7.2f} "
                    f"{r['ratio']:>14.4f}"
                )
            total = sum(r["dropped"] for r in rows)
            print(
                f"{n:>3} {'all':>7} {sum(r['frames'] for r in rows):>7} {total:>8} "
                f"{sum(r['fps'] for r in rows):>7.2f}  {'OK' if total == 0 else 'DROPPED FRAMES'}"
            )


if __name__ == "__main__":
    main()
