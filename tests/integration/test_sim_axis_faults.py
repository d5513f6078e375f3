"""The simulated Axis camera's faults over real HTTP on loopback (dropped, stalled and torn
streams, viewers refused, auth refused, wrong lengths, closed connections), its control
endpoint, and the real frame source (SimCameraSource) behind it. Clients and the fake source:
tests/sim_axis_kit.py."""

from __future__ import annotations

import http.client
import time

import cv2
import numpy as np
import pytest
import requests

from sim_axis_kit import (  # noqa: F401  (fixtures: cam and the source it serves)
    PART_RE,
    PASSWORD,
    auth_header,
    cam,
    get,
    raw_request,
    read_all,
    read_head,
    source,
    stream,
    walk_parts,
)
from vts_hw.recording.axis_jpeg import inspect_jpeg
from vts_hw.sim_devices.axis_camera import SimAxisCamera
from vts_hw.sim_devices.faults import Faults


# ----------------------------------------------------------------------------------------
# Control endpoint
# ----------------------------------------------------------------------------------------
def test_control_endpoint_faults_and_state(cam):
    assert requests.get(cam.url + "/sim/faults").json() == Faults().to_dict()
    r = requests.post(cam.url + "/sim/faults", json={"drop_after_frames": 3, "torn_mode": "cut"})
    assert r.status_code == 200 and r.json()["drop_after_frames"] == 3
    assert cam.faults.drop_after_frames == 3 and cam.faults.torn_mode == "cut"
    bad = requests.post(cam.url + "/sim/faults", json={"no_such_fault": 1})
    assert bad.status_code == 400 and "no_such_fault" in bad.json()["error"]
    assert requests.post(cam.url + "/sim/faults", json={"stall_s": "long"}).status_code == 400
    assert cam.faults.drop_after_frames == 3  # a refused change changes nothing
    r = requests.post(cam.url + "/sim/faults?reset=1", json={"reject_auth": True})
    assert r.json()["drop_after_frames"] is None and r.json()["reject_auth"] is True
    get(cam, "/axis-cgi/jpg/image.cgi")  # refused: reject_auth
    cam.faults.reset()
    get(cam, "/axis-cgi/jpg/image.cgi")
    sock, reader = raw_request(cam, "/axis-cgi/mjpg/video.cgi")
    with sock:
        read_head(reader)
        got = b""
        while got.count(b"\xff\xd9") < 2:  # two whole frames received (JPEG end markers)
            chunk = reader.read1(65536)
            assert chunk, "the stream ended before two frames"
            got += chunk
        state = requests.get(cam.url + "/sim/state").json()
    assert state["name"] == "cam0" and state["led_on"] is False
    assert abs(state["camera_time"] - (time.time() + 3.25)) < 0.5
    assert state["active_streams"] == 1 and state["connections"] >= 2
    assert state["frames_served"] >= 2 and state["snapshots_served"] == 1


# ----------------------------------------------------------------------------------------
# Faults
# ----------------------------------------------------------------------------------------
def test_fault_drop_after_frames(cam):
    cam.set_faults(drop_after_frames=3)
    _, _, body = stream(cam, "?nbrofframes=50")
    assert len(walk_parts(body)) == 3


def test_fault_drop_reaches_a_running_stream(cam):
    sock, reader = raw_request(cam, "/axis-cgi/mjpg/video.cgi")
    with sock:
        read_head(reader)
        first = reader.read1(65536)
        requests.post(cam.url + "/sim/faults", json={"drop_after_frames": 0})
        rest = read_all(reader, limit_s=2)
    assert len(PART_RE.findall(first + rest)) < 10


def test_fault_stall_keeps_the_connection_open(cam):
    cam.set_faults(stall_after_frames=2, stall_s=1.0)
    sock, reader = raw_request(cam, "/axis-cgi/mjpg/video.cgi?nbrofframes=4")
    with sock:
        read_head(reader)
        data, arrivals = b"", []
        while chunk := reader.read1(65536):
            data += chunk
            arrivals.append((time.monotonic(), len(PART_RE.findall(data))))
    parts = walk_parts(data)
    assert len(parts) == 4
    t2 = min(t for t, n in arrivals if n >= 2)
    t3 = min(t for t, n in arrivals if n >= 3)
    assert t3 - t2 >= 0.9  # nothing came during the stall (a lower bound)
    stamps = [inspect_jpeg(j).timestamp for _, j in parts]
    assert 0.9 <= stamps[2] - stamps[1] <= 1.2  # and the frames of the stall are lost, as a camera's


def test_fault_too_many_viewers(cam):
    cam.faults.too_many_viewers = True
    for path in ("/axis-cgi/mjpg/video.cgi", "/axis-cgi/jpg/image.cgi"):
        r = get(cam, path)
        assert r.status_code == 503 and "Too many viewers" in r.text
    assert get(cam, "/axis-cgi/param.cgi?action=list&group=Brand.Brand").status_code == 200
    cam.faults.too_many_viewers = False
    assert get(cam, "/axis-cgi/jpg/image.cgi").status_code == 200


def test_fault_max_viewers(cam):
    cam.set_faults(max_viewers=1)
    sock, reader = raw_request(cam, "/axis-cgi/mjpg/video.cgi")
    with sock:
        read_head(reader)
        reader.read1(1000)
        assert get(cam, "/axis-cgi/mjpg/video.cgi?nbrofframes=1").status_code == 503
    deadline = time.monotonic() + 3
    while cam.counter("active_streams") and time.monotonic() < deadline:
        time.sleep(0.05)
    assert get(cam, "/axis-cgi/mjpg/video.cgi?nbrofframes=1").status_code == 200


def test_fault_reject_auth(cam):
    cam.faults.reject_auth = True
    r = get(cam, "/axis-cgi/jpg/image.cgi")
    assert r.status_code == 401 and r.headers["WWW-Authenticate"].startswith("Digest ")
    cam.faults.reject_auth = False
    assert get(cam, "/axis-cgi/jpg/image.cgi").status_code == 200


def test_fault_torn_jpeg_in_a_stream(cam):
    cam.set_faults(torn_jpeg_at=2)
    _, _, body = stream(cam, "?nbrofframes=4")
    parts = walk_parts(body)  # "short": Content-Length states the short length
    assert len(parts) == 4
    assert [inspect_jpeg(j).complete for _, j in parts] == [True, True, False, True]
    assert parts[2][0] < 0.6 * parts[1][0]


def test_fault_torn_jpeg_cut_kills_the_connection_mid_frame(cam):
    cam.set_faults(torn_jpeg_at=1, torn_mode="cut")
    _, _, body = stream(cam, "?nbrofframes=4")
    heads = list(PART_RE.finditer(body))
    assert len(heads) == 2
    stated, received = int(heads[1].group(1)), len(body) - heads[1].end()
    assert 0.4 * stated <= received <= 0.6 * stated


def test_fault_torn_snapshot(cam):
    cam.set_faults(torn_jpeg_at=0)
    r = get(cam, "/axis-cgi/jpg/image.cgi")
    assert r.status_code == 200 and int(r.headers["Content-Length"]) == len(r.content)
    assert not inspect_jpeg(r.content).complete
    assert inspect_jpeg(get(cam, "/axis-cgi/jpg/image.cgi").content).complete  # only that one
    cam.set_faults(torn_jpeg_at=0, torn_mode="cut")
    conn = http.client.HTTPConnection("127.0.0.1", cam.port, timeout=5)
    path = "/axis-cgi/jpg/image.cgi"
    conn.request("GET", path, headers={"Authorization": auth_header(cam, path)})
    with pytest.raises(http.client.IncompleteRead):
        conn.getresponse().read()
    conn.close()


def test_fault_wrong_content_length_swallows_the_next_boundary(cam):
    cam.set_faults(wrong_content_length_at=1)
    _, _, body = stream(cam, "?nbrofframes=3")
    heads = list(PART_RE.finditer(body))
    assert len(heads) == 3
    actual = heads[2].start() - 2 - heads[1].end()  # up to the CRLF before the next boundary
    assert int(heads[1].group(1)) == actual + 100
    naive_end = heads[1].end() + int(heads[1].group(1))
    assert naive_end > heads[2].start()  # a naive reader eats the next part's boundary
    assert int(heads[0].group(1)) == heads[1].start() - 2 - heads[0].end()  # the others are right


def test_fault_missing_content_length(cam):
    cam.set_faults(missing_content_length=True)
    _, _, body = stream(cam, "?nbrofframes=3")
    assert b"Content-Length" not in body.split(b"\xff\xd8", 1)[0]
    chunks = body.split(b"--myboundary\r\nContent-Type: image/jpeg\r\n\r\n")
    assert chunks[0] == b"" and len(chunks) == 4
    assert all(c.endswith(b"\r\n") and inspect_jpeg(c[:-2]).complete for c in chunks[1:])


def test_fault_close_after_response(cam):
    path = "/axis-cgi/param.cgi?action=list&group=Brand.Brand"
    conn = http.client.HTTPConnection("127.0.0.1", cam.port, timeout=5)
    for _ in range(2):  # healthy: keep-alive, two requests on one connection
        conn.request("GET", path, headers={"Authorization": auth_header(cam, path)})
        r = conn.getresponse()
        assert r.read() == b"root.Brand.Brand=AXIS\r\n" and not r.will_close
    sock_before = conn.sock
    conn.close()
    assert sock_before is not None
    cam.faults.close_after_response = True
    sock, reader = raw_request(cam, path)
    with sock:
        status, headers = read_head(reader)
        assert status == b"HTTP/1.0 200 OK\r\n" and headers["connection"] == "close"
        assert reader.read(int(headers["content-length"])) == b"root.Brand.Brand=AXIS\r\n"
        assert reader.read1(10) == b""  # the camera closed the connection
    r = requests.get(cam.url + path)  # the 401 is closed too
    assert r.status_code == 401 and r.headers["Connection"] == "close"


# ----------------------------------------------------------------------------------------
# With the real frame source
# ----------------------------------------------------------------------------------------
@pytest.fixture
def real_cam():
    from vts_hw.sim_devices.camera_source import SimCameraSource
    from vts_hw.sim_devices.clock import RealClock
    from vts_hw.sim_devices.render import Renderer
    from vts_hw.sim_devices.scene import Scene

    scene = Scene.reference()
    clock = RealClock()
    src = SimCameraSource(scene, Renderer(scene), next(iter(scene.cameras)), clock)
    with SimAxisCamera(src, password=PASSWORD, clock=clock) as camera:
        yield camera


def test_real_source_snapshot_stamp_and_stream(real_cam):
    src = real_cam.source
    before = src.camera_time()
    r = get(real_cam, "/axis-cgi/jpg/image.cgi?resolution=640x480")
    after = src.camera_time()
    info = inspect_jpeg(r.content)
    assert (info.width, info.height) == (640, 480) and info.problems == ()
    assert before - 0.05 <= info.timestamp <= after + 0.05
    _, _, body = stream(real_cam, "?nbrofframes=3")
    assert len(walk_parts(body)) == 3
    cap = cv2.VideoCapture(
        f"http://root:{PASSWORD.replace(' ', '%20')}@127.0.0.1:{real_cam.port}/axis-cgi/mjpg/video.cgi", cv2.CAP_FFMPEG
    )
    try:
        ok, img = cap.read()
    finally:
        cap.release()
    assert ok and img.shape[:2] == (480, 640)


def test_real_source_led_lights_the_markers(real_cam):
    """port.cgi switches the scene's LED: the wall markers (where the scene's ground truth
    puts them) are bright in the next frame with the LED on, and gone with it off."""
    src = real_cam.source

    def marker_levels():
        img = cv2.imdecode(np.frombuffer(get(real_cam, "/axis-cgi/jpg/image.cgi").content, np.uint8), 0)
        truth = src.scene.truth(src.name, src.clock.now())
        assert len(truth) >= 4
        return np.array([img[int(round(v)), int(round(u))] for _, u, v in truth]), np.median(img)

    get(real_cam, "/axis-cgi/io/port.cgi?action=1%3A%2F")
    assert src.led_on()
    lit, background = marker_levels()
    get(real_cam, "/axis-cgi/io/port.cgi?action=1%3A%5C")
    assert not src.led_on()
    dark, _ = marker_levels()
    assert lit.min() > background + 80, (lit, background)
    assert dark.max() < background + 30, (dark, background)
    get(real_cam, "/axis-cgi/io/port.cgi?action=1%3A%2F300%5C")  # a 300 ms pulse
    pulsed, _ = marker_levels()
    time.sleep(0.4)
    after, _ = marker_levels()
    assert pulsed.min() > background + 80 and after.max() < background + 30
