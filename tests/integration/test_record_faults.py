"""`vts camera record|snapshot|stream` and `vts recording reindex` as a user runs them, when
things go wrong: nothing recorded is lost or changed, and nothing says "complete" when it is not.

The simulated rig runs in this process (its faults switched directly); `vts` runs in this
process too (tests/inprocess_cli.py, as the console script runs it) with the rig.yaml and password
variables the rig writes. The reindex tests start from copies of one recording made once.
"""

import json
import os
import shutil

import pytest

from inprocess_cli import run
from vts_hw.recording.folder import read_index
from vts_hw.recording.mjpeg import split_jpegs
from vts_hw.sim_devices.rig import SimRig


def vts(env, *args):
    return run(*args, env=env)


def _rig(folder):
    with SimRig(n_cameras=2, seed=3) as r:
        cfg_dir = folder / "sim"
        r.write(cfg_dir)
        env = dict(os.environ, **r.env_vars(), VTS_CONFIG=str(cfg_dir / "rig.yaml"))
        yield r, env


@pytest.fixture()
def rig(tmp_path):
    yield from _rig(tmp_path)


@pytest.fixture(scope="module")
def one_second(tmp_path_factory):
    """`vts camera record cam1 --seconds 1`, once for the module: what the reindex tests damage
    (each a copy of its own)."""
    folder = tmp_path_factory.mktemp("one-second")
    for _, env in _rig(folder):
        assert vts(env, "camera", "record", "cam1", "--seconds", "1", "-o", str(folder / "rec")).returncode == 0
    return folder / "rec"


def _consistent(folder, cam):
    """The index lists exactly the whole frames of the .mjpeg, in order."""
    rows = read_index(folder / f"{cam}.index.csv")
    data = (folder / f"{cam}.mjpeg").read_bytes()
    spans = [s for s in split_jpegs(data) if s.complete]
    assert [(r.offset, r.length) for r in rows] == [(s.offset, s.length) for s in spans]
    assert [r.frame for r in rows] == list(range(len(rows)))
    assert len(data) == (rows[-1].offset + rows[-1].length if rows else 0)
    return len(rows)


def _scan_like(folder):
    """Give a recording the sections a scan session adds, as `vts scan start` would."""
    m = json.loads((folder / "manifest.json").read_text())
    m["scan"] = {"times": {"scan_started": 1.0}, "problems": []}
    m["trigger"] = {"backend": "triggerbox", "fired": True}
    m["cameras"]["cam1"]["gaps"] = [{"after_frame": 3, "missing": 2, "reason": "test"}]
    (folder / "manifest.json").write_text(json.dumps(m))
    return m


def test_record_never_modifies_an_existing_recording(rig, tmp_path):
    _, env = rig
    out = tmp_path / "session1"
    assert vts(env, "camera", "record", "cam1", "cam2", "--seconds", "1", "-o", str(out)).returncode == 0
    _scan_like(out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    p = vts(env, "camera", "record", "cam1", "--seconds", "1", "-o", str(out))
    assert p.returncode == 2
    assert "already holds a recording" in p.stderr and "--append" in p.stderr and "Traceback" not in p.stderr
    assert {q.name: q.read_bytes() for q in out.iterdir()} == before


def test_append_keeps_every_entry(rig, tmp_path):
    _, env = rig
    out = tmp_path / "session1"
    assert vts(env, "camera", "record", "cam1", "cam2", "--seconds", "1", "-o", str(out)).returncode == 0
    old = _scan_like(out)
    n1 = _consistent(out, "cam1")
    p = vts(env, "camera", "record", "cam1", "--seconds", "1", "-o", str(out), "--append")
    assert p.returncode == 0, p.stderr
    m = json.loads((out / "manifest.json").read_text())
    assert m["scan"] == old["scan"] and m["trigger"] == old["trigger"]
    assert m["started"] == old["started"] and m["cameras"]["cam2"] == old["cameras"]["cam2"]
    assert m["cameras"]["cam1"]["gaps"][0] == old["cameras"]["cam1"]["gaps"][0]
    (added,) = m["appended"]
    n2 = _consistent(out, "cam1")
    assert added["frames_added"]["cam1"] == n2 - n1 > 0 and m["cameras"]["cam1"]["frames"] == n2
    assert added["status"] == "complete" and m["status"] == "complete"


def test_append_after_a_crash_asks_for_reindex(rig, tmp_path):
    _, env = rig
    out = tmp_path / "session1"
    assert vts(env, "camera", "record", "cam1", "--seconds", "1", "-o", str(out)).returncode == 0
    with open(out / "cam1.mjpeg", "ab") as f:
        f.write(b"\xff\xd8\xff\xe0 half a frame")
    p = vts(env, "camera", "record", "cam1", "--seconds", "1", "-o", str(out), "--append")
    assert p.returncode == 3 and "reindex" in p.stderr and "Traceback" not in p.stderr


@pytest.mark.parametrize(
    "fault, cause",
    [
        ({"offline": True}, "recorded nothing"),
        ({"too_many_viewers": True}, "too many viewers"),
        ({"stall_after_frames": 0, "stall_s": 30.0}, "recorded nothing"),
    ],
)
def test_record_of_a_camera_that_records_nothing_is_not_complete(rig, tmp_path, fault, cause):
    r, env = rig
    r.servers["cam2"].set_faults(**fault)
    out = tmp_path / "rec"
    p = vts(env, "camera", "record", "cam1", "cam2", "--seconds", "2", "-o", str(out))
    assert p.returncode == 4, p.stdout + p.stderr
    m = json.loads((out / "manifest.json").read_text())
    assert m["status"] == "partial" and m["cameras"]["cam2"]["frames"] == 0
    assert m["cameras"]["cam1"]["frames"] >= 25
    line = [x for x in p.stderr.splitlines() if "cam2" in x]
    assert line and cause in line[0] and "Traceback" not in p.stderr
    assert "status partial" in p.stdout and "complete" not in p.stdout


def test_record_unreachable_and_wrong_password(rig, tmp_path):
    r, env = rig
    r.servers["cam1"].stop()  # nothing listens on its port any more
    p = vts(env, "camera", "record", "cam1", "--seconds", "1", "-o", str(tmp_path / "a"))
    assert p.returncode == 4 and "status failed" in p.stdout
    assert "camera cam1: recorded nothing" in p.stderr and "connection refused" in p.stderr
    bad = dict(env, VTS_SIM_CAM2_PASSWORD="wrong")
    p = vts(bad, "camera", "record", "cam2", "--seconds", "1", "-o", str(tmp_path / "b"))
    assert p.returncode == 4 and "status failed" in p.stdout
    assert "cam2" in p.stderr and "password" in p.stderr and "Traceback" not in p.stderr


@pytest.mark.parametrize(
    "args", [["--seconds", "nan"], ["--seconds", "inf"], ["--seconds", "-1"], ["--seconds", "0"], ["--seconds", "ten"]]
)
def test_record_refuses_durations_that_are_not(rig, tmp_path, args):
    _, env = rig
    p = vts(env, "camera", "record", "cam1", *args, "-o", str(tmp_path / "r"))
    assert p.returncode == 2 and "--seconds" in p.stderr and "Traceback" not in p.stderr
    assert not (tmp_path / "r").exists()


def test_stream_refuses_a_negative_fps_and_shows_latency(rig):
    _, env = rig
    p = vts(env, "camera", "stream", "cam1", "--fps", "-3", "--seconds", "1")
    assert p.returncode == 2 and "--fps" in p.stderr
    p = vts(env, "camera", "stream", "cam1", "--seconds", "1")
    assert p.returncode == 0
    header, *rows = [x for x in p.stdout.splitlines() if x.strip()]
    assert "latency" in header
    lat = [float(x.split()[-4]) for x in rows if x.split()[0].isdigit()]
    # the camera's clock offset (the sim's cameras are seconds off) is taken out: a few ms
    # of network and encoding delay is left, to the 10 ms of the stamps
    assert len(lat) >= 20 and all(-15 < v < 500 for v in lat)


def test_unknown_camera_and_unset_password_write_nothing(rig, tmp_path):
    _, env = rig
    p = vts(env, "camera", "record", "cam9", "--seconds", "1", "-o", str(tmp_path / "a"))
    assert p.returncode == 2 and "cam9" in p.stderr and not (tmp_path / "a").exists()
    e = dict(env)
    del e["VTS_SIM_CAM1_PASSWORD"]
    p = vts(e, "camera", "record", "cam1", "--seconds", "1", "-o", str(tmp_path / "b"))
    assert p.returncode == 2 and "VTS_SIM_CAM1_PASSWORD" in p.stderr and not (tmp_path / "b").exists()


# -- disk full ----------------------------------------------------------------------------------
def test_disk_full_during_record_keeps_every_whole_frame(rig, tmp_path, small_disk):
    _, env = rig
    disk = small_disk(1536)
    out = disk.path / "rec"
    p = vts(env, "camera", "record", "cam1", "cam2", "--seconds", "20", "-o", str(out))
    assert p.returncode == 3, p.stdout + p.stderr
    assert "no space left on device" in p.stderr and "whole frame(s)" in p.stderr
    m = json.loads((out / "manifest.json").read_text())
    assert m["status"] == "partial" and any("no space left" in x for x in m["problems"])
    for cam in ("cam1", "cam2"):
        n = _consistent(out, cam)
        assert n == m["cameras"][cam]["frames"] > 5
    left = set(disk.files())
    assert not [f for f in left if f.endswith(".tmp") or "reserve" in f]
    assert all(size > 0 for size in disk.files().values())
    # and the recording is as good as any: reindex finds every frame
    p = vts(env, "recording", "reindex", str(out))
    assert p.returncode == 0, p.stderr


def test_disk_full_before_the_first_frame_leaves_nothing(rig, small_disk):
    _, env = rig
    disk = small_disk(256)
    disk.fill(leave=0)
    p = vts(env, "camera", "record", "cam1", "--seconds", "2", "-o", str(disk.path / "rec"))
    assert p.returncode == 3 and "no space left on device" in p.stderr and "nothing was recorded" in p.stderr
    assert disk.files() == {}


def test_disk_full_snapshot_leaves_no_empty_jpeg(rig, small_disk):
    _, env = rig
    disk = small_disk(64)
    disk.fill(leave=0)
    out = disk.path / "a.jpg"
    p = vts(env, "camera", "snapshot", "cam1", "-o", str(out))
    assert p.returncode == 3 and str(out) in p.stderr and "no space left on device" in p.stderr
    assert not out.exists() and disk.files() == {}


# -- reindex ---------------------------------------------------------------------------------
def _recorded(one_second, folder):
    """A copy of the module's one-second recording of cam1 at ``folder``: its index."""
    shutil.copytree(one_second, folder)
    return (folder / "cam1.index.csv").read_bytes()


def test_reindex_never_makes_an_index_worse(one_second, tmp_path):
    env = dict(os.environ)  # (reindex reads the folder alone)
    out = tmp_path / "rec"
    index = _recorded(one_second, out)
    (out / "cam1.mjpeg").write_bytes(b"\0" * 5000)  # no readable frame any more
    p = vts(env, "recording", "reindex", str(out))
    assert p.returncode == 3 and "old index is kept" in p.stderr and "cam1.index.rebuilt.csv" in p.stderr
    assert (out / "cam1.index.csv").read_bytes() == index
    assert read_index(out / "cam1.index.rebuilt.csv") == []


@pytest.mark.parametrize("manifest", ["[]", '{"cameras": []}', '{"cameras": {"cam1": 3}}', "\xff\xfe"])
def test_reindex_of_a_manifest_of_the_wrong_shape(one_second, tmp_path, manifest):
    env = dict(os.environ)  # (reindex reads the folder alone)
    out = tmp_path / "rec"
    _recorded(one_second, out)
    (out / "manifest.json").write_bytes(manifest.encode("latin-1"))
    p = vts(env, "recording", "reindex", str(out))
    assert p.returncode == 3 and "Traceback" not in p.stderr
    assert "not a recording manifest" in p.stderr and "manifest.unreadable.json" in p.stderr
    assert (out / "manifest.unreadable.json").read_bytes() == manifest.encode("latin-1")
    m = json.loads((out / "manifest.json").read_text())
    assert m["status"] == "recovered" and m["cameras"]["cam1"]["frames"] == _consistent(out, "cam1")
    assert vts(env, "recording", "info", str(out)).returncode == 0


def test_disk_full_during_reindex_changes_nothing(one_second, small_disk):
    env = dict(os.environ)  # (reindex reads the folder alone)
    disk = small_disk(1024)
    out = disk.path / "rec"
    _recorded(one_second, out)
    (out / "cam1.index.csv").write_text("frame,offset,length,camera_time,host_time\n")  # lost by a crash
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    disk.fill(leave=0)
    p = vts(env, "recording", "reindex", str(out))
    assert p.returncode == 3 and "cam1.index.csv" in p.stderr and "no space left on device" in p.stderr
    assert {q.name: q.read_bytes() for q in out.iterdir()} == before


def test_reindex_replaces_a_damaged_index_and_keeps_it_beside(one_second, tmp_path):
    env = dict(os.environ)  # (reindex reads the folder alone)
    out = tmp_path / "rec"
    index = _recorded(one_second, out)
    lines = index.decode().splitlines()
    lines[5] = "garbage,in,the,middle"  # a bad line before the last
    damaged = ("\n".join(lines) + "\n").encode()
    (out / "cam1.index.csv").write_bytes(damaged)
    p = vts(env, "recording", "reindex", str(out))
    assert p.returncode == 3 and "cam1.index.damaged.csv" in p.stderr and "Traceback" not in p.stderr
    assert (out / "cam1.index.damaged.csv").read_bytes() == damaged
    rows = read_index(out / "cam1.index.csv")
    assert len(rows) == _consistent(out, "cam1") == len(lines) - 1
    # the host times of every whole row were kept: only the frame of the bad line lost its own
    assert sum(r.host_time is None for r in rows) == 1
