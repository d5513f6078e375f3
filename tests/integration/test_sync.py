"""The sync analysis against the truth of the simulated rig (issue 6, part 5), and its parts.

The acceptance checks run the real pieces: `vts scan start` in a subprocess against this
process's simulated cameras (HTTP) and trigger-box firmware (emulator, pty); the source
marker moves in the scene the cameras render; the simulated SPECT follows the start pulse and
square wave the emulator emitted; `vts sync analyze` reads only the session and the
list-mode. The calibration files are the simulated cameras' truth (written by the sim rig).
Truth of a motion event: the move's middle (half the displacement), host clock.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from inprocess_cli import run as vts_run
from vts_hw.config import load_rig
from vts_hw.drivers.registry import open_cameras
from vts_hw.procedures.scan import ScanSession
from vts_hw.procedures.sync import SyncAnalysis
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scenarios import sync_session as sync_sim
from vts_hw.sim_devices.source_marker import min_jerk
from vts_hw.sim_devices.sync_truth import plan_sync_moves
from vts_hw.store import ResultsStore
from vts_hw.timing.marker_steps import find_steps, fit_step, match_events
from vts_hw.tracking.processing import Tracks
from vts_hw.vision.registration import RigidTransform

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]
EVENT_GOAL_S = 0.020
DELAY_GOAL_S = 0.010
FPS = 25.0


# ------------------------------------------------------------------------ the parts, offline


def _staircase(times, steps, t, move_s=0.3, z0=5.0):
    z = np.full(t.shape, z0)
    for t0, dz in zip(times, steps):
        z = z + dz * min_jerk(np.clip((t - t0) / move_s, 0, 1))
    return z


def test_steps_found_and_timed_to_a_millisecond_from_25_fps_samples():
    rng = np.random.default_rng(0)
    t = np.arange(0, 30, 1 / FPS) + 0.013
    moves = [4.1, 11.37, 14.9, 19.9]
    steps = [15.0, -22.0, 8.0, 11.0]
    z = _staircase(moves, steps, t) + rng.normal(0, 0.1, t.size)
    z[(t > 14) & (t < 16)] = np.nan  # a gap: the move in it is not found
    found = find_steps(t, z)
    del moves[2], steps[2]
    assert len(found) == 3 and all(abs(c.t - (t0 + 0.15)) < 0.05 for c, t0 in zip(found, moves))
    for c, t0, dz in zip(found, moves, steps):
        f = fit_step(t, z, c.t)
        assert abs(f.t_mid - (t0 + 0.15)) < 1e-3 and f.step_mm == pytest.approx(dz, abs=0.1)
        assert 0 < f.t_err_s < 2e-3


def test_an_edge_fit_of_raw_counts_beats_their_bins():
    """3000 counts/s with 4 mm blur and a uniform background: the edge of the raw events."""
    rng = np.random.default_rng(1)
    t = np.sort(rng.uniform(0, 10, 30000))
    z = _staircase([5.0], [12.0], t) + rng.normal(0, 4.0, t.size)
    bg = rng.random(t.size) < 0.05
    z[bg] = rng.uniform(-200, 200, bg.sum())
    f = fit_step(t, z, 5.1)
    assert abs(f.t_mid - 5.15) < 5e-3 and f.step_mm == pytest.approx(12.0, abs=1.0)


def test_match_events_by_time_and_direction():
    pairs = match_events([1.0, 5.0, 9.0], [10, -10, 10], [1.01, 5.2, 7.0], [10, 10, -10], 0.5)
    assert pairs == [(0, 0), (1, None), (None, 1), (None, 2), (2, None)]


def test_moves_are_planned_clear_of_the_head_rotations():
    fire = 1000.0
    for seed in range(5):
        times, steps = plan_sync_moves(fire, 60.0, n=4, seed=seed)
        rel = np.array(times) - fire
        assert len(times) == 4 and np.all(np.diff(rel) >= 2.0) and 2.0 <= rel[0] and rel[-1] <= 57.7
        for k, (a, b) in enumerate(((20.0, 22.6), (41.8, 45.0)), 1):  # every possible rotation
            assert np.all((rel + 0.3 < a - 1.0) | (rel > b + 1.0)), (seed, k, rel)
        assert np.all(np.abs(steps) >= 10) and np.all(np.sign(steps) == [1, -1, 1, -1])
    with pytest.raises(ValueError, match="too short"):
        plan_sync_moves(fire, 8.0, n=4)


def test_when_a_list_mode_was_acquired_is_read_from_its_ends(tmp_path):
    """read_listmode_span: the header's start and the END block's time, as the whole file says;
    a file cut short gives the planned duration (reading it whole says what is wrong)."""
    from vts_hw.spect.listmode import VtslmWriter, read_listmode, read_listmode_span

    path = tmp_path / "a.vtslm"
    with VtslmWriter(path, start_time=1_795_000_000.5, duration_s=30.0, gate_rate_hz=2000.0) as w:
        w.events(np.linspace(0, 20, 5000), np.zeros(5000), np.zeros(5000), np.zeros(5000, np.uint8))
        w.gate(np.zeros(40000))
        w.close(20.25)  # stopped before the planned 30 s
    lm = read_listmode(path)
    assert read_listmode_span(path) == (lm.start_time, lm.duration_s) == (1_795_000_000.5, 20.25)
    cut = tmp_path / "cut.vtslm"
    cut.write_bytes(path.read_bytes()[:50000])
    assert read_listmode_span(cut) == (1_795_000_000.5, 30.0)


# ------------------------------------------------------------------- on the simulated rig


@pytest.fixture()
def box_rig(tmp_path):
    rig = SimRig(n_cameras=2, seed=3, trigger="triggerbox").start()
    try:
        rig_yaml, _ = rig.write(tmp_path / "rig")
        marker = sync_sim.prepare(rig)
        with rig.env():
            yield rig, rig_yaml, marker
    finally:
        rig.stop()


def _analyze_cli(run, rig_yaml, *extra):
    p = subprocess.run(
        [*VTS, "sync", "analyze", str(run.session), "--listmode", str(run.listmode), "--json", *extra],
        env={**os.environ, "VTS_CONFIG": str(rig_yaml)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert p.returncode == 0, p.stderr
    assert "Traceback" not in p.stderr and "frame pairs" in p.stderr  # progress on stderr
    return json.loads(p.stdout), p.stderr


def _event_near(events, t, within=0.5):
    ev = min(events, key=lambda e: abs((e["t_spect"] or e["t_vts"]) - t))
    return ev if abs((ev["t_spect"] or ev["t_vts"]) - t) <= within else None


@pytest.fixture(scope="module")
def scan22(tmp_path_factory):
    """`vts scan start --duration 22` with 3 moves planned clear of the head rotation, and the
    simulated SPECT's list-mode: (run, rig_yaml, rig) — the rig stopped, its scene kept."""
    tmp = tmp_path_factory.mktemp("scan22")
    rig = SimRig(n_cameras=2, seed=3, trigger="triggerbox").start()
    try:
        rig_yaml, _ = rig.write(tmp / "rig")
        marker = sync_sim.prepare(rig)
        run = sync_sim.cli_scan(rig, rig_yaml, tmp / "scan", 22.0, marker, n=3, seed=1)
    finally:
        rig.stop()
    return run, rig_yaml, rig


def test_scan_then_sync_analyze_meets_the_goals(scan22, tmp_path):
    """`vts scan start --duration 22`, 3 moves, the SPECT following the emitted trigger, then
    `vts sync analyze`: every move reported by both, each within 20 ms of the truth; the
    start delay within 10 ms; the report, plot and exported trajectories written."""
    run, rig_yaml, rig = scan22
    cfg = load_rig(rig_yaml)
    assert cfg.calibration.cameras.name == "calibration.json" and cfg.calibration.mapping.exists()
    m = json.loads((run.session / "manifest.json").read_text())
    assert m["status"] == "complete" and m["trigger"]["fired"]

    report = tmp_path / "sync.html"
    data, _ = _analyze_cli(run, rig_yaml, "-o", str(report), "--export", str(tmp_path / "export"))
    lines = []
    for mv in run.source.moves:
        ev = _event_near(data["events"], mv.t_mid)
        assert ev is not None and ev["seen_by"] == "both", (mv, data["events"])
        errs = (ev["t_vts"] - mv.t_mid, ev["t_spect"] - mv.t_mid, ev["dt_s"])
        assert max(abs(e) for e in errs) < EVENT_GOAL_S, errs  # measured: under 5 ms
        assert np.sign(ev["step_spect_mm"]) == np.sign(mv.step_mm) and ev["step_vts_mm"] == pytest.approx(
            mv.step_mm, abs=1.0
        )
        lines.append(" ".join(f"{e * 1e3:+.1f}" for e in errs))
    assert len(data["events"]) == len(run.source.moves)
    delay_err = data["summary"]["start_delay_s"] - run.spect.start_delay_s
    assert abs(delay_err) < DELAY_GOAL_S  # measured: about 0.2 ms
    assert data["summary"]["state"] == "OK" and abs(data["summary"]["offset_s"]) < EVENT_GOAL_S
    assert data["calibration"]["note"].startswith("simulated rig: the scene's true cameras")
    # the dead time (the first head rotation, 20 s into the acquisition) mapped to host time
    ((d0, d1),) = data["dead_time_host"]
    assert abs(d0 - run.spect.host_time(run.spect.dead[0][0])) < 5e-3  # ~0.2 ms idle, 3 ms seen under heavy load
    print("events (VTS, SPECT, VTS-SPECT ms):", "; ".join(lines), f"start delay error {delay_err * 1e3:+.2f} ms")

    html = report.read_text()
    assert "data:image/png;base64," in html and 'data-state="OK"' in html and "<script src" not in html
    # the trajectories in the SPECT frame on SPECT time: the source where the scene put it
    tracks = Tracks.load(tmp_path / "export" / "trajectories.csv")
    ids = data["vts"]["markers"]
    t_host, xyz = tracks.trajectory(ids[0], frame="spect")
    sel = np.isin(tracks.marker, ids)
    list_t = tracks.spect_time[tracks.point_frame[sel]]
    # host → list-mode time goes through the trigger's first edge on the host clock (the
    # trigger-box clock fit): one offset for the whole scan, ~0.2 ms idle, 1.5 ms seen in CI
    # under load; the skew (the spread along the scan) is fitted from the edges, to µs
    off = list_t - run.spect.list_time(t_host)
    assert abs(float(np.mean(off))) < 5e-3 and np.ptp(off) < 2e-4, (np.mean(off), np.ptp(off))
    still = np.abs(t_host - run.source.moves[0].t_start) > 0.5
    true = np.array([m.center for m in rig.scene.markers_world(float(t_host[0])) if m.id == "SRC"])[0]
    assert np.linalg.norm(xyz[0] - true) < 1.0 and still.sum() > 100
    assert tracks.meta["sync"]["start_delay_s"] == pytest.approx(data["summary"]["start_delay_s"])
    # stored as a run, the one way every QA result is: a measurement per sync window
    run_id = data["stored"]["run_id"]
    with ResultsStore(cfg.results.url) as store:
        stored = store.run(run_id)
        assert stored.procedure == "sync" and stored.status == "OK"
        ms = {m.metric: m.value for m in store.measurements(run_id=run_id)}
    assert ms == {
        "sync_max_abs_dt_ms": pytest.approx(data["summary"]["max_abs_dt_s"] * 1e3),
        "sync_events_one_system": 0,
        "sync_events_both": len(run.source.moves),
    }


def test_a_report_on_a_full_disk_never_costs_the_check(scan22, small_disk):
    """Issue 21 §2: `vts sync analyze -o FULL/sync.html --plot FULL/sync.png --export FULL/x` on a
    full disk: the figures are printed and the run stored all the same; one sentence names the
    files not written (exit 3); nothing half-written is left."""
    run, rig_yaml, _ = scan22
    cfg = load_rig(rig_yaml)
    disk = small_disk(64)
    disk.fill()
    with ResultsStore(cfg.results.url) as store:
        before = len(store.runs(procedure="sync"))
    p = vts_run(
        "sync",
        "analyze",
        run.session,
        "--listmode",
        run.listmode,
        "-o",
        disk.path / "sync.html",
        "--plot",
        disk.path / "sync.png",
        "--export",
        disk.path / "x",
        env={**os.environ, "VTS_CONFIG": str(rig_yaml)},
    )
    err = p.stderr.strip().splitlines()[-1]
    assert p.returncode == 3 and "Traceback" not in p.stderr, p.stderr
    assert err.startswith("vts: ") and "sync.html: could not be written (no space left on device)" in err, err
    assert "sync.png: could not be written" in err and "trajectories.csv: could not be written" in err
    assert "sync check is stored as run" in err
    assert "SPECT start delay" in p.stdout and "state: OK" in p.stdout and "stored: run" in p.stdout
    assert "report:" not in p.stdout
    with ResultsStore(cfg.results.url) as store:
        runs = store.runs(procedure="sync")
        assert len(runs) == before + 1 and "sync.html" in (runs[-1].notes or "")
    assert disk.files() == {}, disk.files()


def test_without_a_mapping_and_with_a_named_marker(scan22):
    """No VTS -> SPECT mapping: the trace is the source's main direction of motion and the
    events are still found (times within 20 ms); a named wall marker has no event at all."""
    run, rig_yaml, _ = scan22
    cfg = load_rig(rig_yaml)
    a = SyncAnalysis(run.session, run.listmode, cfg.calibration.cameras, workers=1).analyze()
    data = a.results_data()
    assert data["vts"]["trace"] == "main direction of motion"
    assert any("no VTS -> SPECT mapping" in p for p in data["problems"])
    assert [e["seen_by"] for e in data["events"]] == ["both"] * len(run.source.moves)
    for mv, ev in zip(run.source.moves, data["events"]):
        assert abs(ev["t_vts"] - mv.t_mid) < EVENT_GOAL_S and abs(ev["t_spect"] - mv.t_mid) < EVENT_GOAL_S
    source = data["vts"]["markers"][0]
    wall = next(
        d["marker"]
        for d in data["vts"]["marker_summary"]
        if d["marker"] != source and d["points"] > 0.9 * data["vts"]["samples"]
    )
    b = SyncAnalysis(
        run.session, run.listmode, cfg.calibration.cameras, cfg.calibration.mapping, marker=wall, workers=1
    ).analyze()
    d = b.results_data()
    assert d["vts"]["markers"] == [wall] and d["summary"]["events_both"] == 0
    assert d["summary"]["state"] == "ACTION" and "no motion event seen by both" in b.results()
    assert {e["seen_by"] for e in d["events"]} == {"SPECT only"}
    p = vts_run(
        "sync",
        "analyze",
        run.session,
        "--listmode",
        run.listmode,
        "--config",
        rig_yaml,
        "--marker",
        wall,
        "--workers",
        "1",
    )
    assert p.returncode == 20 and "state: ACTION" in p.stdout and "Traceback" not in p.stderr
    png = b.plot(None)
    assert png[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_camera_offline_for_5_s_still_analyses(box_rig, tmp_path):
    """cam1 off the network for 5 s mid-scan: cam2's recording complete, the gap in the
    manifest, the analysis runs; the move in the gap is reported as seen by the SPECT only."""
    rig, rig_yaml, marker = box_rig
    cfg = load_rig(rig_yaml)
    duration = 12.0
    s = ScanSession(cfg, tmp_path / "scan", open_cameras(cfg.cameras), duration=duration)
    s.start()
    fire = s.trigger.info["fire_time"]
    src = sync_sim.start_moves(rig, marker, fire, duration, times_rel=[2.0, 6.0, 10.0], steps=[18.0, -14.0, 12.0])
    threading.Timer(fire + 3.5 - time.time(), rig.servers["cam1"].go_offline, (5.0,)).start()
    m = s.stop(s.wait())
    lm, truth = sync_sim.simulate_spect(rig, src, tmp_path / "scan", duration - 0.6)

    c1, c2 = m["cameras"]["cam1"], m["cameras"]["cam2"]
    assert m["status"] == "partial" and c2["gaps"] == [] and c2["frames"] >= 0.98 * duration * FPS
    gap = max(c1["gaps"], key=lambda g: g["missing"])
    assert gap["camera_t1"] - gap["camera_t0"] >= 5.0

    a = SyncAnalysis(tmp_path / "scan", lm, cfg.calibration.cameras, cfg.calibration.mapping, workers=2).analyze()
    data = a.results_data()
    assert any(b - a_ >= 5.0 for a_, b in data["vts"]["gaps_host"])
    assert any("cam1" in p and "gap" in p for p in data["problems"])
    seen = []
    for mv in src.moves:
        ev = _event_near(data["events"], mv.t_mid)
        assert ev is not None
        seen.append(ev["seen_by"])
        assert abs(ev["t_spect"] - mv.t_mid) < EVENT_GOAL_S
        if ev["seen_by"] == "both":
            assert abs(ev["t_vts"] - mv.t_mid) < EVENT_GOAL_S
    assert seen == ["both", "SPECT only", "both"]
    assert _event_near(data["events"], src.moves[1].t_mid)["note"] == "in a gap of the VTS recording"
    assert len(data["vts"]["markers"]) >= 2  # the source's track re-joined across the gap
    assert abs(a.gating.start_delay_s - truth.start_delay_s) < DELAY_GOAL_S
    print(f"camera offline: cam1 gap {gap['camera_t1'] - gap['camera_t0']:.2f} s; events seen by {seen}")


def test_kill_9_of_the_scan_leaves_a_session_that_reindexes_and_analyses(box_rig, tmp_path):
    """`vts scan start` killed with SIGKILL 9 s after the fire (the square wave keeps running,
    the manifest says "recording"): `vts recording reindex` makes it whole and `vts sync
    analyze` finds both moves within 20 ms of the truth."""
    rig, rig_yaml, marker = box_rig
    run = sync_sim.cli_scan(
        rig, rig_yaml, tmp_path / "scan", 60.0, marker, times_rel=[2.5, 6.0], steps=[15.0, -20.0], kill_after_s=9.0
    )
    assert json.loads((run.session / "manifest.json").read_text())["status"] == "recording"
    r = vts_run("recording", "reindex", run.session)
    assert r.returncode == 0, r.stderr
    assert json.loads((run.session / "manifest.json").read_text())["status"] == "recovered"

    data, _ = _analyze_cli(run, rig_yaml)
    for mv in run.source.moves:
        ev = _event_near(data["events"], mv.t_mid)
        assert ev is not None and ev["seen_by"] == "both"
        assert abs(ev["t_vts"] - mv.t_mid) < EVENT_GOAL_S and abs(ev["t_spect"] - mv.t_mid) < EVENT_GOAL_S
    assert abs(data["summary"]["start_delay_s"] - run.spect.start_delay_s) < DELAY_GOAL_S
    assert data["trigger"]["start_pulse"] is True


# ---------------------------------------------------------------------------- clear errors


def test_bad_inputs_end_in_one_sentence(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "VTS_CONFIG"}
    (tmp_path / "empty").mkdir()
    junk = tmp_path / "junk.vtslm"
    junk.write_bytes(b"not a list-mode file")
    (tmp_path / "session").mkdir()
    (tmp_path / "session" / "manifest.json").write_text(json.dumps({"cameras": {"cam1": {}}}))
    (tmp_path / "session" / "trigger.csv").write_text("host_time,device_time_us,device,kind,text\n")
    (tmp_path / "untriggered").mkdir()  # recorded with trigger backend none: no trigger log
    (tmp_path / "untriggered" / "manifest.json").write_text(json.dumps({"cameras": {"cam1": {}}}))
    cal = tmp_path / "calibration.json"
    cal.write_text("{}")
    cases = [
        ([str(tmp_path / "nope"), "--listmode", str(junk)], 3, "no such session folder"),
        ([str(tmp_path / "empty"), "--listmode", str(junk)], 3, "not a session folder (no manifest.json)"),
        (
            [str(tmp_path / "untriggered"), "--listmode", str(junk)],
            3,
            f"vts: {tmp_path / 'untriggered'}: no trigger.csv: the session has no trigger log to time the SPECT "
            f"against (was it recorded with trigger backend none?)",
        ),
        ([str(tmp_path / "session")], 2, "give the scan's list-mode: --listmode FILE"),
        ([str(tmp_path / "session"), "--listmode", str(junk)], 2, "no camera calibration: give --calibration"),
        ([str(tmp_path / "session"), "--listmode", str(junk), "--calibration", str(cal)], 3, f"{junk}: "),
        (
            [str(tmp_path / "session"), "--listmode", str(tmp_path / "none.vtslm"), "--calibration", str(cal)],
            3,
            "none.vtslm: no such file",
        ),
    ]
    for args, code, text in cases:
        p = vts_run("sync", "analyze", *args, env=env, cwd=tmp_path)
        assert p.returncode == code and text in p.stderr, (args, p.stderr)
        one_line = len(p.stderr.strip().splitlines()) == 1
        assert "Traceback" not in p.stderr and (one_line or p.stderr.startswith("Usage:"))  # click's usage


def test_the_sim_rig_writes_its_true_calibration(tmp_path):
    with SimRig(n_cameras=2, seed=2) as rig:
        rig_yaml, _ = rig.write(tmp_path)
    cfg = load_rig(rig_yaml)
    mp = RigidTransform.load(cfg.calibration.mapping)
    c1 = rig.scene.camera_at("cam1", rig.scene.start_epoch)
    world = np.array([[10.0, -20.0, 5.0], [100.0, 50.0, -80.0]])
    assert np.allclose(mp.apply(c1.to_camera(world)), world, atol=1e-9)  # VTS (camera 1) -> SPECT


@pytest.mark.parametrize(
    "manifest, words",
    [
        ("[]", "not a recording manifest (expected a JSON object, got a list)"),
        ('{"cameras": []}', 'not a recording manifest ("cameras" must map each camera name to its entry)'),
        ('{"cameras": {"cam1": 3}}', 'not a recording manifest ("cameras" must map each camera name to its entry)'),
    ],
)
def test_a_manifest_of_the_wrong_shape_is_one_sentence(tmp_path, manifest, words):
    """`vts sync analyze` on a session whose manifest.json is not a recording manifest."""
    session = tmp_path / "session"
    session.mkdir()
    (session / "manifest.json").write_text(manifest)
    (session / "trigger.csv").write_text("host_time,device_time_us,device,kind,text\n")
    env = {k: v for k, v in os.environ.items() if k != "VTS_CONFIG"}
    p = vts_run("sync", "analyze", session, "--listmode", tmp_path / "x.vtslm", env=env, cwd=tmp_path)
    assert p.returncode == 3, p.stderr
    assert p.stderr.strip() == f"vts: {session / 'manifest.json'}: {words}"
