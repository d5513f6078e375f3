"""Simulated patient scans through the real path, with frames lost in bursts (bench/motion_under_loss.py).

One simulated rig per seed (``PatientRig``): the reference room's cameras on 127.0.0.1 (the
simulated Axis cameras over HTTP), a breathing patient on the table with body moves planned
after the live reference, and every camera's frames for the scan **made ahead of time**
(``SimRig.prerender``) so that the renderer adds no loss of its own: the only frames missing
are the ones the declared loss fault drops (``Faults.lose_burst_frames`` every
``lose_burst_every_s``: every camera at the same moments, as behind one congested switch).
Per loss pattern the stretch is rewound (``FrameBank.rewind``) and ``vts scan start`` (a
subprocess, live tracking on) records it once per camera count, the scans of one pattern at
the same time (they share the rig, its faults and its patient); then ``vts motion analyze
--export`` (a subprocess at lower priority, so that it yields to the scans that follow) reads
each session. :func:`cpu_load` starts spinning processes on every core and stops them at the
end, also on Ctrl-C.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from vts_hw.sim_devices.patient import BodyMove, add_patient
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scenarios.sync_session import run_scan_cli

REFERENCE_S = 10.0  # the live reference (vts scan start --reference)
AHEAD_MARGIN_S = 8.0  # frames made ahead beyond the scan: its start, and scans starting apart
SPIN = "import signal, sys\nsignal.signal(signal.SIGTERM, lambda *a: sys.exit(0))\nwhile True:\n    pass\n"
MOTION_EXIT = (0, 10, 20)  # vts motion analyze ran: OK, TOLERANCE, ACTION


@contextlib.contextmanager
def cpu_load(n: int):
    """``n`` spinning processes (plain busy Python at the scans' priority) for the block; ended
    when it ends, on an exception or Ctrl-C included (SIGTERM to this process too)."""
    old = signal.signal(signal.SIGTERM, _interrupt)
    procs = []
    try:
        procs = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(n)]
        yield [p.pid for p in procs]
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        signal.signal(signal.SIGTERM, old)


def _interrupt(*_):
    raise KeyboardInterrupt


def burst_faults(loss: float, seed: int, fps: float = 25.0) -> dict:
    """The loss fault for a share ``loss`` of the time: bursts of about a second (0.7-1.3 s,
    drawn from ``seed``) in every camera, as often as the share needs."""
    if loss <= 0:
        return {"lose_burst_frames": 0, "lose_burst_every_s": 0.0}
    rng = np.random.default_rng([seed, int(round(1000 * loss)), 47])
    n = max(1, int(round(fps * rng.uniform(0.7, 1.3))))
    return {"lose_burst_frames": n, "lose_burst_every_s": round(n / fps / loss, 3)}


def plan_moves(t0: float, seconds: float, seed: int) -> list[BodyMove]:
    """Body moves from ``REFERENCE_S`` + 7 s after ``t0`` on, about 11 s apart (±1.5 s), the last
    ending 4 s before the scan does: 2.5-8 mm, 0.3-2 deg, over 0.4-1.0 s, in random directions."""
    rng = np.random.default_rng([seed, 53])
    moves, at = [], REFERENCE_S + 7.0
    while at + 5.0 < seconds:
        start = t0 + at + rng.uniform(-1.5, 1.5)
        d, axis = rng.normal(size=3), rng.normal(size=3)
        trans = rng.uniform(2.5, 8.0) * d / np.linalg.norm(d)
        rot = rng.uniform(0.3, 2.0) * axis / np.linalg.norm(axis)
        moves.append(BodyMove(start, start + rng.uniform(0.4, 1.0), tuple(map(float, rot)), tuple(map(float, trans))))
        at += 11.0
    return moves


@dataclass
class Scan:
    """One scan of a loss pattern: its session, what ran it, and how it ended."""

    cameras: int
    session: Path
    rig_yaml: Path
    returncode: int | None = None
    err: str = ""
    wall_s: float = 0.0
    manifest: dict = field(default_factory=dict)
    analysis: dict | None = None  # `vts motion analyze --json`, or None
    export: Path | None = None
    analysis_error: str = ""
    analysis_wall_s: float = 0.0
    truth: object = None  # rows.slot_truth: the truth of this scan


class PatientRig:
    """A simulated rig of ``max(cameras)`` cameras with a breathing, moving patient, and a
    rig.yaml per camera count (the first N cameras; calibration.json for two, cameras.json for
    more); the frames of ``seconds`` + ``AHEAD_MARGIN_S`` made ahead by :meth:`prerender`."""

    def __init__(self, seed: int, seconds: float, cameras, work: Path):
        self.seed, self.seconds, self.cameras = seed, float(seconds), sorted(set(cameras))
        self.work = Path(work)
        self.rig = SimRig(n_cameras=max(self.cameras), seed=seed).start()
        try:
            self.rig.ntp_sync()
            base, _ = self.rig.write(self.work / "rig")
            cfg = yaml.safe_load(base.read_text())
            self.yamls = {}
            for n in self.cameras:
                c = dict(cfg, cameras=cfg["cameras"][:n])
                c["calibration"] = dict(
                    cfg["calibration"],
                    cameras=str(self.work / "rig" / ("calibration.json" if n == 2 else "cameras.json")),
                )
                self.yamls[n] = self.work / f"rig-{n}cams.yaml"
                self.yamls[n].write_text(yaml.safe_dump(c))
            now = self.rig.clock.now()
            self.patient = add_patient(
                self.rig.scene, now, self.seconds + 600.0, seed=seed, moves=plan_moves(now, self.seconds, seed)
            )
        except BaseException:
            self.rig.stop()
            raise
        self.stats = None

    @property
    def env(self) -> dict:
        return self.rig.env_vars()

    def prerender(self):
        self.stats = self.rig.prerender(self.seconds + AHEAD_MARGIN_S)
        return self.stats

    def set_faults(self, faults: dict) -> None:
        for srv in self.rig.servers.values():
            srv.faults.reset()
            srv.faults.update(faults)

    def lost(self, name: str, t: float) -> bool:
        """Whether camera ``name``'s frame captured at host time ``t`` is lost by its fault."""
        period = 1.0 / self.rig.fps
        g = int(round(t / period))
        return self.rig.servers[name].faults.lost(name, g, g * period, period)

    def scan(self, faults: dict, work: Path, label: str, cameras=None) -> list[Scan]:
        """The stretch rewound, ``faults`` on every camera, one ``vts scan start`` per camera
        count at the same time; returns the scans (manifests read)."""
        self.rig.bank.rewind()
        self.set_faults(faults)
        scans = [Scan(n, Path(work) / f"{label}-{n}cams", self.yamls[n]) for n in (cameras or self.cameras)]
        threads = [threading.Thread(target=self._one, args=(s,), daemon=True) for s in scans]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        return scans

    def _one(self, s: Scan) -> None:
        t0 = time.monotonic()
        try:
            run = run_scan_cli(
                self.rig,
                s.rig_yaml,
                s.session,
                self.seconds,
                args=("--reference", f"{REFERENCE_S:g}"),
                event="scan",
                check=False,
                timeout=self.seconds + 240.0,
            )
            s.returncode, s.err = run.returncode, run.err
        except (RuntimeError, TimeoutError, subprocess.SubprocessError) as exc:
            s.err = str(exc)
        s.wall_s = time.monotonic() - t0
        try:
            s.manifest = json.loads((s.session / "manifest.json").read_text())
        except (OSError, ValueError) as exc:
            s.err += f"\nmanifest: {exc}"

    def stop(self) -> None:
        self.rig.stop()


def analyze(s: Scan, env: dict, nice: int = 10, procs: list | None = None) -> Scan:
    """``vts motion analyze SESSION --config RIG --export DIR --json --workers 1`` at lower
    priority; fills ``s.analysis`` (its JSON) or ``s.analysis_error``. ``procs``: the running
    process is kept there while it runs (to be ended on Ctrl-C)."""
    s.export = s.session.parent / (s.session.name + "-export")
    cmd = [
        sys.executable,
        "-m",
        "vts_hw.cli.__main__",
        "motion",
        "analyze",
        str(s.session),
        "--config",
        str(s.rig_yaml),
        "--export",
        str(s.export),
        "--json",
        "--workers",
        "1",
    ]
    t0 = time.monotonic()
    p = subprocess.Popen(
        cmd,
        env={**os.environ, **env},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: os.nice(nice),
    )
    if procs is not None:
        procs.append(p)
    try:
        out, err = p.communicate()
    finally:
        if procs is not None:
            procs.remove(p)
    s.analysis_wall_s = time.monotonic() - t0
    if p.returncode in MOTION_EXIT:
        try:
            s.analysis = json.loads(out)
        except ValueError as exc:
            s.analysis_error = f"vts motion analyze --json printed no JSON ({exc})"
    else:
        s.analysis_error = f"vts motion analyze exit {p.returncode}: {err.strip()[-500:]}"
    return s
