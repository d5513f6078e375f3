"""Streams from the simulated camera: pacing, sequence, and every injected fault survived."""

import threading

import pytest

from stream_items import collect
from vts_hw.drivers.axis import AxisError, CameraUnauthorized, Frame
from vts_hw.drivers.axis_stream import FrameStream


def test_stream_frames_are_consecutive_and_paced(cam1):
    frames, gaps = collect(FrameStream(cam1, nbrofframes=30))
    assert len(frames) == 30 and gaps == []
    assert [f.seq for f in frames] == list(range(30))
    dts = [b.camera_time - a.camera_time for a, b in zip(frames, frames[1:])]
    assert all(0.03 <= d <= 0.05 for d in dts)
    assert all(f.host_time >= frames[0].host_time for f in frames)


def test_duration_ends_the_stream(cam1):
    s = FrameStream(cam1, duration=1.0)
    frames, _ = collect(s)
    assert not s.stop_event.is_set()  # it ended by itself, not by the test's limit
    assert 15 <= len(frames) <= 30
    assert frames[-1].camera_time - frames[0].camera_time <= 1.0


def test_dropped_connection_reconnects_and_reports_the_gap(sim_rig, cam1):
    sim_rig.servers["cam1"].faults.drop_after_frames = 10
    s = FrameStream(cam1, nbrofframes=25)
    frames, gaps = collect(s)
    assert len(frames) == 25
    assert s.stats.reconnects >= 1
    assert gaps and all(g.missing >= 1 for g in gaps)
    assert "reconnect" in gaps[0].reason
    # camera times strictly increase across the reconnect: nothing recorded twice, nothing lost silently
    times = [f.camera_time for f in frames]
    assert times == sorted(times) and len(set(times)) == len(times)
    missing = sum(g.missing for g in gaps)
    span = round((times[-1] - times[0]) / 0.04) + 1
    assert span == len(frames) + missing


def test_stall_reconnects(sim_rig, cam1):
    sim_rig.servers["cam1"].faults.stall_after_frames = 5
    sim_rig.servers["cam1"].faults.stall_s = 30.0
    s = FrameStream(cam1, nbrofframes=12, stall_timeout=1.0)
    frames, gaps = collect(s, limit_s=60)
    assert len(frames) == 12 and not s.stop_event.is_set()
    gap = next(g for g in gaps if "stall" in g.reason)
    assert gap.seconds < 30  # reconnected, rather than waited out the 30 s stall


def test_torn_jpeg_is_counted_not_yielded(sim_rig, cam1):
    sim_rig.servers["cam1"].faults.torn_jpeg_at = 4
    s = FrameStream(cam1, nbrofframes=10)
    frames, gaps = collect(s)
    assert len(frames) == 10 and all(f.complete for f in frames)
    assert s.stats.torn == 1
    assert sum(g.missing for g in gaps) >= 1


@pytest.mark.parametrize("fault", ["wrong_content_length_at", "missing_content_length"])
def test_framing_faults_lose_no_frame(sim_rig, cam1, fault):
    setattr(sim_rig.servers["cam1"].faults, fault, 3 if fault.endswith("_at") else True)
    s = FrameStream(cam1, nbrofframes=10)
    frames, gaps = collect(s)
    assert len(frames) == 10 and s.stats.torn == 0 and gaps == []
    assert all(isinstance(f, Frame) and f.camera_time for f in frames)


def test_503_then_recovery(sim_rig, cam1):
    faults = sim_rig.servers["cam1"].faults
    faults.too_many_viewers = True
    timer = threading.Timer(1.0, lambda: setattr(faults, "too_many_viewers", False))
    timer.start()
    s = FrameStream(cam1, nbrofframes=5)
    frames, _ = collect(s)
    assert len(frames) == 5 and s.stats.reconnects >= 1
    assert "too many viewers" in s.stats.last_error


def test_wrong_password_stops_the_stream_at_once(sim_rig, cam1):
    sim_rig.servers["cam1"].faults.reject_auth = True
    with pytest.raises(CameraUnauthorized):
        collect(FrameStream(cam1, nbrofframes=5))


def test_give_up_after(sim_rig, cam1):
    sim_rig.servers["cam1"].faults.too_many_viewers = True
    with pytest.raises(AxisError, match="giving up"):
        collect(FrameStream(cam1, nbrofframes=5, give_up_after=1.5))


def test_stop_from_another_thread_is_prompt(cam1):
    s = FrameStream(cam1)
    threading.Timer(0.5, s.stop).start()
    frames, _ = collect(s, limit_s=60)
    # an endless stream, ended by the stop: well before the test's own limit of 60 s
    assert frames and frames[-1].camera_time - frames[0].camera_time < 30
