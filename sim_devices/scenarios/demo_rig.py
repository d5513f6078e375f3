"""The demo's two live parts on a simulated rig: the camera tour and the scan with its sync check.

:func:`camera_tour` brings up two simulated Axis cameras on 127.0.0.1, reads each one's device
info and clock offset through the real driver, takes an LED-off and an LED-on snapshot and
records both for a few seconds. :func:`demo_scan` runs `vts scan start` against a rig with the
trigger-box firmware in the emulator while a source marker moves along the table, lets the
simulated SPECT follow the trigger, then runs `vts sync analyze` and scores each move against
the truth. `vts demo` prints what these return; a script gets the same figures.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw.drivers.axis import AxisCamera
from vts_hw.files import check_folder, write_atomic
from vts_hw.lifeline import child_options
from vts_hw.recording.capture import FrameRecorder
from vts_hw.recording.promised import info
from vts_hw.room import Room
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scenarios import sync_session as sync_sim
from vts_hw.sim_devices.source_marker import SourceMarker

SYNC_EXIT_CODES = (0, 10, 20)  # OK, TOLERANCE, ACTION: the analysis ran


@dataclass
class CameraLook:
    name: str
    product: str
    firmware: str
    vapix: str
    clock_offset_s: float
    lit: Path  # the LED-on snapshot
    dark: Path  # the LED-off snapshot
    lit_bright_px: int  # pixels above 128 in each
    dark_bright_px: int


@dataclass
class CameraTour:
    base_urls: dict[str, str]
    cameras: list[CameraLook]
    recording: Path
    manifest: dict
    streams: list = field(default_factory=list)  # recording.promised.info(): per camera frames, fps, gaps


def _record_plainly(rec, seconds: float) -> dict:
    rec.start()
    rec.wait()
    return rec.finish()


def camera_tour(
    out_dir, seconds: float, *, record: Callable | None = None, say: Callable[[str], None] = lambda m: None
) -> CameraTour:
    """Two simulated cameras through the real driver: info, clock, LED snapshots, a recording of
    ``seconds``. ``record(recorder, seconds) -> manifest`` runs the recording (default: to its
    end, silently; the CLI passes its progress display)."""
    out_dir = Path(out_dir)
    looks = []
    with SimRig(n_cameras=2) as rig, rig.env():
        rig.write(out_dir / "sim")
        cfg = rig.config()
        urls = {c.name: c.base_url for c in cfg.cameras}
        say(f"simulated rig up: {', '.join(f'{n} at {u}' for n, u in urls.items())}")
        with Room(cfg) as room:  # its cameras closed with it
            cams = room.cameras
            for cam in cams:
                if not isinstance(cam, AxisCamera):  # a simulated rig's cameras are Axis cameras
                    raise RuntimeError(f"camera {cam.name}: not an Axis camera, no LED or VAPIX version to show")
                dev = cam.device_info()
                off = cam.clock_offset()
                cam.led_off()
                dark = cam.snapshot()
                cam.led_on()
                time.sleep(0.05)
                lit = cam.snapshot()
                lit_path, dark_path = out_dir / f"{cam.name}-led-on.jpg", out_dir / f"{cam.name}-led-off.jpg"
                write_atomic(dark_path, dark.jpeg)
                write_atomic(lit_path, lit.jpeg)
                looks.append(
                    CameraLook(
                        cam.name,
                        dev.get("ProdNbr", "?"),
                        dev.get("Version", "?"),
                        str(cam.vapix_version),
                        off.offset_s,
                        lit_path,
                        dark_path,
                        bright_pixels(lit.jpeg),
                        bright_pixels(dark.jpeg),
                    )
                )
            rec_dir = out_dir / "recording"
            if check_folder(rec_dir, "demo's recording folder"):  # a link, FIFO or device there: refused
                shutil.rmtree(
                    rec_dir
                )  # the demo's own recording from an earlier run: a recording refuses a full folder
            say(f"recording {seconds:g} s from {len(cams)} cameras into {rec_dir} ...")
            manifest = (record or _record_plainly)(
                FrameRecorder(cams, rec_dir, seconds=seconds, meta={"rig": cfg.rig}), seconds
            )
    return CameraTour(urls, looks, rec_dir, manifest, list(info(rec_dir)))


def bright_pixels(jpeg: bytes) -> int:
    import cv2
    import numpy as np

    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ValueError("the camera's snapshot is not a JPEG")
    return int(np.count_nonzero(img > 128))


@dataclass
class DemoScan:
    run: object  # sync_session.SimSyncScan: the session, list-mode and truth
    rig_yaml: Path
    report: Path
    data: dict  # `vts sync analyze --json`
    moves: list[dict]  # per true move: found, errors of each system (s), seen_by


def demo_scan(out_dir, seconds: float, *, say: Callable[[str], None] = lambda m: None) -> DemoScan:
    """A scan of ``seconds`` with three moves of a source marker, then the sync check.
    RuntimeError with the analysis's own message when it did not run."""
    out_dir = Path(out_dir)
    scan_dir = out_dir / "scan"
    if scan_dir.exists():
        shutil.rmtree(scan_dir)  # a scan refuses a folder that is not empty
    rig = SimRig(n_cameras=2, seed=3, trigger="triggerbox").start()
    try:
        rig_yaml, _ = rig.write(out_dir / "scan-rig")
        marker = sync_sim.prepare(rig)
        say(
            f"vts scan start --duration {seconds:g} -o {scan_dir}  (trigger box firmware in the "
            "emulator; a source marker moved along the table)"
        )
        run = sync_sim.cli_scan(rig, rig_yaml, scan_dir, seconds, marker, n=3, seed=1)
    finally:
        rig.stop()
    report = out_dir / "sync-report.html"
    cmd = [
        sys.executable,
        "-m",
        "vts_hw.cli.__main__",
        "sync",
        "analyze",
        str(run.session),
        "--listmode",
        str(run.listmode),
        "--config",
        str(rig_yaml),
        "-o",
        str(report),
        "--export",
        str(out_dir / "trajectories"),
        "--json",
    ]
    say(f"vts sync analyze {run.session} --listmode {run.listmode} -o {report}")
    p = subprocess.run(cmd, capture_output=True, text=True, **child_options())
    if p.returncode not in SYNC_EXIT_CODES:
        raise RuntimeError(f"the sync analysis failed (exit {p.returncode}): {p.stderr.strip()}")
    data = json.loads(p.stdout)
    if not isinstance(run.source, SourceMarker):  # sync_session.prepare placed one
        raise RuntimeError("the sync scan has no source marker to match the moves of")
    return DemoScan(run, Path(rig_yaml), report, data, sync_sim.match_moves(data["events"], run.source.moves))
