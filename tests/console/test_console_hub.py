"""The console's frames hub against the simulated Axis cameras over HTTP (issue 23 §2).

One stream per camera at most, opened only while watched and closed when nobody watches; a
recording in the same process feeds the hub the frames it already receives, and the camera
never sees a second viewer (its ``max_viewers`` fault would refuse one with 503); the markers
the worker finds are where the scene's markers are.
"""

from __future__ import annotations

import tempfile
import time

import numpy as np
import pytest

from console_live import until
from vts_hw.console.hub import FramesHub
from vts_hw.console.markers import MarkerWorker
from vts_hw.drivers.registry import open_camera
from vts_hw.recording.capture import FrameRecorder
from vts_hw.sim_devices.rig import SimRig

pytestmark = pytest.mark.timeout(120)


@pytest.fixture(scope="module")
def rig():
    with SimRig(n_cameras=2, seed=3) as r, r.env():
        yield r


@pytest.fixture()
def cameras(rig):
    cfg = rig.config()
    cams = {c.name: open_camera(c) for c in cfg.cameras}
    yield cams
    for c in cams.values():
        c.close()
    for srv in rig.servers.values():
        srv.faults.reset()


def streams(rig, name):
    return rig.servers[name].state()["active_streams"]


def test_a_stream_only_while_watched_and_one_for_many_viewers(rig, cameras):
    hub = FramesHub(cameras, idle_close_s=0.5)
    try:
        time.sleep(0.5)
        assert streams(rig, "cam1") == 0 and hub.status("cam1")["doing"] == "idle"
        hub.watch("cam1")
        hub.watch("cam1")  # a second page: the same stream
        assert until(lambda: (hub.latest("cam1") or 0) and hub.latest("cam1").seq >= 5)
        assert streams(rig, "cam1") == 1 and streams(rig, "cam2") == 0
        assert hub.status("cam1")["doing"] == "streaming" and hub.status("cam1")["viewers"] == 2
        hub.unwatch("cam1")
        time.sleep(1.0)
        assert streams(rig, "cam1") == 1  # one viewer left
        hub.unwatch("cam1")
        assert until(lambda: streams(rig, "cam1") == 0, 10)
        assert until(lambda: hub.status("cam1")["doing"] == "idle", 5)
    finally:
        hub.close()
    assert streams(rig, "cam2") == 0


def test_a_recording_feeds_the_hub_and_the_camera_never_sees_a_second_viewer(rig, cameras):
    """The camera takes one viewer only (max_viewers=1): the hub's stream is closed before the
    recording opens its own, the recording's frames reach the page through feed(), and the
    recording gets every frame (a second viewer would have been refused with 503)."""
    rig.servers["cam1"].set_faults(max_viewers=1)
    hub = FramesHub(cameras, idle_close_s=0.5)
    seen = []
    try:
        hub.watch("cam1")
        assert until(lambda: hub.latest("cam1") is not None)
        hub.attach(["cam1"])  # what the Scan page will do before its recording starts
        assert until(lambda: streams(rig, "cam1") == 0, 5)
        before = hub.counts("cam1")["received"]
        with tempfile.TemporaryDirectory() as folder:
            rec_cam = open_camera(rig.config().cameras[0])
            rec = FrameRecorder([rec_cam], folder + "/r", seconds=None, on_frame=hub.feed)
            rec.start()
            try:
                for _ in range(40):
                    seen.append(streams(rig, "cam1"))
                    time.sleep(0.05)
                assert until(lambda: (hub.latest("cam1") or 0) and hub.latest("cam1").seq >= 10)
                st = hub.status("cam1")
                assert st["doing"] == "recording" and st["source"] == "fed"
            finally:
                rec.stop()
                rec.wait()
                rec_cam.close()
            prog = rec.progress["cam1"]
            assert prog.frames >= 10 and prog.error == "" and prog.reconnects == 0
            # every frame the recording wrote reached the hub's slot, and nothing else did
            assert hub.counts("cam1")["received"] - before == prog.frames
        assert max(seen) == 1  # the recording's stream alone, all along
        assert until(lambda: streams(rig, "cam1") == 0, 5)
        hub.detach(["cam1"])  # the recording ended: the hub's own stream again
        assert until(lambda: streams(rig, "cam1") == 1, 10)
        assert until(lambda: hub.status("cam1")["doing"] == "streaming", 10)
    finally:
        hub.close()


def test_a_camera_that_stops_answering_is_said_so(rig, cameras):
    hub = FramesHub(cameras, idle_close_s=0.5)
    try:
        hub.watch("cam2")
        assert until(lambda: hub.latest("cam2") is not None)
        rig.servers["cam2"].faults.offline = True
        st = until(lambda: (s := hub.status("cam2"))["doing"] == "not answering" and s, 20)
        assert st and st["age"] > st["fresh_within"]
        rig.servers["cam2"].faults.offline = False
        assert until(lambda: hub.status("cam2")["doing"] == "streaming", 20)
    finally:
        hub.close()


def test_the_markers_found_are_the_scene_markers(rig, cameras):
    rig.scene.set_led("cam1", True)
    hub = FramesHub(cameras, idle_close_s=0.5)
    worker = MarkerWorker(hub, rate_hz=5)
    try:
        hub.watch("cam1")
        found = until(lambda: (f := worker.found("cam1")) and f.markers and f, 20)
        assert found and not found.problem
        t = hub.latest("cam1").frame.camera_time
        _, _, uv, visible = rig.scene.project_markers("cam1", rig.clock.now())
        truth = uv[visible]
        got = np.array([[m["x"], m["y"]] for m in found.markers])
        assert len(got) == len(truth) >= 4 and t is not None
        dist = np.linalg.norm(got[:, None, :] - truth[None, :, :], axis=2).min(axis=1)
        assert dist.max() < 1.0, dist
    finally:
        worker.close()
        hub.close()
        rig.scene.set_led("cam1", False)
