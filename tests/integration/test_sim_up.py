"""`vts sim up` as a user runs it: a --dir it cannot use, a detached rig that fails to start,
and the simulated function generator whose state lasts between `vts trigger` commands."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys

import pytest

from vts_hw.config import load_rig
from vts_hw.sim_devices.rig import FGEN_LOG, load_env_file
from vts_hw.sim_devices.scpi_server import read_output_log

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def vts(*args, env=None, timeout=90):
    return subprocess.run([*VTS, *args], capture_output=True, text=True, env=env, timeout=timeout)


@pytest.mark.parametrize("detach", [False, True], ids=["foreground", "detached"])
def test_a_dir_that_cannot_be_created_is_one_sentence_and_exit_3(readonly_dir, detach):
    d = readonly_dir / "sim"
    p = vts("sim", "up", "--cameras", "1", "--dir", str(d), *(["--detach"] if detach else []))
    assert p.returncode == 3, p.stderr
    assert p.stderr == (
        f"vts: {d}: could not be written (cannot create the simulated rig folder: read-only file system)\n"
    )
    assert p.stdout == "" and not d.exists()


@pytest.mark.parametrize("detach", [False, True], ids=["foreground", "detached"])
def test_a_read_only_dir_is_one_sentence_and_exit_3(readonly_dir, detach):
    p = vts("sim", "up", "--cameras", "1", "--dir", str(readonly_dir), *(["--detach"] if detach else []))
    assert p.returncode == 3, p.stderr
    assert p.stderr == f"vts: {readonly_dir}: could not be written (the simulated rig folder is not writable)\n"
    assert "Traceback" not in p.stderr and list(readonly_dir.iterdir()) == []


def test_a_detached_rig_that_fails_to_start_says_why(tmp_path):
    d = tmp_path / "sim"
    missing = tmp_path / "no-firmware"
    env = {**os.environ, "VTS_FIRMWARE_DIR": str(missing)}  # the trigger box cannot be built
    (d).mkdir()
    (d / "sim.log").write_text("an older run's line\n")  # sim.log is appended to: not this run's cause
    p = vts("sim", "up", "--detach", "--cameras", "1", "--trigger", "triggerbox", "--dir", str(d), env=env)
    assert p.returncode == 1, p.stderr
    assert p.stderr == (
        f"vts: the simulated rig failed to start (exit 1): RuntimeError: trigger box firmware "
        f"sources not found in {missing} (an installed vts-hw has none: set VTS_FIRMWARE_DIR to "
        f"the firmware/ folder of a checkout) (the whole log: {d / 'sim.log'})\n"
    )
    assert not (d / "rig.yaml").exists() and not (d / "sim.pid").exists()
    log = (d / "sim.log").read_text()
    assert log.startswith("an older run's line\n") and "Traceback" in log  # the details stay in the log


def test_the_simulated_function_generator_keeps_its_state_between_commands(tmp_path):
    d = tmp_path / "sim"
    p = vts("sim", "up", "--detach", "--cameras", "1", "--trigger", "visa", "--dir", str(d))
    assert p.returncode == 0, p.stderr
    try:
        env = {**os.environ, **load_env_file(d / "sim.env")}
        trigger = load_rig(d / "rig.yaml").trigger  # reached as a real 33500 on the LAN
        assert trigger.backend == "visa" and not trigger.options.get("simulated", False)
        assert re.fullmatch(r"TCPIP::127\.0\.0\.1::\d+::SOCKET", trigger.address)
        log = str(tmp_path / "trigger.csv")
        p = vts("trigger", "start", "--log", log, env=env)
        assert p.returncode == 0, p.stderr
        assert p.stdout.strip() == "fgen: output ON, 1 Hz, duty 50 %, 0..2.5 V"
        p = vts("trigger", "status", "--json", "--log", log, env=env)
        assert p.returncode == 0, p.stderr
        st = json.loads(p.stdout)
        assert (st["running"], st["frequency_hz"], st["duty"], st["high_v"], st["low_v"]) == (True, 1.0, 0.5, 2.5, 0.0)
        # the instrument's own log of its output, with host times
        (ev,) = read_output_log(d / FGEN_LOG)
        assert ev.output and ev.function == "SQU" and ev.frequency_hz == 1.0
        p = vts("trigger", "stop", "--log", log, env=env)
        assert p.returncode == 0 and "output OFF" in p.stdout
        assert [e.output for e in read_output_log(d / FGEN_LOG)] == [True, False]
    finally:
        assert vts("sim", "down", "--dir", str(d)).returncode == 0


def test_warmup_drift_starts_the_cameras_now_and_their_pictures_drift_as_they_warm(tmp_path, monkeypatch):
    """`vts sim up --warmup-drift`: asked over HTTP through the driver, the camera has just started
    and its wall markers move as the declared warm-up says (simulated time 60 times real time)."""
    import math
    import time

    from vts_hw.drivers.registry import open_camera
    from vts_hw.procedures.warmup import Watch
    from vts_hw.sim_devices.rig import SimRig

    d = tmp_path / "sim"
    p = vts("sim", "up", "--detach", "--cameras", "1", "--seed", "3", "--rate", "60", "--warmup-drift", "--dir", str(d))
    assert p.returncode == 0, p.stderr
    assert "cameras just switched on: their pictures drift for minutes as they warm" in p.stdout
    try:
        monkeypatch.setattr(os, "environ", {**os.environ, **load_env_file(d / "sim.env")})
        with open_camera(load_rig(d / "rig.yaml").cameras[0]) as cam:
            cam.led_on()
            watch = Watch(cam, frames=2)
            first = watch.sample()
            age0 = cam.uptime().seconds  # a camera started a day before would say 86400 s
            time.sleep(6.0)  # at least 6 simulated minutes (more on a busy machine)
            last = watch.sample()
        assert age0 < 15 * 60, age0
        truth = SimRig(n_cameras=1, seed=3, warmup_drift=True).scene.warmups["cam1"]  # what --seed 3 declares
        a0, a1 = age0, age0 + (last.t - first.t)  # the uptime read just after the first sample
        want = truth.amplitude_px * (math.exp(-a0 / truth.tau_s) - math.exp(-a1 / truth.tau_s))
        moved = math.hypot(last.dx, last.dy)
        assert last.markers >= 4 and want > 0.5, (last, want)
        assert abs(moved - want) < 0.25 * want + 0.1, (moved, want, a0, a1)
    finally:
        vts("sim", "down", "--dir", str(d))


def test_stopping_a_detached_rig_loads_none_of_the_scene(tmp_path):
    """Finding and stopping a detached rig (sim_devices/rig_detached.py) needs its pid file, not
    the scene, the renderer or the devices that rig.py imports (numpy, cv2, scipy): decision 0095."""
    code = (
        "import json, sys\nfrom vts_hw.sim_devices.rig_detached import stop_detached\n"
        f"stopped = stop_detached({str(tmp_path)!r})\n"
        "print(json.dumps([stopped, sorted(m for m in sys.modules if m.startswith('vts_hw.sim_devices.')"
        " or m in ('numpy', 'cv2', 'scipy'))]))"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout) == [False, ["vts_hw.sim_devices.rig_detached", "vts_hw.sim_devices.rig_log"]]


def test_the_simulated_cameras_announce_themselves_and_vts_discover_finds_them(tmp_path):
    """`vts sim up --announce` (issue 34 §4: a newcomer could not try `vts discover` on the
    simulated rig): the detached rig's cameras announce themselves on loopback as Axis cameras
    do, and `vts discover` -- a separate process, as a user runs it -- finds each of rig.yaml's
    cameras and confirms it with sim.env's password."""
    folder = tmp_path / "sim"
    up = vts("sim", "up", "--cameras", "2", "--seed", "9", "--announce", "--detach", "--dir", str(folder))
    assert up.returncode == 0, up.stderr
    assert "cameras announced on loopback" in up.stdout and "--password-env VTS_SIM_CAM1_PASSWORD" in up.stdout
    try:
        env = {**os.environ, **load_env_file(folder / "sim.env")}
        rig = load_rig(folder / "rig.yaml")
        found = vts(
            "discover",
            "--interface",
            "127.0.0.1",
            "--timeout",
            "3",
            "--password-env",
            "VTS_SIM_CAM1_PASSWORD",
            "--json",
            env=env,
        )  # as the line of `sim up` says
        assert found.returncode == 0, found.stderr
        rows = {r["port"]: r for r in json.loads(found.stdout)["cameras"] if r["host"] == "127.0.0.1"}
        for cam in rig.cameras:
            row = rows.get(cam.port)
            assert row is not None and row["confirmed"] is True, (cam.name, cam.port, sorted(rows))
            assert sorted(row["announced_by"]) == ["mdns", "ssdp"], row
    finally:
        down = vts("sim", "down", "--dir", str(folder))
    assert down.returncode == 0 and "stopped" in down.stdout, down.stderr
