"""Killed is not finished (issue 32 §3): a scan whose writer died is read as interrupted by every
reader, never as a finished recording; SIGTERM and the console's Ctrl-C stop the scan with the
square wave off and the recording closed; the simulated SPECT follows a wave that a dead host left
on, to the next scan's start pulse (decision 0082).

One simulated rig with the trigger box (the firmware in the emulator) for the module; `vts scan
start` and `vts console` run as users run them (subprocesses), killed with real signals; the
frames are made ahead (SimRig.prerender), so nothing depends on the simulator keeping up. Every
deadline here is a hang detector, never a measure of speed.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
import requests

from console_live import start_console
from inprocess_cli import vts as vts_here
from vts_hw.config import load_rig
from vts_hw.drivers.trigger_box import TriggerBox
from vts_hw.errors import DataError, UsageError
from vts_hw.recording.folder import load_manifest, read_index
from vts_hw.recording.reindex import reindex
from vts_hw.recording.writer import Recording, RecordingExists
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.spect_follower import SpectFollower
from vts_hw.sim_devices.spect_listmode import ListModeTruth
from vts_hw.sim_devices.trigger_box import F_CPU
from vts_hw.tracking.processing import process_recording
from vts_hw.vision.calibration_io import read_calibration as load_calibration

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]
HANG_S = 300.0
pytestmark = pytest.mark.timeout(900)


@pytest.fixture(scope="module")
def box_rig(tmp_path_factory):
    folder = tmp_path_factory.mktemp("killed")
    rig = SimRig(n_cameras=2, seed=3, trigger="triggerbox").start()
    try:
        rig.ntp_sync()
        rig_yaml, _ = rig.write(folder / "rig")
        env = {**os.environ, **rig.env_vars(), "VTS_CONFIG": str(rig_yaml)}
        env.pop("VTS_STORE", None)
        with rig.env():
            yield rig, load_rig(rig_yaml), env, folder
    finally:
        rig.stop()


def _manifest(folder):
    return json.loads((folder / "manifest.json").read_text())


def _until(check, what: str, timeout: float = HANG_S):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = check()
        if got:
            return got
        time.sleep(0.1)
    raise AssertionError(f"{what}: not within {timeout:g} s")


def _recorded(folder, n: int) -> bool:
    """Both cameras hold ``n`` indexed frames and the trigger has fired (the manifest says so)."""
    try:
        counts = [len(read_index(folder / f"{c}.index.csv")) for c in ("cam1", "cam2")]
        fired = _manifest(folder)["trigger"].get("fired")
    except (OSError, ValueError, KeyError, DataError):  # not there yet, or being written
        return False
    return min(counts) >= n and bool(fired)


def _scan(env, folder, seconds=60):
    return subprocess.Popen(
        [*VTS, "scan", "start", "--duration", str(seconds), "--no-live", "-o", str(folder)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _signalled(p: subprocess.Popen, sig: int, ready, what: str) -> str:
    """Send ``sig`` to ``p`` once ``ready()`` (or once it ended by itself); its stderr once it ended."""
    try:
        _until(lambda: p.poll() is not None or ready(), what)
        p.send_signal(sig)
        return p.communicate(timeout=HANG_S)[1]
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()


def _wave_stays_off(box) -> None:
    """The emulated box's square wave is low and stays so (a second of emulated time on)."""
    before = box.edges("OC1A")
    assert before and before[-1].value == 0, "the square wave was left high"
    box.wait_cycles(F_CPU)
    assert box.edges("OC1A") == before, "the square wave is still running"


# -- kill -9 of a scan: every reader says interrupted -------------------------------------------
def test_kill_9_of_a_scan_is_read_as_interrupted_by_every_reader(box_rig, tmp_path, capsys):
    rig, cfg, env, _ = box_rig
    folder = tmp_path / "scan"
    rig.prerender(8.0)
    p = _scan(env, folder)
    try:
        _until(lambda: _recorded(folder, 40) or p.poll() is not None, "40 frames recorded")
        assert p.poll() is None, p.communicate()[1][-2000:]
    finally:
        p.kill()
        p.wait()
    raw = _manifest(folder)
    assert raw["status"] == "recording" and raw["writer"]["pid"] == p.pid  # on disk: as the kill left it

    m = load_manifest(folder)  # every reader reads through it
    assert m["status"] == "interrupted"
    assert m["unfinished"] == (
        f"its recording was interrupted: vts (pid {p.pid}), which wrote it on this computer, "
        f"ended without closing it (killed, or the computer stopped)"
    )

    code, out, err = vts_here(capsys, "recording", "info", folder)
    assert code == 3, (out, err)
    assert err.strip() == f"vts: {folder}: {m['unfinished']} ('vts recording reindex {folder}' marks it recovered)"
    assert f"note: {m['unfinished']}" in out

    # the analyses (vts motion analyze, sync analyze, recording process, the console's) say it first
    tracks = process_recording(folder, load_calibration(cfg.calibration.cameras), workers=1)
    assert tracks.meta["warnings"][0] == f"{m['unfinished']}; analysed up to the last frame written"

    with pytest.raises(DataError, match=re.escape(f"{folder}: {m['unfinished']}: run 'vts recording reindex")):
        Recording(folder, ["cam1", "cam2"], append=True)

    report = reindex(folder)
    assert not report.problems
    after = _manifest(folder)
    assert after["status"] == "recovered" and after["interrupted"] == m["unfinished"] and "unfinished" not in after
    assert after["trigger"]["fired"] and after["kind"] == "scan"
    for name in ("cam1", "cam2"):
        rows = read_index(folder / f"{name}.index.csv")
        assert after["cameras"][name]["frames"] == len(rows) >= 40 and all(r.camera_time is not None for r in rows)
        data = (folder / f"{name}.mjpeg").read_bytes()
        assert all(
            cv2.imdecode(np.frombuffer(data[r.offset : r.offset + r.length], np.uint8), cv2.IMREAD_GRAYSCALE)
            is not None
            for r in rows
        ), f"{name}: an indexed frame does not decode"
        # the bytes after the last indexed frame, if any, are one torn frame at most
        assert len(data) == rows[-1].offset + rows[-1].length or after["cameras"][name]["torn_at_end"] == 1
    code, out, err = vts_here(capsys, "recording", "info", folder)
    assert code == 0 and err == "", err


def test_a_recording_being_made_is_not_taken_for_interrupted(tmp_path, capsys):
    """Its writer runs (this process): read as being recorded; reindex and an append refuse it."""
    rec = Recording(tmp_path / "rec", ["cam1"])
    try:
        m = load_manifest(tmp_path / "rec")
        assert m["status"] == "recording"
        assert m["unfinished"] == f"it is being recorded now by vts (pid {os.getpid()}) on this computer"
        with pytest.raises(UsageError, match="reindex it once that recording has stopped; nothing was changed"):
            reindex(tmp_path / "rec")
        with pytest.raises(RecordingExists, match="add to it once that recording has stopped"):
            Recording(tmp_path / "rec", ["cam1"], append=True)
        code, out, err = vts_here(capsys, "recording", "info", tmp_path / "rec")
        assert code == 0 and "note: it is being recorded now" in out
    finally:
        rec.close()
    assert load_manifest(tmp_path / "rec")["status"] == "complete"


def test_a_recording_written_elsewhere_or_by_an_older_vts_is_never_read_as_finished(tmp_path):
    rec = Recording(tmp_path / "rec", ["cam1"])
    rec.close()
    path = tmp_path / "rec" / "manifest.json"
    data = json.loads(path.read_text())
    data["status"] = "recording"
    for writer, words in (
        ({**data["writer"], "host": "scanner-2\x1b[2J"}, "written on scanner-2[2J, which cannot be asked from here"),
        (None, "names no writer to ask whether it still runs"),
        ({**data["writer"], "pid": 2**22 + 1}, "ended without closing it"),
    ):
        data.pop("writer", None)
        if writer is not None:
            data["writer"] = writer
        path.write_text(json.dumps({**data, "unfinished": "a word from the file: never believed"}))
        m = load_manifest(tmp_path / "rec")
        assert m["status"] == "interrupted" and words in m["unfinished"], m["unfinished"]


@pytest.mark.parametrize("damage", ["garbage", "deleted"])
def test_recording_info_on_a_garbage_or_deleted_manifest_is_exit_3(tmp_path, capsys, damage):
    rec = Recording(tmp_path / "rec", ["cam1"])
    rec.close()
    path = tmp_path / "rec" / "manifest.json"
    if damage == "garbage":
        path.write_bytes(b"\x00garbage{")
        said = f"vts: {path}: not a recording manifest (not valid JSON) ('vts recording reindex "
    else:
        path.unlink()
        said = f"vts: {tmp_path / 'rec'}: no manifest.json, so what the recording promised is not known ("
    code, out, err = vts_here(capsys, "recording", "info", tmp_path / "rec")
    assert code == 3 and err.startswith(said) and len(err.strip().splitlines()) == 1, err


# -- SIGTERM of a scan: closed, the wave off --------------------------------------------------
def test_sigterm_of_a_scan_closes_it_with_the_wave_off(box_rig, tmp_path):
    rig, cfg, env, _ = box_rig
    folder = tmp_path / "scan"
    rig.prerender(8.0)
    p = _scan(env, folder)
    err = _signalled(p, signal.SIGTERM, lambda: _recorded(folder, 25), "25 frames recorded")
    assert p.returncode == 0 and "Traceback" not in err, err[-2000:]
    m = load_manifest(folder)
    assert m["status"] == "complete" and m["scan"]["stop_reason"] == "interrupted" and "unfinished" not in m
    assert m["trigger"]["stop_status"]["running"] is False
    _wave_stays_off(rig.trigger_box)


def test_sigterm_of_any_command_is_ctrl_c_a_recording_closed_as_interrupted(box_rig, tmp_path):
    """SIGTERM is Ctrl-C for every command (vts_hw/cli: `timeout`, `kill`, a service manager):
    `vts camera record` left its manifest at 'recording' before; now it closes it, exit 130."""
    rig, cfg, env, _ = box_rig
    folder = tmp_path / "rec"
    rig.prerender(8.0)
    p = subprocess.Popen(
        [*VTS, "camera", "record", "--all", "--seconds", "60", "-o", str(folder)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    indexed = [folder / f"{n}.index.csv" for n in ("cam1", "cam2")]
    err = _signalled(
        p, signal.SIGTERM, lambda: all(i.exists() and len(read_index(i)) >= 10 for i in indexed), "10 frames recorded"
    )
    assert p.returncode == 130 and "Traceback" not in err, err[-2000:]
    assert err.strip().splitlines()[-1] == f"vts: interrupted; what was recorded is kept in {folder}", err
    m = load_manifest(folder)
    assert m["status"] == "interrupted" and "unfinished" not in m  # closed by its writer, not judged dead
    assert m["finished"] is not None


# -- Ctrl-C (or SIGTERM) of the console during a Scan-page scan -----------------------------------
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_the_console_stopped_during_a_scan_closes_it_with_the_wave_off(box_rig, tmp_path, sig):
    rig, cfg, env, _ = box_rig
    scans = tmp_path / "scans"
    scans.mkdir()
    rig.prerender(10.0)
    p, url = start_console(["--port", "0", "--scans-dir", str(scans)], env)
    try:
        page = requests.get(url + "scan", timeout=30).text
        token = re.search(r'id="scan"[^>]*data-token="([^"]+)"', page)
        r = requests.post(
            url + "scan/start",
            json={"reference_s": 2},
            timeout=30,
            headers={"X-Console-Token": token.group(1), "Origin": url.rstrip("/")},
        )
        assert r.status_code == 200, r.text
        folder = _until(lambda: next(scans.glob("scan-*"), None), "the scan's folder")
        _until(lambda: _recorded(folder, 25) or p.poll() is not None, "25 frames recorded")
        p.send_signal(sig)
        out, err = p.communicate(timeout=HANG_S)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
    assert "Traceback" not in err, err[-3000:]
    m = load_manifest(folder)
    assert m["status"] != "recording" and "unfinished" not in m, m.get("unfinished")
    assert m["scan"]["stop_reason"] == "interrupted"
    assert m["trigger"]["stop_status"]["running"] is False
    _wave_stays_off(rig.trigger_box)


# -- the simulated SPECT after a host that died with the wave on ----------------------------------
def test_the_simulated_spect_follows_a_wave_left_on_to_the_next_scans_start(box_rig, tmp_path):
    """A host fires and dies (its port closed, the wave left on); the next host stops the wave
    and fires again at once. Before, the SPECT took both for one scan and failed with a raw
    ValueError; now each scan is its own list-mode, the first ending before the second's pulse."""
    rig, cfg, env, _ = box_rig
    logs: list[str] = []
    follower = SpectFollower(rig, tmp_path / "spect", log=logs.append).start()
    box = rig.trigger_box
    try:
        first = TriggerBox(box.port)
        first.stop()  # a wave an earlier test's host left on, if any
        first.configure(cfg.trigger.frequency_hz, cfg.trigger.duty)
        first.fire(pulse_ms=cfg.trigger.pulse_ms)
        box.wait_cycles(2 * F_CPU)
        first.close()  # the host is gone; the wave runs on
        second = TriggerBox(box.port)
        second.stop()
        second.fire(pulse_ms=cfg.trigger.pulse_ms)
        box.wait_cycles(2 * F_CPU)
        second.stop()
        second.close()
        written = _until(lambda: len(follower.written) >= 2 or follower.failures, "two list-modes written")
    finally:
        follower.stop()
    assert written and not follower.failures, logs
    one, two = (ListModeTruth.load(str(p) + ".truth.json") for p in follower.written[:2])
    pulses = [box.host_time(e.cycle) for e in box.edges("CH2") if e.value == 1][-2:]
    assert one.acquisition_start_host < pulses[1] and two.acquisition_start_host > pulses[1]
    assert one.acquisition_start_host + one.duration_s <= pulses[1]
    assert math.isfinite(two.duration_s) and two.duration_s > 1.0
    assert not any("ValueError" in line for line in logs), logs
