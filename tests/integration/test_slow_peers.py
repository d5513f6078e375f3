"""Peers that answer too slowly to be waited for, and camera answers that are not what they
seem (issue 21, second round): every network operation has a deadline for the whole of it,
not only for each read, and ends in one sentence naming the device (exit 4); a stream that
delivered nothing, or a snapshot that is half a JPEG, is never an OK.

The simulated rig runs in this process (its faults switched directly); `vts` runs as a
subprocess with the rig.yaml the rig writes. The subprocess timeouts are hang detectors only.
"""

import json
import os
import subprocess
import sys
import time

import pytest

from vts_hw.sim_devices.rig import SimRig

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def vts(env, *args, timeout=45):
    t0 = time.monotonic()
    p = subprocess.run([*VTS, *args], capture_output=True, text=True, env=env, timeout=timeout)
    p.seconds = time.monotonic() - t0
    return p


@pytest.fixture()
def rig(tmp_path):
    with SimRig(n_cameras=1, seed=5) as r:
        cfg_dir = tmp_path / "sim"
        r.write(cfg_dir)
        env = dict(os.environ, **r.env_vars(), VTS_CONFIG=str(cfg_dir / "rig.yaml"))
        yield r, env


def _one_sentence_about_cam1(p):
    assert "Traceback" not in p.stderr, p.stderr
    last = p.stderr.strip().splitlines()[-1]
    assert last.startswith("vts: ") and "cam1" in last, p.stderr
    return last


@pytest.mark.parametrize(
    "args",
    [
        ["camera", "snapshot", "cam1", "-o", "{tmp}/s.jpg"],
        ["camera", "info", "cam1"],
        ["camera", "stream", "cam1", "--seconds", "3"],
    ],
)
def test_a_trickling_camera_ends_at_the_deadline(rig, tmp_path, args):
    """A 200 and its headers at once, then a byte a second: each read returns, so only a
    deadline on the whole answer ends it."""
    r, env = rig
    r.servers["cam1"].set_faults(trickle=True, trickle_s=0.5)
    p = vts(env, *[a.format(tmp=tmp_path) for a in args])
    assert p.returncode == 4, p.stdout + p.stderr
    last = _one_sentence_about_cam1(p)
    assert "within" in last or "no whole frame" in last or "no frames" in last, last
    assert not (tmp_path / "s.jpg").exists()


def test_a_trickling_camera_ends_a_recording_on_time(rig, tmp_path):
    r, env = rig
    r.servers["cam1"].set_faults(trickle=True, trickle_s=0.5)
    out = tmp_path / "rec"
    p = vts(env, "camera", "record", "cam1", "--seconds", "3", "-o", str(out))
    assert p.returncode == 4, p.stdout + p.stderr
    assert "status failed" in p.stdout and "cam1" in p.stderr and "Traceback" not in p.stderr
    m = json.loads((out / "manifest.json").read_text())
    assert m["status"] == "failed" and m["cameras"]["cam1"]["frames"] == 0


@pytest.mark.parametrize(
    "fault, words",
    [
        ({"too_many_viewers": True}, "too many viewers"),
        ({"stall_after_frames": 0, "stall_s": 30.0}, "stall"),
        ({"drop_after_frames": 0}, "no frames"),
    ],
)
def test_a_stream_that_delivers_nothing_is_not_ok(rig, fault, words):
    r, env = rig
    r.servers["cam1"].set_faults(**fault)
    p = vts(env, "camera", "stream", "cam1", "--seconds", "3")
    assert p.returncode == 4, p.stdout + p.stderr
    last = _one_sentence_about_cam1(p)
    assert words in last, last
    assert "0 frames" in p.stderr  # the counts are still shown


def test_a_stream_that_lost_frames_on_the_way_says_so(rig):
    """Frames, then the connection dropped and came back: the frames are shown, and the exit
    says the stream was not whole (4), naming the camera and the cause."""
    r, env = rig
    r.servers["cam1"].set_faults(drop_after_frames=10)
    p = vts(env, "camera", "stream", "cam1", "--seconds", "3")
    assert p.returncode == 4, p.stdout + p.stderr
    last = _one_sentence_about_cam1(p)
    assert "reconnect" in last or "dropped" in last, last
    assert sum(1 for line in p.stdout.splitlines() if line.strip()[:1].isdigit()) >= 10


def test_a_healthy_stream_is_ok(rig):
    r, env = rig
    p = vts(env, "camera", "stream", "cam1", "--seconds", "2")
    assert p.returncode == 0, p.stderr
    assert "0 missing" in p.stderr


@pytest.mark.parametrize("mode", ["short", "cut"])
def test_a_torn_snapshot_is_never_saved(rig, tmp_path, mode):
    r, env = rig
    r.servers["cam1"].set_faults(torn_jpeg_at=0, torn_mode=mode)
    out = tmp_path / "s.jpg"
    p = vts(env, "camera", "snapshot", "cam1", "-o", str(out))
    assert p.returncode == 4, p.stdout + p.stderr
    last = _one_sentence_about_cam1(p)
    assert "JPEG" in last or "closed the connection" in last, last
    assert not out.exists() and list(tmp_path.glob("s.jpg*")) == []
    # and the next (whole) snapshot is saved, and decodes
    p = vts(env, "camera", "snapshot", "cam1", "-o", str(out))
    assert p.returncode == 0, p.stderr
    import cv2
    import numpy as np

    assert cv2.imdecode(np.frombuffer(out.read_bytes(), np.uint8), cv2.IMREAD_UNCHANGED) is not None


# -- qa daily, the function generator (VISA), PostgreSQL ---------------------------------------


def test_qa_daily_with_a_trickling_camera_ends_naming_it(tmp_path):
    """The daily QA ends on time: the trickling camera is ACTION (not reachable), with why."""
    from qa_runs import baselines_now
    from test_qa_faults import _setup
    from vts_hw.store import ResultsStore

    with SimRig(n_cameras=2, seed=5) as r, r.env():
        url = f"sqlite:///{tmp_path / 'r.sqlite'}"
        cfg, env = _setup(r, tmp_path / "a", url)
        with ResultsStore(url) as s:
            baselines_now(cfg, s)
        r.servers["cam2"].set_faults(trickle=True, trickle_s=0.5)
        p = vts(env, "qa", "daily", "--frames", "2", timeout=120)
    # a camera that cannot be read is the QA's ACTION (camera_reachable 0), its reason named
    assert p.returncode == 20, p.stdout + p.stderr
    assert "Traceback" not in p.stderr
    assert "camera cam2 at" in p.stdout and "within 5 s" in p.stdout and "cam1: OK" in p.stdout


def test_a_trickling_function_generator_ends_at_its_timeout(tmp_path):
    """The SCPI generator answers a byte every 0.3 s. pyvisa-py looks at its timeout only when a
    read brings nothing, so each reply was read whole however long it took (about 15 s for
    `*IDN?`, as long for each query after it); the driver now reads the reply against one
    deadline: `vts trigger status` ends at the generator's timeout naming it, exit 4."""
    import yaml

    from vts_hw.sim_devices.scpi_server import SimFunctionGenerator

    with SimFunctionGenerator() as fgen:
        cfg = {
            "rig": "t",
            "cameras": [{"name": "cam1", "host": "127.0.0.1"}],
            "trigger": {"backend": "visa", "address": fgen.resource},
        }
        (tmp_path / "rig.yaml").write_text(yaml.safe_dump(cfg))
        fgen.go_trickle(0.3)
        p = vts(
            dict(os.environ),
            "trigger",
            "status",
            "--config",
            str(tmp_path / "rig.yaml"),
            "--log",
            str(tmp_path / "t.csv"),
        )
    assert p.returncode == 4, p.stdout + p.stderr
    assert p.stderr.startswith("vts: fgen: ") and "did not answer" in p.stderr and "Traceback" not in p.stderr
    assert p.seconds < 30


def test_a_postgresql_that_accepts_and_says_nothing_ends_at_connect_timeout(tmp_path):
    """A listener that accepts the connection and never answers (a hung server, a firewall that
    swallows): the store is given up on within its connect timeout, one sentence naming it."""
    import socket
    import threading

    lst = socket.socket()
    lst.bind(("127.0.0.1", 0))
    lst.listen(8)
    port = lst.getsockname()[1]
    held, stop = [], threading.Event()

    def accept():
        lst.settimeout(0.2)
        while not stop.is_set():
            try:
                held.append(lst.accept()[0])
            except OSError:
                pass

    t = threading.Thread(target=accept, daemon=True)
    t.start()
    try:
        env = dict(os.environ, PGPASSWORD="x")
        env.pop("VTS_CONFIG", None)
        p = vts(env, "--store", f"postgresql://vts@127.0.0.1:{port}/vts", "store", "info", timeout=60)
    finally:
        stop.set()
        t.join()
        for c in held:
            c.close()
        lst.close()
    assert p.returncode == 3, p.stdout + p.stderr
    assert held, "the command never connected"
    last = p.stderr.strip().splitlines()[-1]
    assert "Traceback" not in p.stderr and f"127.0.0.1:{port}" in last or "127.0.0.1" in last, p.stderr
    assert p.seconds < 40
