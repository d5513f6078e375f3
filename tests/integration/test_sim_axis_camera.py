"""The simulated Axis camera over real HTTP on loopback: snapshots, digest auth, the MJPEG
stream, parameters and VAPIX paths (faults and the real frame source: tests/integration/test_sim_axis_faults.py).

Clients are independent of the server code: requests, curl, OpenCV/FFmpeg, and a raw socket
client written here (tests/sim_axis_kit.py, with its own digest computation) for byte-exact
checks. A small fake frame source stands in for ``SimCameraSource``.
"""

from __future__ import annotations

import http.client
import re
import shutil
import subprocess
import time
from datetime import UTC, datetime

import cv2
import numpy as np
import requests
from requests.auth import HTTPDigestAuth

from sim_axis_kit import (  # noqa: F401  (fixtures: cameras and the source they serve)
    AUTH,
    PASSWORD,
    FakeSource,
    auth_header,
    cam,
    cam2,
    get,
    raw_request,
    read_all,
    read_head,
    source,
    stream,
    walk_parts,
)
from vts_hw.recording.axis_jpeg import AxisProduct, inspect_jpeg
from vts_hw.sim_devices.axis_camera import SimAxisCamera
from vts_hw.sim_devices.clock import VirtualClock
from vts_hw.sim_devices.digest import parse_auth_params


# ----------------------------------------------------------------------------------------
# Snapshot, authentication
# ----------------------------------------------------------------------------------------
def test_snapshot_is_a_stamped_640x480_jpeg_of_the_camera_clock(cam, source):
    before = source.camera_time()
    r = get(cam, "/axis-cgi/jpg/image.cgi?resolution=640x480&compression=30")
    after = source.camera_time()
    assert r.status_code == 200
    assert r.headers["Content-Type"] == "image/jpeg"
    assert int(r.headers["Content-Length"]) == len(r.content)
    info = inspect_jpeg(r.content)
    assert info.problems == ()
    assert (info.width, info.height) == (640, 480)
    # the product segment of the model (P1375 on 10.12.240) with the source's MAC
    assert info.product == cam.product == AxisProduct(0x931, (10, 12, 240), source.product.mac)
    assert before - 0.05 <= info.timestamp <= after + 0.05  # the stamp is truncated to 10 ms


def test_no_credentials_or_wrong_password_get_a_digest_challenge(cam):
    r = requests.get(cam.url + "/axis-cgi/jpg/image.cgi")
    assert r.status_code == 401
    challenge = r.headers["WWW-Authenticate"]
    assert challenge.startswith("Digest ")
    assert 'realm="AXIS_ACCC8E192567"' in challenge and 'qop="auth"' in challenge
    assert "algorithm=MD5" in challenge and "opaque=" in challenge and "nonce=" in challenge
    assert requests.get(cam.url + "/axis-cgi/jpg/image.cgi", auth=HTTPDigestAuth("root", "nope")).status_code == 401
    assert requests.get(cam.url + "/axis-cgi/jpg/image.cgi", auth=("root", PASSWORD)).status_code == 401  # basic
    assert get(cam, "/axis-cgi/jpg/image.cgi").status_code == 200


def test_raw_digest_answer_and_expired_nonce_is_stale(cam):
    path = "/axis-cgi/param.cgi?action=list&group=Brand.ProdNbr"
    sock, reader = raw_request(cam, path)
    with sock:
        status, headers = read_head(reader)
        assert status == b"HTTP/1.1 200 OK\r\n"
        assert reader.read(int(headers["content-length"])) == b"root.Brand.ProdNbr=P1375\r\n"
    header = auth_header(cam, path)
    cam.auth.now = lambda: time.monotonic() + cam.auth.nonce_ttl_s + 10  # the nonce is now old
    conn = http.client.HTTPConnection("127.0.0.1", cam.port, timeout=5)
    conn.request("GET", path, headers={"Authorization": header})
    r = conn.getresponse()
    r.read()
    assert r.status == 401
    assert "stale=true" in r.getheader("WWW-Authenticate")
    conn.close()


def test_digest_for_another_uri_is_refused(cam):
    header = auth_header(cam, "/axis-cgi/date.cgi?action=get")
    conn = http.client.HTTPConnection("127.0.0.1", cam.port, timeout=5)
    conn.request("GET", "/axis-cgi/jpg/image.cgi", headers={"Authorization": header})
    assert conn.getresponse().status == 401
    conn.close()


def test_digest_header_parsing_of_the_clients_we_meet():
    ffmpeg = (
        'username="root",realm="AXIS_1",nonce="a.b.c",uri="/x?a=1,2",response="ff",'
        'algorithm=MD5,opaque="o",qop="auth",cnonce="c1",nc=00000001'
    )
    curl = (
        'username="root", realm="AXIS_1", nonce="a.b.c", uri="/x?a=1,2", cnonce="c1", '
        'nc=00000001, qop=auth, response="ff", opaque="o", algorithm=MD5'
    )
    assert parse_auth_params(ffmpeg) == parse_auth_params(curl)
    assert parse_auth_params(curl)["uri"] == "/x?a=1,2" and parse_auth_params(curl)["qop"] == "auth"
    assert parse_auth_params(r'realm="a \"quoted\" b", x=1')["realm"] == 'a "quoted" b'


def test_curl_digest(cam, tmp_path):
    curl = shutil.which("curl")
    assert curl is not None, "curl is missing: `make test` installs Debian's curl"
    out = tmp_path / "snap.jpg"
    run = subprocess.run(
        [
            curl,
            "-sS",
            "--fail",
            "--digest",
            "-u",
            f"root:{PASSWORD}",
            "-o",
            str(out),
            cam.url + "/axis-cgi/jpg/image.cgi?resolution=640x480",
        ],
        capture_output=True,
        timeout=10,
    )
    assert run.returncode == 0, run.stderr
    assert inspect_jpeg(out.read_bytes()).problems == ()
    run = subprocess.run(
        [curl, "-sS", "--digest", "-u", f"root:{PASSWORD}", cam.url + "/axis-cgi/io/port.cgi?action=1%3A%2F"],
        capture_output=True,
        timeout=10,
    )
    assert run.stdout == b"OK\r\n"
    run = subprocess.run(
        [
            curl,
            "-sS",
            "-o",
            "/dev/null",
            "-w",
            "%{http_code}",
            "--digest",
            "-u",
            "root:wrong",
            cam.url + "/axis-cgi/jpg/image.cgi",
        ],
        capture_output=True,
        timeout=10,
    )
    assert run.stdout == b"401"


def test_opencv_ffmpeg_reads_the_stream_with_credentials_in_the_url(cam):
    cap = cv2.VideoCapture(
        f"http://root:{PASSWORD.replace(' ', '%20')}@127.0.0.1:{cam.port}"
        "/axis-cgi/mjpg/video.cgi?resolution=640x480&fps=25",
        cv2.CAP_FFMPEG,
    )
    try:
        assert cap.isOpened()
        frames = [cap.read() for _ in range(5)]
    finally:
        cap.release()
    assert all(ok for ok, _ in frames)
    assert frames[-1][1].shape[:2] == (480, 640)
    assert cam.counter("auth_failures") >= 1  # FFmpeg really went through the digest challenge


def test_opencv_with_a_wrong_password_does_not_open(cam):
    cap = cv2.VideoCapture(f"http://root:wrong@127.0.0.1:{cam.port}/axis-cgi/mjpg/video.cgi", cv2.CAP_FFMPEG)
    try:
        assert not cap.isOpened() or not cap.read()[0]
    finally:
        cap.release()
    assert cam.counter("frames_served") == 0


# ----------------------------------------------------------------------------------------
# The MJPEG stream
# ----------------------------------------------------------------------------------------
def test_stream_layout_is_byte_exact_like_the_real_capture(cam, axis_frames):
    real = (axis_frames / "t.mjpg").read_bytes()
    real_parts = walk_parts(real)  # the walker's template is what the real camera sends
    assert len(real_parts) == 16
    status, headers, body = stream(cam, "?nbrofframes=4")
    assert status == b"HTTP/1.0 200 OK\r\n"
    assert headers["content-type"] == "multipart/x-mixed-replace; boundary=myboundary"
    parts = walk_parts(body)
    assert len(parts) == 4
    for n, jpeg in parts:
        assert n == len(jpeg) and inspect_jpeg(jpeg).problems == ()
    assert body.startswith(real[: real.index(b"\r\n\r\n") - len(str(real_parts[0][0]))])  # same header text


def test_nbrofframes_ends_the_stream(cam):
    _, _, body = stream(cam, "?nbrofframes=7&fps=30")
    assert len(walk_parts(body)) == 7


def test_duration_ends_the_stream(cam):
    t0 = time.monotonic()
    _, _, body = stream(cam, "?duration=1&fps=10")  # returns at the end of the body: the stream ended
    elapsed = time.monotonic() - t0
    parts = walk_parts(body)
    assert 9 <= len(parts) <= 11
    stamps = [inspect_jpeg(j).timestamp for _, j in parts]
    assert 0.8 <= stamps[-1] - stamps[0] <= 1.0  # one second of the camera's own clock
    assert elapsed >= 0.8  # paced, not sent at once (only a lower bound:
    # a loaded host may be slower, never faster)


def test_fps_pacing_is_spread_over_time(cam):
    """20 frames at 20 fps come over about a second, not at once (a lower bound only: a loaded
    host may be slower, never faster); their stamps are the camera's 50 ms grid."""
    sock, reader = raw_request(cam, "/axis-cgi/mjpg/video.cgi?fps=20&nbrofframes=20")
    with sock:
        read_head(reader)
        t0 = time.monotonic()
        data = read_all(reader)
        spread = time.monotonic() - t0
    parts = walk_parts(data)
    stamps = np.array([inspect_jpeg(j).timestamp for _, j in parts])
    assert len(parts) == 20 and spread >= 0.8
    assert np.abs(np.diff(stamps) - 0.05).max() < 0.011


def test_stream_pacing_does_not_drift():
    """Frame k is due at start + k/fps: 10 ms of capture time per frame must not add up."""
    slow = FakeSource(render_s=0.01)
    with SimAxisCamera(slow, password=PASSWORD) as camera:
        _, _, body = stream(camera, "?fps=25&nbrofframes=25")
    stamps = np.array([inspect_jpeg(j).timestamp for _, j in walk_parts(body)])
    residual = stamps - stamps[0] - np.arange(25) / 25.0
    assert np.abs(residual).max() < 0.025, residual  # stamps are truncated to 10 ms


def test_pacing_follows_the_given_clock(source):
    fast = VirtualClock(rate=20.0)  # simulated time runs 20 times faster than real time
    with SimAxisCamera(source, password=PASSWORD, clock=fast) as camera:
        t0 = time.monotonic()
        _, _, body = stream(camera, "?fps=10&duration=2")  # 2 s of simulated time
        elapsed = time.monotonic() - t0
    parts = walk_parts(body)
    stamps = [inspect_jpeg(j).timestamp for _, j in parts]
    assert 19 <= len(parts) <= 21 and 1.8 <= stamps[-1] - stamps[0] <= 2.0
    # paced by the given clock, not the host's: 2 s of camera time in much less real time
    # (0.1 s at a rate of 20; the bound is the simulated duration itself, 20 times that)
    assert elapsed < 2.0


def test_lower_resolution_and_compression(cam):
    r = get(cam, "/axis-cgi/jpg/image.cgi?resolution=320x240")
    info = inspect_jpeg(r.content)
    assert (info.width, info.height) == (320, 240) and info.problems == ()
    fine = get(cam, "/axis-cgi/jpg/image.cgi?compression=0").content
    coarse = get(cam, "/axis-cgi/jpg/image.cgi?compression=90").content
    assert len(coarse) < 0.5 * len(fine)
    _, _, body = stream(cam, "?resolution=160x120&nbrofframes=2")
    assert all(inspect_jpeg(j).width == 160 for _, j in walk_parts(body))


def test_unsupported_resolution_and_bad_arguments_are_400(cam):
    r = get(cam, "/axis-cgi/jpg/image.cgi?resolution=1234x5")
    assert r.status_code == 400 and r.text.startswith("Error:") and "640x480" in r.text
    assert get(cam, "/axis-cgi/mjpg/video.cgi?fps=fast").status_code == 400
    assert get(cam, "/axis-cgi/jpg/image.cgi?compression=101").status_code == 400


def test_client_disconnect_is_quiet_and_counted_down(cam, capfd):
    for _ in range(3):
        sock, reader = raw_request(cam, "/axis-cgi/mjpg/video.cgi")
        read_head(reader)
        reader.read1(1000)
        sock.close()
    deadline = time.monotonic() + 3
    while cam.counter("active_streams") and time.monotonic() < deadline:
        time.sleep(0.05)
    assert cam.counter("active_streams") == 0
    assert "Traceback" not in capfd.readouterr().err


def test_stop_ends_running_streams(source):
    camera = SimAxisCamera(source, password=PASSWORD).start()
    sock, reader = raw_request(camera, "/axis-cgi/mjpg/video.cgi")
    read_head(reader)
    reader.read1(1000)
    camera.stop()
    with sock:
        read_all(reader, limit_s=30)  # returns at the end of the stream; fails if it never ends


# ----------------------------------------------------------------------------------------
# Parameters, firmware versions, I/O, device info, time
# ----------------------------------------------------------------------------------------
def test_param_list_groups(cam, source):
    r = get(cam, "/axis-cgi/param.cgi?action=list&group=Brand")
    assert r.headers["Content-Type"].startswith("text/plain")
    assert "root.Brand.ProdShortName=AXIS P1375\r\n" in r.text
    assert "root.Brand.ProdType=Network Camera\r\n" in r.text
    assert all(line.startswith("root.Brand.") for line in r.text.splitlines())
    props = get(cam, "/axis-cgi/param.cgi?action=list&group=Properties").text
    assert "root.Properties.System.SerialNumber=ACCC8E192567\r\n" in props
    assert "root.Properties.Firmware.Version=10.12.240\r\n" in props
    assert "root.Properties.Image.Resolution=640x480," in props
    assert "root.Properties.API.HTTP.Version=3\r\n" in props
    image = get(cam, "/axis-cgi/param.cgi?action=list&group=Image.I0").text
    for line in ("Appearance.Resolution=640x480", "Appearance.Compression=25", "Stream.FPS=25"):
        assert f"root.Image.I0.{line}\r\n" in image
    io = get(cam, "/axis-cgi/param.cgi?action=list&group=IOPort.I0").text
    assert "root.IOPort.I0.Direction=output\r\n" in io and "root.IOPort.I0.Output.Active=" in io
    tm = get(cam, "/axis-cgi/param.cgi?action=list&group=root.Time").text
    for key in ("SyncSource", "NTP.Server", "ObtainFromDHCP"):
        assert f"root.Time.{key}=" in tm


def test_param_update_and_errors(cam):
    r = get(cam, "/axis-cgi/param.cgi?action=update&Image.I0.Appearance.Compression=30")
    assert (r.status_code, r.text) == (200, "OK\r\n")
    assert (
        get(cam, "/axis-cgi/param.cgi?action=list&group=Image.I0.Appearance.Compression").text
        == "root.Image.I0.Appearance.Compression=30\r\n"
    )
    r = get(cam, "/axis-cgi/param.cgi?action=list&group=Nonsense")
    assert (r.status_code, r.text) == (200, "# Error: Error -1 getting param in group 'Nonsense'\r\n")
    for bad in ("Image.I0.NoSuch=1", "Image.I0.Appearance.Compression=200", "Brand.ProdNbr=X"):
        r = get(cam, "/axis-cgi/param.cgi?action=update&" + bad)
        assert r.status_code == 200 and r.text.startswith("# Error:"), bad
    assert "Compression=30" in get(cam, "/axis-cgi/param.cgi?action=list&group=Image.I0").text


def test_param_store_is_per_camera(source):
    with SimAxisCamera(source, password=PASSWORD) as a, SimAxisCamera(FakeSource("cam1"), password=PASSWORD) as b:
        get(a, "/axis-cgi/param.cgi?action=update&Time.NTP.Server=10.0.0.9")
        assert "10.0.0.9" in get(a, "/axis-cgi/param.cgi?action=list&group=Time").text
        assert "10.0.0.9" not in get(b, "/axis-cgi/param.cgi?action=list&group=Time").text


def test_vapix2_paths(cam2):
    assert get(cam2, "/axis-cgi/param.cgi?action=list&group=Brand").status_code == 404
    r = get(cam2, "/axis-cgi/view/param.cgi?action=list&group=Properties.API.HTTP.Version")
    assert r.text == "root.Properties.API.HTTP.Version=2\r\n"
    assert get(cam2, "/axis-cgi/view/param.cgi?action=update&Time.NTP.Server=1.2.3.4").text.startswith("# Error:")
    assert get(cam2, "/axis-cgi/admin/param.cgi?action=update&Time.NTP.Server=1.2.3.4").text == "OK\r\n"
    assert "1.2.3.4" in get(cam2, "/axis-cgi/view/param.cgi?action=list&group=Time.NTP").text
    body = {"apiVersion": "1.0", "method": "getAllProperties"}
    assert requests.post(cam2.url + "/axis-cgi/basicdeviceinfo.cgi", json=body, auth=AUTH).status_code == 404
    assert requests.post(cam2.url + "/axis-cgi/time.cgi", json=body, auth=AUTH).status_code == 404
    assert requests.post(cam2.url + "/axis-cgi/apidiscovery.cgi", json=body, auth=AUTH).status_code == 404
    assert get(cam2, "/axis-cgi/io/port.cgi?action=1%3A%2F").status_code == 404  # port.cgi came with 5.00
    assert get(cam2, "/axis-cgi/date.cgi?action=get").status_code == 404
    assert get(cam2, "/axis-cgi/admin/date.cgi?action=get").status_code == 200


def test_vapix3_keeps_the_old_param_paths(cam):
    assert get(cam, "/axis-cgi/view/param.cgi?action=list&group=Brand.Brand").text == "root.Brand.Brand=AXIS\r\n"


def test_basic_device_info(cam, source):
    r = requests.post(
        cam.url + "/axis-cgi/basicdeviceinfo.cgi",
        auth=AUTH,
        json={"apiVersion": "1.0", "context": "t", "method": "getAllProperties"},
    )
    assert r.status_code == 200 and r.headers["Content-Type"] == "application/json"
    reply = r.json()
    assert reply["apiVersion"] == "1.0" and reply["context"] == "t"
    props = reply["data"]["propertyList"]
    assert props["Brand"] == "AXIS" and props["ProdNbr"] == "P1375"
    assert props["SerialNumber"] == "ACCC8E192567" and props["Version"] == "10.12.240"
    r = requests.post(cam.url + "/axis-cgi/basicdeviceinfo.cgi", auth=AUTH, json={"apiVersion": "1.0", "method": "x"})
    assert "error" in r.json()


def test_io_port_drives_the_led(cam, source):
    r = get(cam, "/axis-cgi/io/port.cgi?action=1%3A%2F")
    assert r.text == "OK\r\n" and source.led_on()
    assert get(cam, "/axis-cgi/io/port.cgi?checkactive=1").text == "port1=active\r\n"
    assert get(cam, "/axis-cgi/io/port.cgi?action=1%3A%5C").text == "OK\r\n" and not source.led_on()
    assert get(cam, "/axis-cgi/io/port.cgi?action=1%3A%2F300%5C").text == "OK\r\n"
    assert source.led_calls[-1] == ("pulse", 0.3) and source.led_on()
    assert get(cam, "/axis-cgi/io/port.cgi?action=2%3A%2F").text.startswith("# Error:")
    assert get(cam, "/axis-cgi/io/port.cgi?action=1%3Ax").text.startswith("# Error:")
    assert len(source.led_calls) == 3


def test_led_state_shows_in_the_next_frame(cam):
    def disk_level():
        img = cv2.imdecode(np.frombuffer(get(cam, "/axis-cgi/jpg/image.cgi").content, np.uint8), 0)
        return img[120, 160]

    get(cam, "/axis-cgi/io/port.cgi?action=1%3A%2F")
    assert disk_level() > 200
    get(cam, "/axis-cgi/io/port.cgi?action=1%3A%5C")
    assert disk_level() < 100


def test_date_and_time_are_the_camera_clock(cam, source):
    text = get(cam, "/axis-cgi/date.cgi?action=get").text
    assert re.fullmatch(r"[A-Z][a-z]{2} \d\d, \d{4} \d\d:\d\d:\d\d\r\n", text)
    shown = datetime.strptime(text.strip(), "%b %d, %Y %H:%M:%S").replace(tzinfo=UTC).timestamp()
    assert abs(shown - source.camera_time()) < 2.0
    assert get(cam, "/axis-cgi/date.cgi?action=set").text.startswith("# Error:")
    before = source.camera_time()
    r = requests.post(
        cam.url + "/axis-cgi/time.cgi", auth=AUTH, json={"apiVersion": "1.0", "method": "getDateTimeInfo"}
    )
    after = source.camera_time()
    iso = r.json()["data"]["dateTime"]
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z", iso)
    t = datetime.strptime(iso, "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=UTC).timestamp()
    assert before - 0.002 <= t <= after + 0.002
    assert abs(t - time.time() - source.offset_s) < 0.5  # the camera's clock, not the host's


def test_unknown_paths_are_404(cam):
    assert get(cam, "/axis-cgi/nothing.cgi").status_code == 404
    assert requests.get(cam.url + "/index.html").status_code == 404
