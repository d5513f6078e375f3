"""The camera contract and its kinds: ``axis``, ``mjpeg`` (no Axis stamps, times from receipt)
and ``replay`` (a recording played back as live cameras), each opened from rig.yaml's ``kind:``
and run through the live pipeline: the recorder, processing, the daily drift QA, the scan."""

from __future__ import annotations

import time

import numpy as np
import pytest
import yaml

from inprocess_cli import vts
from vts_hw.camera import Camera, Illumination, Parameters, RunningTime
from vts_hw.config import parse_rig
from vts_hw.drivers.registry import CAMERA_KINDS, open_camera, open_cameras
from vts_hw.errors import ConfigError, DataError
from vts_hw.recording.axis_jpeg import inspect_jpeg
from vts_hw.recording.capture import FrameRecorder
from vts_hw.recording.folder import load_manifest, read_index
from vts_hw.tolerance import State


def _rig(cameras: list[dict], **extra) -> object:
    return parse_rig({"rig": "kinds", "cameras": cameras, **extra}, "test rig.yaml")


def _replay_entries(folder, names=("cam1", "cam2"), speed=8.0) -> list[dict]:
    return [
        {"name": n, "kind": "replay", "options": {"folder": str(folder), "camera": n, "speed": speed}} for n in names
    ]


def _record(cameras, folder, seconds=None):
    rec = FrameRecorder(cameras, folder, seconds=seconds)
    rec.start()
    rec.wait()
    manifest = rec.finish()
    for c in cameras:
        c.close()
    return rec, manifest


# -- the registry -------------------------------------------------------------------------
def test_every_kind_implements_the_contract(sim_rig, tmp_path):
    assert set(CAMERA_KINDS) >= {"axis", "mjpeg", "replay"}
    cfg = sim_rig.config()
    _record(open_cameras(cfg.cameras[:1]), tmp_path / "rec", seconds=1.0)
    entries = [
        cfg.cameras[0].model_dump(mode="json", exclude_none=True),
        {**cfg.cameras[1].model_dump(mode="json", exclude_none=True), "kind": "mjpeg"},
        *_replay_entries(tmp_path / "rec", ("cam1",)),
    ]
    entries[2]["name"] = "cam3"
    entries[2]["options"]["camera"] = "cam1"
    rig = _rig(entries)
    kinds = {}
    for c in rig.cameras:
        with open_camera(c) as cam:
            assert isinstance(cam, Camera), c.kind
            kinds[c.kind] = type(cam).__name__
    assert kinds == {"axis": "AxisCamera", "mjpeg": "MjpegCamera", "replay": "ReplayCamera"}


def test_kind_defaults_to_axis_and_an_unknown_kind_is_named(tmp_path, sim_rig, capsys):
    cfg = sim_rig.config()
    assert cfg.cameras[0].kind == "axis"
    bad = _rig([{"name": "cam9", "kind": "webcam", "host": "127.0.0.1"}])
    with pytest.raises(ConfigError, match=r"camera 'cam9': unknown kind 'webcam' \(known: axis, mjpeg, replay"):
        open_camera(bad.cameras[0])
    with pytest.raises(ConfigError, match=r"camera 'cam1' \(kind axis\) needs a host"):
        open_camera(_rig([{"name": "cam1"}]).cameras[0])
    # on the command line: one sentence, exit 2, no traceback
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"rig": "x", "cameras": [{"name": "cam9", "kind": "webcam", "host": "h"}]}))
    code, out, err = vts(capsys, "camera", "snapshot", "cam9", "-o", tmp_path / "a.jpg", "--config", path)
    assert code == 2, err
    assert "unknown kind 'webcam'" in err and "Traceback" not in err


def test_kind_options_are_checked_by_the_kind(tmp_path):
    rig = _rig([{"name": "cam1", "kind": "replay", "options": {"folder": str(tmp_path / "nope")}}])
    with pytest.raises(ConfigError, match=r"camera 'cam1' \(kind replay\): options.folder: no such folder"):
        open_camera(rig.cameras[0])
    rig = _rig([{"name": "cam1", "kind": "replay", "options": {"folder": str(tmp_path), "sped": 2}}])
    with pytest.raises(ConfigError, match=r"options.sped"):
        open_camera(rig.cameras[0])
    rig = _rig([{"name": "cam1", "kind": "replay", "options": {"folder": str(tmp_path), "speed": 0}}])
    with pytest.raises(ConfigError, match=r"options.speed"):
        open_camera(rig.cameras[0])


# -- mjpeg: no Axis stamps, times from receipt ---------------------------------------------
def test_the_simulated_camera_can_switch_its_stamps_off(sim_rig, cam1):
    assert inspect_jpeg(cam1.snapshot().jpeg).time is not None
    sim_rig.servers["cam1"].faults.no_axis_stamps = True
    jpeg = cam1.snapshot().jpeg
    info = inspect_jpeg(jpeg)
    assert info.time is None and info.product is None
    assert cam1.snapshot().camera_time is None  # the Axis driver finds no time either


def test_mjpeg_kind_records_a_camera_without_stamps(sim_rig, tmp_path):
    for s in sim_rig.servers.values():
        s.faults.no_axis_stamps = True
    cfg = sim_rig.config()
    entries = [
        {**c.model_dump(mode="json", exclude_none=True), "kind": "mjpeg", "options": {"led": "vapix"}}
        for c in cfg.cameras
    ]
    rig = _rig(entries)
    with open_camera(rig.cameras[0]) as cam:
        t0 = time.time()
        f = cam.snapshot()
        assert f.camera_time is None and f.time_source == "receipt" and f.host_time >= t0
        off = cam.clock_offset(samples=3)
        assert off.source == "receipt" and off.method == "receipt" and off.offset_s == 0.0
        assert off.uncertainty_s > 0
        assert "receipt" in cam.device_info()["Clock"]
        assert isinstance(cam, Illumination) and not isinstance(cam, (Parameters, RunningTime))
    rec, manifest = _record(open_cameras(rig.cameras), tmp_path / "rec", seconds=2.0)
    assert manifest["status"] == "complete", rec.problems()
    for name in ("cam1", "cam2"):
        rows = read_index(tmp_path / "rec" / f"{name}.index.csv")
        assert len(rows) >= 25 and all(r.camera_time is None for r in rows)
        host = [r.host_time for r in rows]
        assert host == sorted(host)
        assert any("receipt" in n for n in manifest["cameras"][name]["stream_notes"])


def test_mjpeg_kind_runs_the_drift_qa(sim_rig, tmp_path):
    from qa_runs import run_qa, save_baselines
    from vts_hw.procedures.baseline import take_baselines
    from vts_hw.store import ResultsStore

    for s in sim_rig.servers.values():
        s.faults.no_axis_stamps = True
    cfg = sim_rig.config()
    rig = _rig(
        [
            {**c.model_dump(mode="json", exclude_none=True), "kind": "mjpeg", "options": {"led": "vapix"}}
            for c in cfg.cameras
        ],
        results={"url": f"sqlite:///{tmp_path / 'r.sqlite'}"},
    )
    with ResultsStore(rig.results.url) as store:
        cams = open_cameras(rig.cameras)
        save_baselines(store, take_baselines(cams, frames=2).baselines)
        for c in cams:
            c.close()
        res = run_qa(rig, store, steps=("clock", "drift"), n_frames=2, open_camera=open_camera)
    assert res.state == State.OK, res.results()
    for c in res.cameras:
        assert c.drift.led_off_visible == 0  # the LED is switched through the camera's port


# -- replay: a recording played back as live cameras ----------------------------------------
@pytest.fixture(scope="module")
def sim_session(tmp_path_factory):
    from vts_hw.sim_devices.recording_sim import simulate_recording

    folder = tmp_path_factory.mktemp("replay") / "session"
    return folder, simulate_recording(folder, duration_s=3.0, seed=2)


def test_replay_recorded_again_is_the_same_recording(sim_session, tmp_path):
    folder, sim = sim_session
    rig = _rig(_replay_entries(folder, speed=6.0))
    cams = open_cameras(rig.cameras)
    assert all(not isinstance(c, Illumination) and "no-op" in c.device_info()["LED"] for c in cams)
    t0 = time.monotonic()
    rec, manifest = _record(cams, tmp_path / "again")  # until the replay ends
    elapsed = time.monotonic() - t0
    assert manifest["status"] == "complete", rec.problems()
    for name in ("cam1", "cam2"):
        a = read_index(folder / f"{name}.index.csv")
        b = read_index(tmp_path / "again" / f"{name}.index.csv")
        assert [(r.camera_time, r.host_time) for r in b] == [(r.camera_time, r.host_time) for r in a]
        ja, jb = (folder / f"{name}.mjpeg").read_bytes(), (tmp_path / "again" / f"{name}.mjpeg").read_bytes()
        assert ja == jb
    span = max(r.host_time for r in a) - min(r.host_time for r in a)
    assert elapsed >= span / 6.0 * 0.9  # played at the speed asked, not dumped at once (a lower bound)


def test_replay_processes_as_the_original(sim_session, tmp_path):
    from vts_hw.tracking.processing import process_recording

    folder, sim = sim_session
    rig = _rig(_replay_entries(folder, speed=10.0))
    _record(open_cameras(rig.cameras), tmp_path / "again")
    models = {c: sim.scene.camera_at(c, sim.scene.start_epoch + 1.0) for c in sim.cameras}
    original = process_recording(folder, models, workers=1)
    replayed = process_recording(tmp_path / "again", models, workers=1)
    assert len(replayed) == len(original) > 50
    np.testing.assert_array_equal(replayed.xyz, original.xyz)
    np.testing.assert_array_equal(replayed.host_time, original.host_time)


def test_replay_snapshot_is_the_frame_at_the_playback_time(sim_session):
    folder, _ = sim_session
    rows = read_index(folder / "cam1.index.csv")
    with open_camera(_rig(_replay_entries(folder, ("cam1",), speed=2.0)).cameras[0]) as cam:
        first = cam.snapshot()
        assert first.camera_time == rows[0].camera_time and first.time_source == "recording"
        time.sleep(0.5)
        later = cam.snapshot()
        assert later.camera_time - first.camera_time >= 2.0 * 0.5 - 0.05  # at least as far as played
        off = cam.clock_offset()
        d = [r.camera_time - r.host_time for r in rows]
        assert off.source == "recording" and min(d) <= off.offset_s <= max(d)


def test_replay_of_a_camera_not_in_the_recording_is_named(sim_session):
    folder, _ = sim_session
    rig = _rig([{"name": "cam7", "kind": "replay", "options": {"folder": str(folder)}}])
    with pytest.raises(DataError, match=r"no camera 'cam7' in this recording \(it has cam1, cam2\)"):
        open_camera(rig.cameras[0])


@pytest.fixture()
def rig_recording(sim_rig, tmp_path):
    """Two seconds of the simulated rig (wall markers, LED on), recorded as any session is."""
    folder = tmp_path / "rig-session"
    cams = open_cameras(sim_rig.config().cameras)
    for c in cams:
        c.led_on()
    _, manifest = _record(cams, folder, seconds=2.0)
    assert manifest["status"] == "complete"
    return folder


def test_replay_runs_the_daily_drift_qa(rig_recording, tmp_path):
    from qa_runs import run_qa, save_baselines
    from vts_hw.procedures.baseline import take_baselines
    from vts_hw.store import ResultsStore

    rig = _rig(_replay_entries(rig_recording, speed=1.0), results={"url": f"sqlite:///{tmp_path / 'r.sqlite'}"})
    with ResultsStore(rig.results.url) as store:
        cams = open_cameras(rig.cameras)
        # frames spread over 0.5 s, not the baseline's 3 s: the recording replayed lasts 2 s
        baselines = take_baselines(cams, frames=3, span_s=0.5).baselines
        save_baselines(store, baselines)
        assert all(len(b.markers) == 5 for b in baselines)
        for c in cams:
            c.close()
        res = run_qa(rig, store, n_frames=3, open_camera=open_camera)  # the whole daily set
        assert res.run_id is not None and store.run(res.run_id).procedure == "daily"
    assert res.state == State.OK, res.results()
    for c in res.cameras:
        assert c.drift.led_off_visible is None and abs(c.drift.drift_px[0]) < 0.1
        assert any("parameters not checked" in p for p in c.problems)
        metrics = {m[1] for m in c.measures}
        assert {"camera_reachable", "clock_offset_s", "drift_x_px"} <= metrics and "params_changed" not in metrics
    assert "LED check: not made" in res.cameras[0].drift.results()


def test_replay_runs_a_scan_session(rig_recording, tmp_path):
    from vts_hw.procedures.scan import ScanSession

    rig = _rig(_replay_entries(rig_recording, speed=1.0))
    m = ScanSession(rig, tmp_path / "scan", open_cameras(rig.cameras), duration=1.0).run()
    assert m["status"] == "complete", m["scan"]["problems"]
    for name in ("cam1", "cam2"):
        assert m["cameras"][name]["frames"] >= 10
        assert m["cameras"][name]["clock_offset_before"]["source"] == "recording"
        assert "no parameters" in m["cameras"][name]["parameters"]
        assert m["cameras"][name]["led"] == "none (this kind of camera cannot switch an LED)"  # not "on"
    assert load_manifest(tmp_path / "scan")["status"] == "complete"


def test_replay_from_the_command_line(rig_recording, tmp_path, capsys):
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"rig": "replayed", "cameras": _replay_entries(rig_recording, ("cam1",))}))
    code, out, err = vts(capsys, "camera", "info", "cam1", "--json", "--config", path)
    assert code == 0, err
    assert '"kind": "replay"' in out and "no-op" in out
    snap = tmp_path / "snap.jpg"
    code, out, err = vts(capsys, "camera", "snapshot", "cam1", "-o", snap, "--config", path)
    assert code == 0, err
    assert snap.read_bytes()[:2] == b"\xff\xd8"


def test_only_the_registry_builds_cameras():
    """Procedures, the CLI and the scenarios receive cameras; none of them builds an AxisCamera."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    builds = re.compile(r"\b(AxisCamera|MjpegCamera|ReplayCamera)(\.from_config)?\(")
    found = [
        f"{p.relative_to(root)}:{n}"
        for folder in ("vts_hw", "procedures", "sim_devices", "drivers", "bench")
        for p in sorted((root / folder).rglob("*.py"))
        if p.name not in ("axis.py", "mjpeg.py", "replay.py")
        for n, line in enumerate(p.read_text().splitlines(), 1)
        if builds.search(line)
    ]
    assert found == []
