"""The sync check on the simulated rig, end to end: a scan session with a moving source marker,
the simulated SPECT following the trigger the box actually emitted, and the truth to score it.

Used by tests/integration/test_sync.py and bench/sync_accuracy.py. The rig must be a running
``SimRig(trigger="triggerbox")`` whose ``write(folder)`` has been called (rig.yaml with the
true cameras' calibration files). Host UTC epoch seconds throughout.

The scan session switches the LED rings on through the driver; the source marker is placed before the
scan starts and its moves scheduled once the fire time is known, clear of the simulated
SPECT's head rotations (:func:`vts_hw.sim_devices.sync_truth.plan_sync_moves`).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from vts_hw.lifeline import child_options
from vts_hw.sim_devices.spect_listmode import ListModeTruth, SimListModeSpect
from vts_hw.sim_devices.sync_truth import place_source_marker, plan_sync_moves, schedule_source_moves

__all__ = [
    "SimSyncScan",
    "prepare",
    "start_moves",
    "simulate_spect",
    "match_moves",
    "cli_scan",
    "fire_time_of",
    "run_scan_cli",
    "ScanCli",
]

SPECT_TAIL_S = 0.6  # the SPECT acquisition ends this long before the scan (start delay ≤ 0.4 s)


@dataclass
class SimSyncScan:
    """What a simulated sync scan did: the session, the list-mode and the truth."""

    session: Path
    listmode: Path | None
    fire_host: float
    source: object  # SourceMarker: the moves (host s)
    spect: ListModeTruth | None


def prepare(rig, position=(10.0, -20.0, 5.0), rate_cps: float = 3000.0):
    """Clocks synced, a source marker at rest in the scene (the scan session switches the LED
    rings on). Returns its truth."""
    rig.ntp_sync()
    if "source" in rig.scene.bodies:
        raise ValueError("the scene already has a source marker")
    return place_source_marker(rig.scene, position=position, rate_cps=rate_cps)


def start_moves(
    rig, marker, fire_host: float, duration_s: float, n: int = 4, seed: int = 0, times_rel=None, steps=None
):
    """Schedule the source marker's moves for a scan fired at ``fire_host``: planned clear of
    the head rotations (``n``, ``seed``), or at ``times_rel`` s after the fire with ``steps``
    mm. Returns the truth."""
    if times_rel is None:
        times, steps = plan_sync_moves(fire_host, duration_s, n=n, seed=seed)
    else:
        times = [fire_host + float(x) for x in times_rel]
    if times[0] < time.time() + 0.3:
        raise RuntimeError("the first move would start in the past: the fire time came too late")
    return schedule_source_moves(rig.scene, marker, times, steps)


def fire_time_of(session: Path, timeout: float = 30.0, proc=None, event: str = "fire") -> float:
    """When a scan running in another process started, from its manifest (host s): the
    trigger's fire time (``event="fire"``), or the scan clock's start (``"scan"``: a rig
    without a trigger)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            m = json.loads((Path(session) / "manifest.json").read_text())
            if event == "fire":
                t = (m.get("trigger") or {}).get("fire_time")
                t = t if m["trigger"].get("fired") else None
            else:
                t = m["scan"]["times"].get("scan_started")
            if t is not None:
                return float(t)
        except (OSError, ValueError, KeyError, TypeError):
            pass
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"the scan process ended (exit {proc.returncode}) before it started")
        time.sleep(0.05)
    raise TimeoutError(f"{session}: the scan did not start within {timeout:g} s")


@dataclass
class ScanCli:
    """What :func:`run_scan_cli` saw: the start (host s), what ``on_fire`` returned, the exit
    status and the scan's own output."""

    fire: float
    planned: object
    returncode: int | None
    out: str
    err: str


def run_scan_cli(
    rig,
    rig_yaml,
    session,
    duration_s: float,
    *,
    args=(),
    event: str = "fire",
    on_fire=None,
    kill_after_s: float | None = None,
    timeout: float = 120.0,
    check: bool = True,
) -> ScanCli:
    """``vts scan start --duration D [ARGS] -o SESSION`` in a subprocess against the running
    ``rig`` (this process's simulated cameras and trigger box). ``on_fire(start)`` runs as soon
    as the manifest says the scan started (``event``: the trigger fired, or ``"scan"``: the
    scan clock started), to schedule what the scene does during the scan; its return comes
    back as ``planned``. ``kill_after_s``: SIGKILL the scan that long after the start (a crash:
    nothing closed). ``check``: RuntimeError with the scan's stderr when it exits other than
    0 or 4 (partial, a gap in the manifest: still analysable)."""
    env = {**os.environ, **rig.env_vars(), "VTS_CONFIG": str(rig_yaml)}
    cmd = [
        sys.executable,
        "-m",
        "vts_hw.cli.__main__",
        "scan",
        "start",
        "--duration",
        f"{duration_s:g}",
        *map(str, args),
        "-o",
        str(session),
    ]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **child_options())
    out = err = ""
    try:
        fire = fire_time_of(session, 60.0, proc, event)
        planned = on_fire(fire) if on_fire is not None else None
        if kill_after_s is not None:
            time.sleep(max(0.0, fire + kill_after_s - time.time()))
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)
        else:
            out, err = proc.communicate(timeout=timeout)
            if check and proc.returncode not in (0, 4):
                raise RuntimeError(f"vts scan start failed ({proc.returncode}): {err.strip()}")
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for f in (proc.stdout, proc.stderr):
            if f is not None:
                f.close()
    return ScanCli(fire, planned, proc.returncode, out, err)


def simulate_spect(
    rig, source, session: Path, duration_s: float, out: Path | None = None, seed: int = 0
) -> tuple[Path, ListModeTruth]:
    """The simulated SPECT's list-mode of the scan: it follows the trigger box's pins (the
    start pulse and square wave the emulator actually emitted) for ``duration_s`` list-mode s."""
    out = Path(out) if out else Path(session).parent / (Path(session).name + ".vtslm")
    truth = SimListModeSpect(rig.scene, [source], seed=seed).follow_trigger_box(rig.trigger_box, out, duration_s)
    return out, truth


def match_moves(events: list[dict], moves, window_s: float = 0.5) -> list[dict]:
    """Each true move with the reported event nearest its mid time (``events`` as in
    ``SyncAnalysis.results_data()["events"]``, host s): the VTS and SPECT event times minus the
    move's middle (the instant both systems should report), their difference and who saw it;
    ``found`` False when no event lies within ``window_s``."""
    rows = []
    for mv in moves:
        ev = min(events, key=lambda e: abs(_event_time(e) - mv.t_mid), default=None)
        if ev is None or abs(_event_time(ev) - mv.t_mid) > window_s:
            rows.append({"t_mid": mv.t_mid, "step_mm": mv.step_mm, "found": False})
            continue
        rows.append(
            {
                "t_mid": mv.t_mid,
                "step_mm": mv.step_mm,
                "found": True,
                "seen_by": ev["seen_by"],
                "vts_err_s": None if ev["t_vts"] is None else ev["t_vts"] - mv.t_mid,
                "spect_err_s": None if ev["t_spect"] is None else ev["t_spect"] - mv.t_mid,
                "dt_s": ev["dt_s"],
            }
        )
    return rows


def _event_time(e: dict) -> float:
    return e["t_spect"] if e["t_spect"] is not None else e["t_vts"]


def cli_scan(
    rig,
    rig_yaml,
    session,
    duration_s: float,
    marker,
    *,
    n: int = 4,
    seed: int = 0,
    times_rel=None,
    steps=None,
    kill_after_s: float | None = None,
    spect_s: float | None = None,
    timeout: float = 120.0,
) -> SimSyncScan:
    """``vts scan start --duration D -o SESSION`` in a subprocess against the running ``rig``
    (this process's simulated cameras and trigger box); the source marker's moves are
    scheduled as soon as the manifest says the trigger fired. ``kill_after_s``: SIGKILL the
    scan process that long after the fire (a crash: nothing is closed). Then the simulated
    SPECT follows the box for ``spect_s`` list-mode s (default: the scan less 0.6 s); ``seed``
    draws both the move plan and the SPECT (start delay, clock, counts)."""
    session = Path(session)
    run = run_scan_cli(
        rig,
        rig_yaml,
        session,
        duration_s,
        kill_after_s=kill_after_s,
        timeout=timeout,
        on_fire=lambda fire: start_moves(
            rig, marker, fire, kill_after_s or duration_s, n=n, seed=seed, times_rel=times_rel, steps=steps
        ),
    )
    fire, truth = run.fire, run.planned
    lm, spect = simulate_spect(rig, truth, session, spect_s or (kill_after_s or duration_s) - SPECT_TAIL_S, seed=seed)
    return SimSyncScan(session, lm, fire, truth, spect)
