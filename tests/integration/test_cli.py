"""The `vts` command line against a detached simulated rig, as a user runs it."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vts_hw.recording.folder import read_index
from vts_hw.recording.mjpeg import split_jpegs
from vts_hw.sim_devices.rig import load_env_file

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def vts(*args, env=None, check=True, timeout=60):
    p = subprocess.run([*VTS, *args], capture_output=True, text=True, env=env, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f"vts {' '.join(args)} exited {p.returncode}: {p.stderr}")
    return p


@pytest.fixture(scope="module")
def sim_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("sim")
    vts("sim", "up", "--detach", "--dir", str(d))
    yield d
    vts("sim", "down", "--dir", str(d))
    assert not (d / "sim.pid").exists()


@pytest.fixture()
def env(sim_dir):
    e = dict(os.environ)
    e.update(load_env_file(sim_dir / "sim.env"))
    return e


def test_sim_up_writes_config_and_private_env(sim_dir, env):
    assert env["VTS_CONFIG"] == str((sim_dir / "rig.yaml").resolve())
    assert oct((sim_dir / "sim.env").stat().st_mode & 0o777) == "0o600"
    password = env["VTS_SIM_CAM1_PASSWORD"]
    assert password not in (sim_dir / "rig.yaml").read_text()


def test_snapshot_led_info(sim_dir, env, tmp_path):
    out = tmp_path / "a.jpg"
    p = vts("camera", "snapshot", "cam1", "-o", str(out), env=env)
    assert out.read_bytes()[:2] == b"\xff\xd8" and "camera time" in p.stdout
    assert ": read back: " in vts("camera", "led", "cam2", "pulse", "200", env=env).stdout
    info = json.loads(vts("camera", "info", "cam2", "--json", env=env).stdout)
    assert info["vapix"] == 3 and info["clock_method"] == "time.cgi"
    assert env["VTS_SIM_CAM2_PASSWORD"] not in json.dumps(info)


def test_record_info_reindex(env, tmp_path):
    rec = tmp_path / "rec"
    p = vts("camera", "record", "cam1", "cam2", "--seconds", "2", "-o", str(rec), env=env)
    assert "status complete" in p.stdout
    summary = json.loads(vts("recording", "info", str(rec), "--json").stdout)
    assert {s["source"] for s in summary} == {"cam1", "cam2"}
    assert all(40 <= s["frames"] <= 60 and s["gaps"] == [] for s in summary)
    (rec / "cam1.index.csv").unlink()
    assert "cam1: " in vts("recording", "reindex", str(rec)).stdout
    assert len(read_index(rec / "cam1.index.csv")) == summary[0]["frames"]
    manifest = (rec / "manifest.json").read_text()
    assert env["VTS_SIM_CAM1_PASSWORD"] not in manifest
    import hashlib

    digest = hashlib.sha256(Path(env["VTS_CONFIG"]).read_bytes()).hexdigest()
    assert json.loads(manifest)["rig_digest"] == digest


def test_kill_9_loses_at_most_the_frame_in_flight(env, tmp_path):
    rec = tmp_path / "killed"
    proc = subprocess.Popen(
        [*VTS, "camera", "record", "--all", "--seconds", "60", "-o", str(rec)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            idx = rec / "cam1.index.csv"
            if idx.exists() and len(idx.read_text().splitlines()) > 30:
                break
            time.sleep(0.1)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    for cam in ("cam1", "cam2"):
        data = (rec / f"{cam}.mjpeg").read_bytes()
        rows = read_index(rec / f"{cam}.index.csv")
        assert len(rows) > 10
        spans = split_jpegs(data)
        # every indexed frame is whole on disk, and at most one frame is beyond the index
        assert [(s.offset, s.length) for s in spans[: len(rows)]] == [(r.offset, r.length) for r in rows]
        assert all(s.complete for s in spans[: len(rows)])
        assert len(spans) - len(rows) <= 1
    assert json.loads((rec / "manifest.json").read_text())["status"] == "recording"
    vts("recording", "reindex", str(rec))
    assert json.loads((rec / "manifest.json").read_text())["status"] == "recovered"


@pytest.mark.parametrize(
    "args, code, words",
    [
        (("camera", "snapshot", "cam9", "-o", "x.jpg"), 2, "no camera named 'cam9'"),
        (("--config", "/nonexistent/rig.yaml", "camera", "info", "cam1"), 2, "no such config file"),
        (("recording", "info", "/nonexistent"), 3, "no such file"),
    ],
)
def test_user_errors_are_one_sentence(env, args, code, words):
    if args[0] == "--config":
        args = args[2:4] + ("--config", args[1]) + args[4:]
    p = vts(*args, env=env, check=False)
    assert p.returncode == code, p.stderr
    assert words in p.stderr
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1


def test_wrong_password_is_one_sentence(env, tmp_path):
    bad = dict(env, VTS_SIM_CAM1_PASSWORD="wrong-one")
    p = vts("camera", "snapshot", "cam1", "-o", str(tmp_path / "x.jpg"), env=bad, check=False)
    assert p.returncode == 4 and "refused user 'root'" in p.stderr
    assert "wrong-one" not in p.stderr and "Traceback" not in p.stderr


def test_help_explains():
    p = vts("camera", "record", "--help")
    assert "--seconds" in p.stdout and "manifest.json" in p.stdout


def test_stream_prints_frames_for_the_time_asked(env):
    p = vts("camera", "stream", "cam1", "--seconds", "1", env=env)
    lines = [x for x in p.stdout.splitlines()[1:] if x.strip()]
    assert 18 <= len(lines) <= 30
    assert "0 missing" in p.stderr


def test_sim_up_in_the_foreground_stops_cleanly_on_ctrl_c(tmp_path):
    proc = subprocess.Popen(
        [*VTS, "sim", "up", "--cameras", "1", "--dir", str(tmp_path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30
        while not (tmp_path / "rig.yaml").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert (tmp_path / "rig.yaml").exists()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=15)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert "cam1: http://127.0.0.1:" in out and "stopped" in out
    assert "Traceback" not in err
