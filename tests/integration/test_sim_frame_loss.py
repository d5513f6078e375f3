"""Frame loss as declared faults of the simulated camera, seen by our driver over HTTP: random
frames lost (seeded: the same frames every run), bursts of N frames every M seconds (every
camera given the burst at the same moments), a camera offline for a stretch then back, a clock
that jumps, and a stream that falls behind: sent late by default, skipped with
``skip_when_late_s`` as a real camera's would be."""

from __future__ import annotations

import threading

import requests

from sim_axis_kit import PASSWORD, FakeSource
from stream_items import collect
from vts_hw.config import parse_rig
from vts_hw.drivers.axis_stream import FrameStream
from vts_hw.drivers.registry import open_camera, open_cameras
from vts_hw.sim_devices.axis_camera import SimAxisCamera

PERIOD = 1.0 / 25


def _grid(rig, cam: str, frame) -> int:
    """The sensor-grid index of a frame, from its stamp (truncated to 10 ms) and the true clock."""
    return round((rig.scene.clocks[cam].host_time(frame.camera_time) + 0.005) / PERIOD)


def test_random_loss_is_seeded_and_exactly_the_frames_the_client_misses(sim_rig, cam1):
    server = sim_rig.servers["cam1"]
    server.set_faults(lose_p=0.25, lose_seed=7)
    frames, gaps = collect(FrameStream(cam1, nbrofframes=60))
    assert len(frames) == 60
    got = [_grid(sim_rig, "cam1", f) for f in frames]
    span = range(got[0], got[-1] + 1)
    lost = {g for g in span if server.faults.lost("cam1", g, g * PERIOD, PERIOD)}
    assert set(got) == set(span) - lost  # the frames not sent are exactly those drawn
    assert 5 <= len(lost) <= 40
    assert sum(g.missing for g in gaps) == len(lost)  # and the client counts every one of them
    assert all(g.reason == "camera skipped frames" for g in gaps)
    assert server.state()["frames_lost"] >= len(lost)
    # the draw depends on the seed, the camera and the grid only: another camera loses others
    other = {g for g in span if server.faults.lost("cam2", g, g * PERIOD, PERIOD)}
    assert other != lost


def test_bursts_hit_both_cameras_at_the_same_moments(sim_rig, cam1):
    for server in sim_rig.servers.values():
        server.set_faults(lose_burst_frames=5, lose_burst_every_s=1.0)
    with open_camera(sim_rig.config().camera("cam2")) as cam2:
        results = {}
        threads = [
            threading.Thread(target=lambda c=c: results.__setitem__(c.name, collect(FrameStream(c, duration=3.2))))
            for c in (cam1, cam2)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    seen = {}
    for name, (_frames, gaps) in results.items():
        assert len(gaps) >= 2 and all(g.missing == 5 for g in gaps), (name, [g.missing for g in gaps])
        # each gap: the first 5 frames of a second of the clock
        starts = [round(sim_rig.scene.clocks[name].host_time(g.camera_t1) + 0.005 - 5 * PERIOD, 2) for g in gaps]
        assert all(abs(s - round(s)) < 0.011 for s in starts), starts
        seen[name] = {round(s) for s in starts}
    assert seen["cam1"] & seen["cam2"]  # the same seconds in both cameras


def test_a_camera_offline_for_a_stretch_comes_back(sim_rig, cam1):
    server = sim_rig.servers["cam1"]
    now = sim_rig.clock.now()
    server.set_faults(offline_from=now + 0.8, offline_until=now + 2.0)
    stream = FrameStream(cam1, duration=3.5, max_backoff=0.25)
    frames, gaps = collect(stream)
    hosts = [sim_rig.scene.clocks["cam1"].host_time(f.camera_time) for f in frames]
    assert not [h for h in hosts if now + 0.85 < h < now + 1.95]  # nothing from the stretch
    assert any(h < now + 0.8 for h in hosts) and any(h > now + 2.0 for h in hosts)  # before and back
    assert stream.stats.reconnects >= 1
    big = max(gaps, key=lambda g: g.missing)
    assert big.seconds >= 1.1 and "reconnect" in big.reason
    assert server.faults.offline_at(now + 1.0) and not server.faults.offline_at(now + 2.5)
    assert requests.get(server.url + "/sim/state", timeout=5).json()["faults"]["offline_until"] == now + 2.0


def test_a_clock_that_jumps_moves_the_stamps_and_the_time_cgi(sim_rig, cam1):
    server = sim_rig.servers["cam1"]
    before = cam1.clock_offset(3).offset_s
    now = sim_rig.clock.now()
    server.set_faults(clock_jump_s=2.5, clock_jump_at=now + 0.6, clock_jump_every_s=0.8)
    frames, _ = collect(FrameStream(cam1, duration=1.6))
    steps = [b.camera_time - a.camera_time for a, b in zip(frames, frames[1:])]
    jumps = [d for d in steps if d > 1.0]
    assert len(jumps) == 2 and all(abs(d - 2.5 - PERIOD) < 0.02 for d in jumps)  # two steps of 2.5 s
    assert all(abs(d - PERIOD) < 0.02 for d in steps if d <= 1.0)
    server.set_faults(clock_jump_every_s=None)  # one jump only, long done: 2.5 s ahead
    assert abs(cam1.clock_offset(3).offset_s - before - 2.5) < 0.05


def test_the_loss_faults_over_sim_faults(sim_rig):
    server = sim_rig.servers["cam2"]
    r = requests.post(
        server.url + "/sim/faults",
        json={"lose_p": 0.1, "lose_burst_frames": 3, "lose_burst_every_s": 2.0, "skip_when_late_s": 1.0},
        timeout=5,
    )
    assert r.status_code == 200 and r.json()["lose_p"] == 0.1 and server.faults.lose_burst_frames == 3
    for bad, word in (
        ({"lose_p": 2}, "probability"),
        ({"clock_jump_every_s": 0}, "> 0"),
        ({"offline_from": "soon"}, "time"),
    ):
        r = requests.post(server.url + "/sim/faults", json=bad, timeout=5)
        assert r.status_code == 400 and word in r.json()["error"], r.text
    assert server.faults.lose_p == 0.1  # a refused change changes nothing
    assert set(server.state()["faults"]) == {"lose_p", "lose_burst_frames", "lose_burst_every_s", "skip_when_late_s"}


def _slow_camera(**faults):
    """A camera whose frames take 60 ms to make at 25 fps: its stream falls behind."""
    cam = SimAxisCamera(FakeSource(render_s=0.06), password=PASSWORD).start()
    cam.set_faults(**faults)
    return cam


def _stream_parts(cam, seconds: float):
    cfg = parse_rig(
        {
            "rig": "t",
            "cameras": [
                {
                    "name": "cam0",
                    "host": "127.0.0.1",
                    "port": cam.port,
                    "user": "root",
                    "password_env": "VTS_TEST_CAM0_PASSWORD",
                }
            ],
        },
        "test",
    )
    with open_camera(cfg.camera("cam0")) as client:
        return collect(FrameStream(client, duration=seconds))


def test_a_stream_that_falls_behind_sends_late_and_skips_only_as_a_declared_fault(monkeypatch):
    monkeypatch.setenv("VTS_TEST_CAM0_PASSWORD", PASSWORD)
    cam = _slow_camera()
    try:
        frames, gaps = _stream_parts(cam, 4.0)
        state = cam.state()
    finally:
        cam.stop()
    assert gaps == [] and len(frames) >= 50  # every frame, none skipped ...
    assert all(abs(b.camera_time - a.camera_time - PERIOD) < 0.011 for a, b in zip(frames, frames[1:]))
    assert state["frames_late"] > 25 and state["frames_skipped"] == 0  # ... sent late,
    late = [f.host_time - (f.camera_time - 3.25) for f in frames]  # (FakeSource's clock: host + 3.25 s)
    assert max(late) > 1.2  # more than a second late, each stamped with its capture time
    cam = _slow_camera(skip_when_late_s=0.2)  # a real camera cannot keep up: it skips
    try:
        frames, gaps = _stream_parts(cam, 1.5)
        state = cam.state()
    finally:
        cam.stop()
    assert gaps and sum(g.missing for g in gaps) >= 5 and state["frames_skipped"] >= 5
    assert all(g.reason == "camera skipped frames" for g in gaps)


def test_a_recording_of_lossy_cameras_states_every_lost_frame(sim_rig, tmp_path):
    """Both cameras lose a burst of 4 frames every second, cam2 also 10 % at random: the
    recording holds every frame sent, the manifest's gaps are the frames lost, no more."""
    from vts_hw.recording.capture import FrameRecorder
    from vts_hw.recording.promised import info

    for name, server in sim_rig.servers.items():
        server.set_faults(lose_burst_frames=4, lose_burst_every_s=1.0, lose_p=0.1 if name == "cam2" else 0.0)
    rec = FrameRecorder(open_cameras(sim_rig.config().cameras), tmp_path, seconds=3.0)
    rec.start()
    rec.wait()
    manifest = rec.finish()
    assert manifest["status"] == "complete"  # skipped frames are counted, not a lost stream
    for s in info(tmp_path):
        cam = manifest["cameras"][s.source]
        faults = sim_rig.servers[s.source].faults
        times = [sim_rig.scene.clocks[s.source].host_time(t) for t in (s.first_time, s.last_time)]
        span = range(round((times[0] + 0.005) / PERIOD), round((times[1] + 0.005) / PERIOD) + 1)
        lost = [g for g in span if faults.lost(s.source, g, g * PERIOD, PERIOD)]
        assert s.frames + len(lost) == len(span), s.source
        assert cam["dropped_frames"] == len(lost) == sum(g["missing"] for g in s.gaps) >= 8
