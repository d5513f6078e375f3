"""Live motion during `vts scan start` when frames are lost, on the simulated rig (two cameras
over HTTP, the CLI in a subprocess): a patient who does not breathe with both cameras cut off
the network for a second every three (the issue's busy host), and a camera switched off for
5 s. Whatever else this busy machine adds (the simulated cameras may fall behind), the live
path must learn its reference, alert for the move, say NOT TRACKING with the reason while it
is blind, raise a NOT TRACKING alert for the long stretch, and end with the exit status and
last line that say so. Assertions hold for any extra loss: they never ask the simulator to
keep up."""

from __future__ import annotations

import json
import sys
import threading
import time

import yaml

from inprocess_cli import vts
from test_live_scan import COMMAND
from vts_hw.sim_devices.patient import BodyMove, add_patient
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scenarios.sync_session import run_scan_cli

REFERENCE_S = 4.0
FPS = 10.0  # cameras at 10 fps: the simulator renders in this process on a busy machine


def _rig(tmp_path, breathing: bool):
    rig = SimRig(n_cameras=2, seed=3, fps=FPS).start()
    rig.ntp_sync()
    rig_yaml, _ = rig.write(tmp_path / "rig")
    cfg = yaml.safe_load(rig_yaml.read_text())
    cfg["motion"] = {"alert_command": [sys.executable, "-c", COMMAND, str(tmp_path / "alerts.txt")]}
    rig_yaml.write_text(yaml.safe_dump(cfg))
    patient = add_patient(rig.scene, time.time(), 120.0, seed=5, moves=[], breathing=breathing)
    return rig, rig_yaml, patient


def _scan(rig, rig_yaml, session, duration, on_fire):
    run = run_scan_cli(
        rig,
        rig_yaml,
        session,
        duration,
        args=("--reference", f"{REFERENCE_S:g}"),
        event="scan",
        on_fire=on_fire,
        check=False,
        timeout=duration + 120,
    )
    return run, json.loads((session / "manifest.json").read_text())


# the camera-off scan: tracking, 5 s off, tracked again; room on a busy machine (TRACKING came
# after more than 10 s once, under 4 busy processes on 2 cores, and 18 s left no room)
DURATION_S = 26.0


def _live_status(session) -> str | None:
    """The live path's state in the running scan's manifest (it is written as it changes)."""
    try:
        return json.loads((session / "manifest.json").read_text())["live_motion"]["state"]["status"]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _at(when: float, fn, *args):
    t = threading.Timer(max(0.0, when - time.time()), fn, args)
    t.daemon = True
    t.start()
    return t


def _overlaps(stretch: dict, a: float, b: float) -> float:
    return max(0.0, min(stretch["end"], b) - max(stretch["start"], a))


def _never_still_while_blind(err: str) -> None:
    """Every live line that is not TRACKING says so and never shows the body as still."""
    lines = [ln for ln in err.splitlines() if "live motion:" in ln and not ln.startswith("vts:")]
    assert lines
    for ln in lines:
        if "live motion: TRACKING" not in ln:
            assert "NOT TRACKING" in ln or "REFERENCE" in ln, ln
            assert "still, body" not in ln and ("body " not in ln or "motion since then NOT KNOWN" in ln), ln


def _last_line_says(run, manifest, session):
    """Exit 4 with the reason on the last line when the recording has gaps or the patient was not
    watched; 0 only when both are whole."""
    last = run.err.strip().splitlines()[-1]
    problem = manifest["scan"].get("live_problem")
    if manifest["status"] != "complete":
        assert run.returncode == 4 and f"is {manifest['status']}" in last
    elif problem:
        assert run.returncode == 4 and "the patient was not" in last and problem in last
    else:
        assert run.returncode == 0, run.err
    assert manifest["live_motion"]["summary"]["watched"] is (not problem)


def test_a_still_patient_through_bursts_of_lost_frames(tmp_path):
    """No breathing; both cameras off the network for 1 s at 1 s and at 7 s after the start
    (with the recorder reconnecting, each costs 2-3 s of frames), a 9 mm move at 8 s, inside
    the second: the reference is learned from the still markers between the gaps, the move
    alerts once frames come back, and every burst lies in a NOT TRACKING stretch (camera
    lost) in the manifest."""
    rig, rig_yaml, patient = _rig(tmp_path, breathing=False)
    bursts: list[tuple[float, float]] = []

    def on_fire(start):
        for at in (1.0, 7.0):
            bursts.append((start + at, start + at + 1.0))
            for name in ("cam1", "cam2"):
                _at(start + at, rig.servers[name].go_offline, 1.0)
        move = BodyMove(start + 8.0, start + 8.6, (0.0, 1.5, 0.0), (3.0, 8.0, 2.0))
        patient.motion.moves.append(move)
        return move

    try:
        run, m = _scan(rig, rig_yaml, tmp_path / "scan", 15.0, on_fire)
    finally:
        rig.stop()
    move = run.planned
    lm = m["live_motion"]
    s = lm["summary"]
    assert s["phase"] == "tracking", s
    assert s["reference"].startswith("reference: 8 markers in 2 band(s) (no breathing seen: fitted rigidly)")
    assert len(lm["alerts"]) >= 1 and lm["alerts"][0]["kind"] == "motion"
    a = lm["alerts"][0]
    assert a["move_mm"] > 3.0 and a["onset"] <= move.t_start + 0.6 <= a["raised"]
    # each burst (the recorder reconnecting makes it longer) lies in a NOT TRACKING stretch
    stretches = lm["not_tracking"]
    for b0, b1 in bursts:
        covered = sum(_overlaps(st, b0, b1) for st in stretches)
        assert covered >= 0.5 * (b1 - b0), (b0, b1, stretches)
    assert any(r.startswith("camera lost") for st in stretches for r in st["reasons"])
    tr = s["tracking"]
    assert tr["not_tracking_s"] >= 0.5 * sum(b - a for a, b in bursts)
    assert tr["not_tracking_stretches"] == len(stretches) + lm.get("not_tracking_more", 0)
    assert m["scan"]["problems"], "the gaps are listed"
    _never_still_while_blind(run.err)
    _last_line_says(run, m, tmp_path / "scan")
    assert "live motion: TRACKING " in run.out and "NOT TRACKING alert(s)" in run.out  # the summary's line


def test_a_camera_switched_off_mid_scan_is_not_tracking_and_alerts(tmp_path, capsys):
    """Camera 2 off the network for 5 s after the reference: NOT TRACKING (camera lost: cam2)
    as a stretch of its own, a NOT TRACKING alert as loud as a motion alert (ALERT line with
    the bell, the manifest, the alert command with its text), tracked again after it; the
    offline analysis of the same model agrees with the live poses despite the lost frames."""
    rig, rig_yaml, patient = _rig(tmp_path, breathing=True)
    off: list[float] = []
    session = tmp_path / "scan"

    def switch_off_once_tracking(start):
        # 6 s after the start, or later: once the live path says TRACKING (its reference
        # learned; on a busy machine that takes longer than the reference's 4 s), so that the
        # camera's absence is a lost camera, not a reference never learned
        deadline = start + DURATION_S - 5.0 - 3.0  # room for 5 s off and 3 s tracked again
        while time.time() < deadline:
            if time.time() >= start + 6.0 and _live_status(session) == "TRACKING":
                off.append(time.time())
                rig.servers["cam2"].go_offline(5.0)
                return
            time.sleep(0.1)

    def on_fire(start):
        threading.Thread(target=switch_off_once_tracking, args=(start,), daemon=True).start()

    try:
        run, m = _scan(rig, rig_yaml, session, DURATION_S, on_fire)
    finally:
        rig.stop()
    assert off, (
        "the live path was not TRACKING 8 s before the end: no camera was switched off",
        m["live_motion"]["state"],
    )
    t_off = off[0]
    lm = m["live_motion"]
    assert lm["summary"]["phase"] == "tracking"
    lost = max(lm["not_tracking"], key=lambda st: _overlaps(st, t_off, t_off + 5.0))
    assert _overlaps(lost, t_off, t_off + 5.0) >= 4.0, lm["not_tracking"]
    assert any(r.startswith("camera lost: cam2") for r in lost["reasons"]) and lost["alerted"], lost
    blind = lm["blind_alerts"]
    assert blind and all(b["kind"] == "not tracking" for b in blind)
    # the alert of the stretch the camera's absence lies in (on a busy machine that stretch may
    # have begun earlier, "frames too late", and been alerted then: one stretch, one alert)
    mine = [b for b in blind if abs(b["since"] - lost["start"]) < 1e-3]
    assert mine and mine[0]["not_tracking_s"] > lm["blind_alert_s"], (blind, lost)
    lines = [ln for ln in run.err.splitlines() if ln.startswith("ALERT PATIENT NOT TRACKED")]
    assert lines and all(ln.endswith("\a") for ln in lines)
    assert "PATIENT NOT TRACKED" in (tmp_path / "alerts.txt").read_text()
    assert "tracked again after" in run.err
    assert lm["state"]["status"] in ("TRACKING", "NOT TRACKING")
    assert lm["alerts"] == []  # breathing and a lost camera are no move
    _never_still_while_blind(run.err)
    _last_line_says(run, m, tmp_path / "scan")
    assert m["status"] == "partial"  # the camera's gap in the recording
    code, out, _ = vts(capsys, "motion", "analyze", session, "--config", rig_yaml, "--json", "--workers", "1")
    agree = json.loads(out)["live"]  # one model (issue 33): live = offline, frames lost or not
    assert agree["compared"] >= 0.9 * lm["summary"]["poses_kept"], agree
    assert agree["rms_mm"] <= 0.1 and agree["rms_deg"] <= 0.05, agree


def test_a_scan_that_learned_no_reference_says_so_and_exits_4(tmp_path):
    """A still patient and no SPECT mapping: the live path cannot tell the patient's markers
    from the wall's. It says REFERENCE, then NOT TRACKING (no reference) with a NOT TRACKING
    alert, and the scan ends with exit 4 and a last line saying the patient was not watched --
    never `complete` and 0 with nobody watching."""
    rig, rig_yaml, _ = _rig(tmp_path, breathing=False)
    cfg = yaml.safe_load(rig_yaml.read_text())
    cfg["calibration"]["mapping"] = None
    rig_yaml.write_text(yaml.safe_dump(cfg))
    try:
        run, m = _scan(rig, rig_yaml, tmp_path / "scan", 12.0, None)
    finally:
        rig.stop()
    lm = m["live_motion"]
    assert lm["status"] == "on" and lm["frame"] == "vts" and lm["summary"]["phase"] == "reference"
    assert m["scan"]["live_problem"].startswith("the patient was not watched: no reference was learned")
    assert lm["summary"]["watched"] is False and lm["summary"]["tracking"]["tracking_s"] == 0.0
    assert lm["blind_alerts"] and any(
        "no reference" in b["reason"] or "camera lost" in b["reason"] or "frames too late" in b["reason"]
        for b in lm["blind_alerts"]
    )
    assert run.returncode == 4
    assert f"problem: {m['scan']['live_problem']}" in run.out
    _last_line_says(run, m, tmp_path / "scan")
    _never_still_while_blind(run.err)
