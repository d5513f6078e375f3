"""The 60-day demo is the issue's acceptance check: measured drift against the injected truth,
every day, and the report's forecast against the injected trend."""

import re

import numpy as np
import pytest

from vts_hw.cli.demo import console_hint
from vts_hw.report import build_drift_report
from vts_hw.sim_devices.scenarios.demo_days import DAY, FAST_CAMERA, run_demo
from vts_hw.store import ResultsStore

# 60 simulated days: ~40 s on an idle 2-core machine, several minutes on a loaded one; the
# timeout is a hang detector, and it counts the module fixture's set-up
pytestmark = pytest.mark.timeout(900)


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    return run_demo(out, days=60, frames=3)


def test_measured_drift_within_005_px_of_the_truth_every_day(demo):
    assert len(demo.rows) == 60
    for row in demo.rows:
        for cam, v in row.cameras.items():
            assert abs(v["dx"] - v["truth_dx"]) <= 0.05, (row.day, cam)
            assert abs(v["dy"] - v["truth_dy"]) <= 0.05, (row.day, cam)
    assert set(demo.max_error_px) == {"cam1", "cam2"}


def test_the_fast_camera_passes_its_tolerance_along_the_way(demo):
    states = [r.cameras[FAST_CAMERA]["state"] for r in demo.rows]
    assert states[0] == "OK" and states[-1] == "TOLERANCE"
    first = states.index("TOLERANCE")
    row = demo.rows[first]
    v = row.cameras[FAST_CAMERA]
    assert max(abs(v["truth_dx"]), abs(v["truth_dy"])) > 0.95  # it is the drift, not something else
    assert demo.report_html.stat().st_size > 20000 and demo.report_pdf.read_bytes()[:5] == b"%PDF-"
    # the rooms page over the demo's store: its one room, the fast camera in TOLERANCE, linked
    rooms = demo.rooms_html.read_text()
    assert re.search(r'<tr class="room" data-rig="sim-demo" data-state="TOLERANCE">', rooms)
    assert f'<div class="cam" data-camera="{FAST_CAMERA}" data-state="TOLERANCE">' in rooms
    assert (
        'href="rooms-sim-demo-drift.html"' in rooms and (demo.rooms_html.parent / "rooms-sim-demo-drift.html").is_file()
    )


def test_forecast_agrees_with_the_injected_trend(demo):
    t = np.array([r.when for r in demo.rows])
    with ResultsStore(demo.store_path) as store:
        data = build_drift_report(store, demo.report_html.with_name("again.html"), now=t[-1] + 60).results_data()
    for axis in ("x", "y"):
        truth = np.array([r.cameras[FAST_CAMERA][f"truth_d{axis}"] for r in demo.rows])
        slope, icpt = np.polyfit(t, truth, 1)
        fc = data["cameras"][FAST_CAMERA]["axes"][axis]["forecast"]
        level = np.sign(slope) * 2.0
        t_cross = (level - icpt) / slope
        if t_cross - t[-1] > 365 * DAY:
            assert fc["status"] != "date"
            continue
        assert fc["status"] == "date" and fc["level"] == level
        assert abs(fc["t"] - t_cross) < 3 * DAY, (axis, (fc["t"] - t_cross) / DAY)


def test_the_step_test_follows_the_daily_qa_and_is_in_the_report(demo):
    steps = demo.steps
    assert steps is not None and steps.run_id is not None
    assert all(r.r2 >= 0.999 for r in steps.analysis.regressions.values())
    assert steps.scores["position_rms_mm"] <= 0.15
    with ResultsStore(demo.store_path) as store:
        runs = store.runs(procedure="sphere-steps")
        assert [r.id for r in runs] == [steps.run_id]
        # after the last daily run, on the demo's clock
        assert runs[0].started > max(r.when for r in demo.rows)
    html = demo.report_html.read_text()
    assert f'alt="7-sphere step test, run {steps.run_id}"' in html
    assert 'data-plots-expected="3"' in html  # two cameras' drift and the step test


@pytest.mark.timeout(2400)  # a hang detector: about 3 minutes idle, much longer on a loaded machine
def test_vts_demo_command_end_to_end_with_a_scan(tmp_path):
    """`make demo` runs this command: every section, the step test and a short scan with the
    sync check (events against the truth) included."""
    import re
    import subprocess
    import sys

    out = tmp_path / "demo"
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "vts_hw.cli.__main__",
            "demo",
            "-o",
            str(out),
            "--days",
            "1",
            "--seconds",
            "1",
            "--scan-seconds",
            "16",
            "--patient-seconds",
            "24",
        ],
        capture_output=True,
        text=True,
        timeout=2000,
    )
    assert r.returncode == 0, r.stderr
    for heading in (
        "== 1. the cameras",
        "== 2. the daily QA",
        "== 3. the 7-sphere step test",
        "== 5. a scan of 16 s and the sync check",
        "== 6. a patient scan of 24 s",
    ):
        assert heading in r.stdout
    assert r.stdout.rstrip().endswith(console_hint(out))  # how to see the room live (issue 23)
    # the patient: one live alert, the move found near its true start, the pose near the truth
    patient = r.stdout.split("== 6.")[1]
    # one live alert; or, on a machine so busy that the live path fell behind its frames during the
    # move, none with the NOT TRACKING it said live (issue 20) -- never a silent or unexplained miss
    alerts = re.findall(r"live alert (\d+\.\d+) s after the move started", patient)
    assert len(alerts) == 1 or (
        not alerts and re.search(r"^  no live alert: NOT TRACKING for .*said so live$", patient, re.M)
    ), patient
    assert "NO LIVE ALERT" not in patient
    start_ms = re.search(r"found by the analysis: start ([+-]\d+) ms off the truth", patient)
    assert start_ms and abs(int(start_ms.group(1))) < 500, patient
    pose = re.search(r"RMS (\d+\.\d+) mm, (\d+\.\d+) deg", patient)
    assert float(pose.group(1)) <= 0.3 and float(pose.group(2)) <= 0.2, patient
    # the breathing rate says whether it is known, with its range when bounded (whether ranges
    # hold the truth is scored over 60 patients in tests/unit/test_breathing_rate.py)
    # (the line, not "a breathing patient" in the scan's command line above it)
    # (a measured rate may carry its narrow range too: "measured 16.2-16.8 /min"; a bounded one always does)
    rate = re.search(
        r"^  breathing (\d+\.\d) /min, (measured( \d+\.\d-\d+\.\d /min)?|bounded( \d+\.\d-\d+\.\d /min)) "
        r"\(true (\d+\.\d) /min\)",
        patient,
        re.M,
    )
    assert rate or re.search(r"^  breathing [a-z][^(]* \(true \d+\.\d /min\)", patient, re.M), patient
    assert (out / "patient-export" / "castor_motion_rigid.txt").exists() and (out / "motion-report.html").exists()
    r.stdout = r.stdout.split("== 6.")[0]  # the sync figures below are the scan's
    errors = [abs(float(x)) for x in re.findall(r"(?:VTS|SPECT) ([+-]\d+\.\d) ms", r.stdout)]
    assert errors and max(errors) <= 20.0
    assert "not found" not in r.stdout
    assert (out / "sync-report.html").stat().st_size > 20_000
    assert (out / "trajectories" / "trajectories.csv").exists()


def test_the_demo_ends_saying_how_to_open_the_console_on_its_rig_and_store(tmp_path):
    """(cheap: the lines the demo ends with; the end-to-end test above checks it prints them)"""
    from click.testing import CliRunner

    from vts_hw.cli import _register, cli

    _register()  # the commands, as `vts` registers them
    hint = console_hint(tmp_path / "demo")
    lines = hint.splitlines()
    assert lines[0].startswith("the room console") and "Firefox" in lines[0]
    # the commands, in order: the simulated rig left running, its passwords, the console on the
    # rig it wrote with the store the demo fills (run_demo's results.sqlite), the address
    assert lines[1].split("#")[0].split() == ["vts", "sim", "up", "--dir", str(tmp_path / "demo" / "live"), "--detach"]
    assert lines[2].split() == ["source", str(tmp_path / "demo" / "live" / "sim.env")]
    assert lines[3].split() == [
        f"VTS_STORE={tmp_path / 'demo' / 'results.sqlite'}",
        "vts",
        "console",
        "--config",
        str(tmp_path / "demo" / "live" / "rig.yaml"),
    ]
    assert "http://127.0.0.1:8040/" in hint and "vts sim down --dir" in hint
    # each command and option it names exists as written
    runner = CliRunner()
    for args in (["sim", "up", "--help"], ["console", "--help"], ["sim", "down", "--help"]):
        got = runner.invoke(cli, args)
        assert got.exit_code == 0, (args, got.output)
    assert "--detach" in runner.invoke(cli, ["sim", "up", "--help"]).output
    assert "--config" in runner.invoke(cli, ["console", "--help"]).output


def test_a_demo_move_without_a_live_alert_says_why():
    """What the demo's patient step prints when there was no live alert: off, no reference, NOT
    TRACKING while the alert was due (a busy machine), or nothing -- a real miss, said as one."""
    from vts_hw.sim_devices.scenarios.demo_patient import unwatched_move

    on = {"status": "on", "alert_after_s": 1.0, "summary": {"phase": "tracking"}}
    assert "off (no camera calibration)" in unwatched_move({"status": "off", "off_reason": "no camera calibration"}, 10)
    assert "never learned its reference" in unwatched_move({**on, "summary": {"phase": "reference"}}, 10)
    late = {**on, "not_tracking": [{"start": 10.4, "end": 13.0, "reasons": ["frames too late (0.9 s)"]}]}
    why = unwatched_move(late, 10.0)
    assert why.startswith("NOT TRACKING for 1.1 s of the 1.5 s") and "frames too late (0.9 s)" in why
    before = {**on, "not_tracking": [{"start": 5.0, "end": 9.0, "reasons": ["camera lost: cam2"]}]}
    assert unwatched_move(before, 10.0) == "" and unwatched_move(on, 10.0) == ""
