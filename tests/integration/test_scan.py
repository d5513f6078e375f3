"""The scan session on the simulated rig: cameras over HTTP, the trigger box firmware in the
emulator over a pty, the function generator on a TCP socket (VISA SOCKET through pyvisa-py). What the box really emitted comes
from the emulator's pin log; the camera clock offsets are scored against the scene's truth."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
import time

import cv2
import numpy as np
import pytest

from inprocess_cli import run as vts_run
from vts_hw import __version__
from vts_hw.config import load_rig
from vts_hw.drivers.registry import open_cameras
from vts_hw.drivers.trigger import read_log
from vts_hw.errors import DataError
from vts_hw.procedures.scan import ScanError, ScanSession
from vts_hw.recording.folder import read_index
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.trigger_box import F_CPU

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]
FPS = 25.0
HANG_S = 300.0  # a hang detector for a `vts` subprocess: minutes on a loaded machine, seconds when idle
# a scan's frames are made ahead (SimRig.prerender): its recording is whole however busy the machine is
pytestmark = pytest.mark.timeout(600)


def _ahead(rig, seconds: float) -> None:
    """The cameras' frames for the next ``seconds`` of streaming (and 6 s to start and stop) made
    ahead of time: they start playing at the first stream."""
    rig.prerender(seconds + 6.0)


def _rig(trigger, tmp_path):
    rig = SimRig(n_cameras=2, seed=3, trigger=trigger).start()
    rig.ntp_sync()
    rig_yaml, _ = rig.write(tmp_path / "rig")
    return rig, load_rig(rig_yaml), rig_yaml


@pytest.fixture()
def box_rig(tmp_path):
    rig, cfg, path = _rig("triggerbox", tmp_path)
    with rig.env():
        yield rig, cfg, path
    rig.stop()


@pytest.fixture()
def plain_rig(tmp_path):
    rig, cfg, path = _rig("none", tmp_path)
    with rig.env():
        yield rig, cfg, path
    rig.stop()


def _env(rig, rig_yaml):
    return {**os.environ, **rig.env_vars(), "VTS_CONFIG": str(rig_yaml)}


def _manifest(folder):
    return json.loads((folder / "manifest.json").read_text())


def _frames_decode(folder, cam):
    """Every indexed frame decodes to a 640x480 image; returns the index rows."""
    rows = read_index(folder / f"{cam}.index.csv")
    data = (folder / f"{cam}.mjpeg").read_bytes()
    for r in rows:
        img = cv2.imdecode(np.frombuffer(data[r.offset : r.offset + r.length], np.uint8), cv2.IMREAD_GRAYSCALE)
        assert img is not None and img.shape == (480, 640), f"{cam} frame {r.frame} does not decode"
    return rows


def _check_offsets(rig, cam_manifest, name):
    """Offsets before and after against the scene's clock at the time each was measured;
    returns the errors (measured - true) in seconds."""
    errors = []
    for key in ("clock_offset_before", "clock_offset_after"):
        m = cam_manifest[key]
        truth = rig.scene.clocks[name].camera_time(m["host_time"]) - m["host_time"]
        assert abs(m["offset_s"] - truth) <= m["uncertainty_s"] + 0.002, (name, key, m, truth)
        errors.append(m["offset_s"] - truth)
    return errors


def test_session_with_the_trigger_box(box_rig, tmp_path):
    rig, cfg, rig_yaml = box_rig
    folder = tmp_path / "scan"
    _ahead(rig, 4.0)
    m = ScanSession(cfg, folder, open_cameras(cfg.cameras), duration=4.0).run()

    assert m["status"] == "complete" and m["scan"]["problems"] == [] and m["scan"]["stop_reason"] == "duration"
    assert m["software"]["version"] == __version__
    assert m["rig_digest"] == hashlib.sha256(rig_yaml.read_bytes()).hexdigest()
    tr = m["trigger"]
    assert tr["fired"] and tr["mode"] == "start pulses and square wave" and tr["start_pulses"] and tr["errors"] == []
    assert tr["fire_time_source"].startswith("first rising edge")
    assert tr["clock_mapping_before"]["samples"] >= 5 and tr["clock_mapping_after"]["samples"] >= 5
    fire = tr["fire_time"]
    assert 0 <= fire - tr["fire_sent_host_time"] < 0.05

    # both recordings complete, begun before the fire, every frame decodes
    for name in ("cam1", "cam2"):
        c = m["cameras"][name]
        rows = _frames_decode(folder, name)
        assert len(rows) == c["frames"] >= 4.0 * FPS and c["gaps"] == [] and c["reconnects"] == 0
        assert rows[0].host_time < fire < rows[-1].host_time - 4.0
        before, after = _check_offsets(rig, c, name)
        print(
            f"{name}: {c['frames']} frames, offset {c['clock_offset_before']['offset_s']:+.4f} s, error "
            f"before {before * 1e3:+.2f} ms, after {after * 1e3:+.2f} ms "
            f"(uncertainty {c['clock_offset_before']['uncertainty_s'] * 1e3:.2f} ms)"
        )

    assert "no_watchdog" not in tr  # the box stops its own wave if this computer dies
    # what the box really emitted: both start pulses on the square wave's first rising edge
    sim = rig.trigger_box
    up = [e.cycle for e in sim.edges("OC1A") if e.value == 1]
    assert len(up) == tr["edges"] == tr["stop_status"]["edges"] >= 4
    assert sim.edges("OC1A")[-1].value == 0  # stopped, low
    for pin in ("CH1", "CH2"):
        e = sim.edges(pin)
        assert [x.value for x in e] == [1, 0], pin
        assert abs(e[0].cycle - up[0]) <= 16 * 10  # the same tick (10 us)
        assert abs((e[1].cycle - e[0].cycle) / F_CPU - cfg.trigger.pulse_ms / 1000) < 0.001
    period = np.diff(up) / F_CPU
    assert np.allclose(period, 1 / cfg.trigger.frequency_hz, atol=1e-5)
    print(
        f"trigger: {len(up)} rising edges, period {period.mean():.6f} s, fire - sent "
        f"{(fire - tr['fire_sent_host_time']) * 1e3:.1f} ms"
    )

    # the log holds the fire and the edges
    log = read_log(folder / "trigger.csv")
    assert any(r["kind"] == "cmd" and r["text"] == "*TRG" for r in log)
    edges = [r for r in log if r["kind"] == "edge"]
    assert edges and int(edges[0]["device_time_us"]) == tr["fire_status"]["first_edge_device_us"]


def test_session_with_the_function_generator(tmp_path):
    rig, cfg, _ = _rig("visa", tmp_path)
    assert cfg.trigger.address == rig.function_generator.resource and not cfg.trigger.options.get("simulated", False)
    try:
        _ahead(rig, 3.0)
        with rig.env():
            m = ScanSession(cfg, tmp_path / "scan", open_cameras(cfg.cameras), duration=3.0).run()
    finally:
        runs = rig.function_generator.instrument.runs(1)
        rig.stop()
    tr = m["trigger"]
    # what the instrument on its socket really did: one 1 Hz 0..2.5 V square wave, on from the
    # fire to the stop the session logged
    (run,) = runs
    assert (run.function, run.frequency_hz, run.duty_percent, run.high_v, run.low_v) == ("SQU", 1.0, 50.0, 2.5, 0.0)
    assert tr["fire_sent_host_time"] <= run.start <= tr["fire_confirmed_host_time"]
    assert run.stop is not None and run.stop <= tr["stopped_host_time"] and run.stop - run.start >= 3.0
    assert m["status"] == "complete" and tr["fired"]
    assert tr["mode"] == "square wave only" and tr["start_pulses"] is False and "start pulses" in tr["note"]
    # a 33500 has no watchdog: the scan says so before it starts, and keeps it (decision 0083)
    assert (
        "cannot switch its square wave off by itself" in tr["no_watchdog"] and "vts trigger stop" in tr["no_watchdog"]
    )
    assert tr["confirmed"]["high_v"] == 2.5 and tr["confirmed"]["low_v"] == 0.0
    assert tr["fire_status"]["running"] and not tr["stop_status"]["running"]
    assert "clock_mapping_before" not in tr  # a 33500 has no clock to map
    sent = [r["text"] for r in read_log(tmp_path / "scan" / "trigger.csv") if r["kind"] == "cmd"]
    assert "OUTP 1" in sent and sent.index("OUTP 1") < sent.index("OUTP 0")
    for name in ("cam1", "cam2"):
        assert m["cameras"][name]["frames"] >= 3.0 * FPS and m["cameras"][name]["gaps"] == []
        _check_offsets(rig, m["cameras"][name], name)


def test_a_camera_off_the_network_for_5_s(plain_rig, tmp_path):
    rig, cfg, _ = plain_rig
    folder = tmp_path / "scan"
    duration = 8.0
    _ahead(rig, duration)
    s = ScanSession(cfg, folder, open_cameras(cfg.cameras), duration=duration)
    s.start()
    threading.Timer(1.0, rig.servers["cam1"].go_offline, (5.0,)).start()
    m = s.stop(s.wait())

    assert m["status"] == "partial" and m["trigger"]["backend"] == "none" and m["trigger"]["fired"] is False
    assert not (folder / "trigger.csv").exists()
    c1, c2 = m["cameras"]["cam1"], m["cameras"]["cam2"]
    # the other camera: complete, nothing missing
    assert c2["gaps"] == [] and c2["frames"] >= 0.98 * duration * FPS
    assert len(_frames_decode(folder, "cam2")) == c2["frames"]
    # the camera that went away: its gap stated, in camera time, at least the 5 s it was away
    gap = max(c1["gaps"], key=lambda g: g["missing"])
    secs = gap["camera_t1"] - gap["camera_t0"]
    assert 5.0 <= secs < 7.5 and gap["missing"] == round(secs * FPS) - 1
    assert c1["reconnects"] >= 1 and c1["frames"] + c1["dropped_frames"] >= 0.98 * duration * FPS
    assert len(_frames_decode(folder, "cam1")) == c1["frames"]
    assert any(p.startswith("camera cam1:") and "missing" in p for p in m["scan"]["problems"])
    assert not any("cam2" in p for p in m["scan"]["problems"])
    print(
        f"cam2 {c2['frames']} frames in {duration:g} s; cam1 {c1['frames']} frames, gap {secs:.2f} s "
        f"({gap['missing']} missing), {c1['reconnects']} reconnect(s)"
    )


def test_trigger_unplugged_during_the_scan_keeps_the_recordings(box_rig, tmp_path):
    rig, cfg, _ = box_rig
    folder = tmp_path / "scan"
    _ahead(rig, 3.0)
    s = ScanSession(cfg, folder, open_cameras(cfg.cameras), duration=3.0)
    s.start()
    time.sleep(1.0)
    rig.trigger_box.unplug()
    m = s.stop(s.wait())
    assert m["status"] == "partial" and m["trigger"]["fired"]
    assert m["trigger"]["errors"] and all(p.startswith("trigger:") for p in m["scan"]["problems"])
    for name in ("cam1", "cam2"):
        assert m["cameras"][name]["frames"] >= 3.0 * FPS and m["cameras"][name]["gaps"] == []
    assert any(r["text"] == "*TRG" for r in read_log(folder / "trigger.csv"))
    print("trigger unplugged:", m["trigger"]["errors"])


def test_trigger_that_fails_to_fire_keeps_the_recordings(box_rig, tmp_path):
    rig, cfg, _ = box_rig
    folder = tmp_path / "scan"

    def unplug_before_the_fire(step, text):
        if step == "first frames":
            rig.trigger_box.unplug()

    _ahead(rig, 2.0)
    m = ScanSession(cfg, folder, open_cameras(cfg.cameras), duration=2.0, on_step=unplug_before_the_fire).run()
    tr = m["trigger"]
    assert m["status"] == "partial" and tr["fired"] is False and tr["errors"][0].startswith("fire: ")
    assert any(p.startswith("trigger: fire: ") for p in m["scan"]["problems"])
    for name in ("cam1", "cam2"):
        assert m["cameras"][name]["frames"] >= 2.0 * FPS and m["cameras"][name]["gaps"] == []
        assert len(_frames_decode(folder, name)) == m["cameras"][name]["frames"]


def test_no_first_frame_means_no_fire(box_rig, tmp_path):
    rig, cfg, _ = box_rig
    rig.servers["cam2"].faults.max_viewers = 0  # answers the checks, never streams (HTTP 503)
    folder = tmp_path / "scan"
    with pytest.raises(ScanError, match="camera cam2 delivered no frame within 1 s"):
        ScanSession(cfg, folder, open_cameras(cfg.cameras), duration=2.0, first_frame_timeout=1.0).start()
    m = _manifest(folder)
    assert m["status"] == "failed" and m["trigger"]["fired"] is False and m["scan"]["stop_reason"] == "no first frame"
    assert rig.trigger_box.edges() == []  # nothing started the SPECT
    assert m["cameras"]["cam1"]["frames"] > 0 and m["cameras"]["cam2"]["frames"] == 0
    assert len(_frames_decode(folder, "cam1")) == m["cameras"]["cam1"]["frames"]


def test_unreachable_camera_is_named_and_nothing_is_written(box_rig, tmp_path):
    rig, cfg, _ = box_rig
    rig.servers["cam2"].stop()
    folder = tmp_path / "scan"
    with pytest.raises(ScanError, match=r"camera cam2 at http://127\.0\.0\.1:\d+ is unreachable"):
        ScanSession(cfg, folder, open_cameras(cfg.cameras), duration=1.0).start()
    assert not folder.exists()
    assert rig.trigger_box.edges() == []  # the trigger was never reached


def test_cli_scan_with_duration(box_rig, tmp_path):
    rig, cfg, rig_yaml = box_rig
    folder = tmp_path / "scan"
    # no patient in the room: nothing to track live (with --live, exit 0 means the patient was watched)
    _ahead(rig, 3.0)
    p = subprocess.run(
        [*VTS, "scan", "start", "--duration", "3", "--no-live", "-o", str(folder)],
        env=_env(rig, rig_yaml),
        capture_output=True,
        text=True,
        timeout=HANG_S,
    )
    assert p.returncode == 0, p.stderr
    assert f"{folder}: status complete (stopped: duration)" in p.stdout
    assert "cam1:" in p.stdout and "trigger: triggerbox fired at" in p.stdout
    assert "Traceback" not in p.stderr
    m = _manifest(folder)
    assert m["status"] == "complete" and m["rig_digest"] == hashlib.sha256(rig_yaml.read_bytes()).hexdigest()
    for name in ("cam1", "cam2"):
        assert m["cameras"][name]["frames"] >= 3.0 * FPS


def test_ctrl_c_stops_cleanly(plain_rig, tmp_path):
    rig, cfg, rig_yaml = plain_rig
    folder = tmp_path / "scan"
    _ahead(rig, 3.0)
    # PYTHONFAULTHANDLER: a scan that does not stop is aborted and says where every thread was.
    # Started with SIGINT ignored, as a shell starts a background job (or nohup, a service):
    # Python then installs no KeyboardInterrupt, and Ctrl-C must still stop the scan.
    p = subprocess.Popen(
        [*VTS, "scan", "start", "--json", "--no-live", "-o", str(folder)],
        env={**_env(rig, rig_yaml), "PYTHONFAULTHANDLER": "1"},
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    _wait_frames(folder, 50, p)
    p.send_signal(signal.SIGINT)
    try:
        out, err = p.communicate(timeout=HANG_S)  # a hang detector: stopping takes ~1 s when idle
    except subprocess.TimeoutExpired:
        p.send_signal(signal.SIGABRT)
        out, err = p.communicate(timeout=30)
        raise AssertionError(
            f"the scan did not stop within {HANG_S:g} s of Ctrl-C; its threads:\n{err[-6000:]}"
        ) from None
    assert p.returncode == 0, err
    m = json.loads(out)
    assert m["status"] == "complete" and m["scan"]["stop_reason"] == "interrupted"
    assert m == _manifest(folder)
    for name in ("cam1", "cam2"):
        assert len(read_index(folder / f"{name}.index.csv")) == m["cameras"][name]["frames"] >= 50


def test_dry_run_touches_nothing(box_rig, tmp_path):
    rig, cfg, rig_yaml = box_rig
    folder = tmp_path / "scan"
    p = vts_run(
        "scan", "start", "--dry-run", "--duration", "60", "-o", folder, env=_env(rig, rig_yaml)
    )  # (in this process)
    assert p.returncode == 0, p.stderr
    assert "dry run" in p.stdout and "fire:" in p.stdout and "record for 60 s" in p.stdout
    assert not folder.exists()
    for srv in rig.servers.values():
        assert srv.state()["requests"] == 0
    assert rig.trigger_box.uart() == [] and rig.trigger_box.edges() == []


def _wait_frames(folder, n, proc, timeout=HANG_S):
    """Until both cameras have ``n`` indexed frames and the trigger has fired (manifest)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, "the scan process ended early"
        try:
            counts = [len(read_index(folder / f"{c}.index.csv")) for c in ("cam1", "cam2")]
            fired = _manifest(folder)["scan"]["times"].get("scan_started")
        except (OSError, ValueError, KeyError, DataError):  # not there yet, or being written
            counts, fired = [0], None
        if min(counts) >= n and fired:
            return
        time.sleep(0.1)
    raise AssertionError(f"no {n} frames in {folder} within {timeout:g} s")


def test_disk_full_during_a_scan_stops_it_and_keeps_every_whole_frame(plain_rig, small_disk):
    rig, cfg, rig_yaml = plain_rig
    disk = small_disk(1536)
    folder = disk.path / "scan"
    _ahead(rig, 6.0)
    p = subprocess.run(
        [*VTS, "scan", "start", "--duration", "30", "-o", str(folder)],
        env=_env(rig, rig_yaml),
        capture_output=True,
        text=True,
        timeout=HANG_S,
    )
    assert p.returncode == 3, p.stdout + p.stderr
    assert "no space left on device" in p.stderr and "whole frame(s)" in p.stderr and "Traceback" not in p.stderr
    m = _manifest(folder)
    assert m["status"] == "partial" and m["scan"]["stop_reason"] == "disk full"
    assert any("recording stopped" in x for x in m["scan"]["problems"])
    for name in ("cam1", "cam2"):
        rows = _frames_decode(folder, name)
        assert len(rows) == m["cameras"][name]["frames"] > 0
        assert (folder / f"{name}.mjpeg").stat().st_size == rows[-1].offset + rows[-1].length
    assert not [f for f in disk.files() if f.endswith(".tmp") or "reserve" in f]


def test_scan_refuses_durations_that_are_not(plain_rig, tmp_path):
    rig, cfg, rig_yaml = plain_rig
    for bad in ("nan", "inf", "-1", "0"):
        p = vts_run(
            "scan", "start", "--duration", bad, "-o", tmp_path / "s", env=_env(rig, rig_yaml)
        )  # (in this process)
        assert p.returncode == 2 and "--duration" in p.stderr, (bad, p.stderr)
    assert not (tmp_path / "s").exists()
