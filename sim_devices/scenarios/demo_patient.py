"""The demo's patient scan: breathing, a body move, the live alert, the motion analysis and the
exports for reconstruction, each figure scored against the simulated patient's truth.

A simulated rig of two cameras with the trigger box in the emulator and a breathing patient
(still for ``still_s``, then one sudden body move) comes up on 127.0.0.1; `vts scan start`
records it with the live tracking on (the scenario :func:`patient_scan`, the cameras' frames made
ahead of time so that the recording is whole however busy the machine is); the simulated SPECT
writes the list-mode of the scan, counting the patient's heart; then `vts motion analyze
--listmode … --export …` puts the motion on the SPECT clock and writes the CASToR files.
:func:`demo_patient_scan` returns what `vts demo` prints: the alert's delay after the true
start of the move, the move as found against the truth, the breathing rate against the truth,
and the body pose error in still frames. What could make those figures rest on less than the
whole scan (frames the recording lacks, frames the cameras had to render live) is said plainly
before them (:func:`recording_notes`).
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vts_hw.lifeline import child_options
from vts_hw.sim_devices.patient_rig import PatientOptions
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scenarios.patient_scan import patient_scan

MOTION_EXIT_CODES = (0, 10, 20)  # OK, TOLERANCE, ACTION: the analysis ran


@dataclass
class DemoPatientScan:
    session: Path
    report: Path
    export: Path
    data: dict  # `vts motion analyze --json`
    move: dict  # the true move: start (host s, list-mode s), translation, rotation
    found: dict | None  # the event matching it: start error (s), size errors
    alerts: list[dict]  # the live alerts in the manifest, with their delay after the move
    rate_per_min: tuple[float, float]  # breathing rate: measured, true
    pose_error: tuple[float, float]  # body 6-DOF RMS in still frames: mm, deg
    notes: tuple[str, ...] = ()  # what degraded the recording, in plain words (none: whole)
    no_alert_why: str = ""  # with no live alert: why, from the manifest ("" : the live path watched and raised none)


def demo_patient_scan(
    out_dir, seconds: float = 30.0, *, say: Callable[[str], None] = lambda m: None
) -> DemoPatientScan:
    """The patient scan of ``seconds`` (at least 24), its analysis, scored against the truth.
    RuntimeError with the command's own message when a step fails."""
    out_dir = Path(out_dir)
    session = out_dir / "patient-scan"
    for old in (session, out_dir / "patient-scan.vtslm", out_dir / "patient-export"):
        if old.is_dir():
            shutil.rmtree(old)  # the demo's own files from an earlier run
        elif old.exists():
            old.unlink()
    move_at = max(16.0, 0.6 * seconds)  # after the live reference (10 s of tracking, from ~3 s into the plan)
    options = PatientOptions(
        seed=3, moves=1, minutes=max(1.0, (seconds + 60.0) / 60.0), still_s=6.0, move_at_s=(move_at,)
    )
    rig = SimRig(n_cameras=2, seed=5, trigger="triggerbox", patient=options).start()
    try:
        rig_yaml, _ = rig.write(out_dir / "patient-rig")
        say(f"making the cameras' frames for the scan ahead of time ({seconds:g} s, 2 cameras) ...")
        say(
            f"vts scan start --duration {seconds:g} -o {session}  (a breathing patient on the table, live "
            "tracking on; the body moves once)"
        )
        run = patient_scan(rig, rig_yaml, session, seconds, truth_dir=out_dir / "patient-truth")
        notes = recording_notes(session, rig.bank)
    finally:
        rig.stop()
    if run.render is not None:
        say(f"  frames made ahead: {run.render.line()}")
    for note in notes:
        say(f"  DEGRADED: {note}")
    report, export = out_dir / "motion-report.html", out_dir / "patient-export"
    cmd = [
        sys.executable,
        "-m",
        "vts_hw.cli.__main__",
        "motion",
        "analyze",
        str(session),
        "--listmode",
        str(run.listmode),
        "--config",
        str(rig_yaml),
        "-o",
        str(report),
        "--export",
        str(export),
        "--json",
    ]
    say(f"vts motion analyze {session} --listmode {run.listmode} -o {report} --export {export}")
    p = subprocess.run(cmd, capture_output=True, text=True, **child_options())
    if p.returncode not in MOTION_EXIT_CODES:
        raise RuntimeError(f"the motion analysis failed (exit {p.returncode}): {p.stderr.strip()}")
    data = json.loads(p.stdout)
    return _score(run, data, session, report, export, tuple(notes))


def recording_notes(session: Path, bank=None) -> list[str]:
    """Plain sentences for whatever makes the recording less than the whole scan: its status,
    frames missing per camera, and frames of the scan (from its start to its stop) that the
    simulated cameras rendered live, not ahead: on a busy machine those come late. Empty when
    the recording is whole."""
    m = json.loads((Path(session) / "manifest.json").read_text())
    notes = []
    if m.get("status") != "complete":
        problems = "; ".join((m.get("scan") or {}).get("problems") or []) or "no reason given"
        notes.append(f"the recording is {m.get('status')}: {problems}")
    for name, cam in sorted((m.get("cameras") or {}).items()):
        if cam.get("dropped_frames"):
            notes.append(
                f"camera {name} lost {cam['dropped_frames']} frame(s) in {len(cam.get('gaps') or [])} "
                "gap(s): the figures below rest on the time it saw, not the whole scan"
            )
    times = (m.get("scan") or {}).get("times") or {}
    if bank is not None:
        live = bank.missed_between(times.get("scan_started", float("-inf")), times.get("stopped", float("inf")))
        if live:
            why = ", ".join(f"{k}: {v}" for k, v in sorted(live.items()))
            notes.append(
                f"{sum(live.values())} frame(s) of the scan were rendered live, not ahead ({why}): "
                "on a busy machine they come late"
            )
    return notes


def _score(run, data, session, report, export, notes=()) -> DemoPatientScan:
    spect, patient = run.spect, run.patient
    (m,) = run.moves_in_window()
    t_list = float(spect.list_time(m.t_start))
    move = {
        "t_start_host": m.t_start,
        "t_start_list": t_list,
        "translation_mm": float(np.linalg.norm(m.translation_mm)),
        "rotation_deg": float(np.linalg.norm(m.rotation_deg)),
    }
    found = None
    if data["events"]:
        e = min(data["events"], key=lambda e: abs(e["t_start"] + data["time_origin"] - t_list))
        before = patient.six_dof(m.t_start - 0.1)
        after = patient.six_dof(m.t_end + 0.1)
        change = np.asarray(e["change_6dof"], float)
        true_change = after - before
        found = {
            "start_error_s": e["t_start"] + data["time_origin"] - t_list,
            "translation_error_mm": float(np.linalg.norm(change[:3] - true_change[:3])),
            "rotation_error_deg": float(np.linalg.norm(change[3:] - true_change[3:])),
            "events": len(data["events"]),
        }
    manifest = json.loads((session / "manifest.json").read_text())
    alerts = [{**a, "delay_s": a["raised"] - m.t_start} for a in manifest.get("live_motion", {}).get("alerts", [])]
    # breathing rate: the truth's cycles inside the recording
    a, b = run.window
    true_cycles = [
        c for c in patient.breathing.cycles if a <= c.t_start and c.t_start + c.period_s <= b and c.kind != "pause"
    ]
    true_rate = float(np.mean([60.0 / c.period_s for c in true_cycles])) if true_cycles else float("nan")
    rate = data["summary"].get("breathing_rate_per_min") or float("nan")
    return DemoPatientScan(
        session,
        report,
        export,
        data,
        move,
        found,
        alerts,
        (float(rate), true_rate),
        _pose_error(export / "motion_6dof.csv", spect, patient, m),
        notes,
        "" if alerts else unwatched_move(manifest.get("live_motion") or {}, m.t_start),
    )


def unwatched_move(lm: dict, t_start: float) -> str:
    """Why the live path could not alert for a move starting at host ``t_start``, from the
    manifest's ``live_motion``: off, no reference, or NOT TRACKING between the move's start and
    the moment its alert was due (``alert_after_s`` + 0.5 s later). "" when it was tracking then
    (a live alert missed: the figure that matters)."""
    if lm.get("status") != "on":
        return f"the live tracking was off ({lm.get('off_reason') or 'no reason given'})"
    summ = lm.get("summary") or {}
    if summ.get("phase") != "tracking":
        return f"the live tracking never learned its reference ({summ.get('reference') or summ.get('note') or ''})"
    due = t_start + float(lm.get("alert_after_s", 1.0)) + 0.5
    blind = [e for e in lm.get("not_tracking", []) if e["start"] < due and e["end"] > t_start]
    if blind:
        secs = sum(min(e["end"], due) - max(e["start"], t_start) for e in blind)
        reasons = sorted({r for e in blind for r in e.get("reasons", [])})
        return (
            f"NOT TRACKING for {secs:.1f} s of the {due - t_start:.1f} s its alert was due in "
            f"({'; '.join(reasons)}), and said so live"
        )
    return ""


def _pose_error(path: Path, spect, patient, move) -> tuple[float, float]:
    """Body 6-DOF RMS against the truth in the exported series, away from the move (±1 s)."""
    with open(path, newline="") as f:
        rows = [r for r in csv.DictReader(f) if r["quality"] == "ok"]
    t_host = spect.host_time(np.array([float(r["time_s"]) for r in rows]))
    six = np.array([[float(r[k]) for k in ("tx_mm", "ty_mm", "tz_mm", "rx_deg", "ry_deg", "rz_deg")] for r in rows])
    keep = (t_host < move.t_start - 1.0) | (t_host > move.t_end + 1.0)
    truth = np.array([patient.six_dof(float(t)) for t in t_host[keep]])
    err = six[keep] - truth
    return (
        float(np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1)))),
        float(np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1)))),
    )
