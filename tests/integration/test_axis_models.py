"""The simulated camera models answer as real ones: the parameter tree, the JSON APIs of current
firmware, the AXIS 211 on firmware 4.47 with VAPIX 2 only, and the JPEGs (colour YCbCr 4:2:0, the
Axis comment segments laid out as in the real frames of ../shared/data/axis-frames)."""

from __future__ import annotations

import http.client
import struct

import cv2
import numpy as np
import pytest
import requests
from requests.auth import HTTPDigestAuth

from vts_hw.drivers.axis import AxisCamera
from vts_hw.recording.axis_jpeg import inspect_jpeg
from vts_hw.sim_devices.axis_params import MODELS, Profile
from vts_hw.sim_devices.axis_streaming import restamp
from vts_hw.sim_devices.render import Renderer, encode
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scene import Scene
from vts_hw.vision.detect import detect, detect_jpeg


def segments(jpeg: bytes) -> list[tuple[int, bytes]]:
    """(marker, payload) of every header segment up to the start of scan."""
    out, i = [], 2
    while jpeg[i] == 0xFF and jpeg[i + 1] != 0xDA:
        (length,) = struct.unpack(">H", jpeg[i + 2 : i + 4])
        out.append((jpeg[i + 1], jpeg[i + 4 : i + 2 + length]))
        i += 2 + length
    return out


def layout(jpeg: bytes) -> list[str]:
    """The header up to the frame header, as names: APP0, DQT, time, product, SOF0."""
    names = []
    for marker, body in segments(jpeg):
        if marker == 0xFE and body[:2] == b"\x0a\x01":
            names.append("time")
        elif marker == 0xFE and body[:2] == b"\x0a\x00":
            names.append("product")
        else:
            names.append({0xE0: "APP0", 0xDB: "DQT", 0xC0: "SOF0", 0xC4: "DHT", 0xDD: "DRI"}.get(marker, hex(marker)))
        if names[-1] == "SOF0":
            return names
    return names


def components(jpeg: bytes) -> list[tuple[int, int]]:
    """(component id, sampling factors) from the SOF0 segment."""
    body = next(b for m, b in segments(jpeg) if m == 0xC0)
    return [(body[6 + 3 * k], body[7 + 3 * k]) for k in range(body[5])]


@pytest.fixture
def rig_p1375():
    with SimRig(n_cameras=1, seed=4) as rig, rig.env():
        yield rig


@pytest.fixture
def rig_211():
    with SimRig(n_cameras=1, seed=4, firmware="axis211") as rig, rig.env():
        yield rig


def _get(rig, path, **kw):
    return requests.get(rig.servers["cam1"].url + path, auth=HTTPDigestAuth("root", rig.password), timeout=5, **kw)


def _post(rig, path, **kw):
    return requests.post(rig.servers["cam1"].url + path, auth=HTTPDigestAuth("root", rig.password), timeout=5, **kw)


# ----------------------------------------------------------------------------------------
# Current firmware: the tree and the JSON APIs
# ----------------------------------------------------------------------------------------
def test_parameter_tree_has_every_group_a_client_reads(rig_p1375):
    text = _get(rig_p1375, "/axis-cgi/param.cgi?action=list").text
    tree = dict(line.split("=", 1) for line in text.splitlines())
    serial = rig_p1375.servers["cam1"].product.mac.hex().upper()
    for key in (
        "Brand.Brand",
        "Brand.ProdFullName",
        "Brand.ProdNbr",
        "Brand.ProdShortName",
        "Brand.ProdType",
        "Brand.ProdVariant",
        "Brand.WebURL",
        "Properties.API.HTTP.Version",
        "Properties.API.HTTP.AdminPath",
        "Properties.API.Metadata.Metadata",
        "Properties.API.Metadata.Version",
        "Properties.Firmware.BuildDate",
        "Properties.Firmware.BuildNumber",
        "Properties.Firmware.Version",
        "Properties.Image.Format",
        "Properties.Image.NbrOfViews",
        "Properties.Image.Resolution",
        "Properties.Image.Rotation",
        "Properties.System.Architecture",
        "Properties.System.HardwareID",
        "Properties.System.SerialNumber",
        "Properties.System.Soc",
        "Image.I0.Name",
        "Image.I0.Appearance.Resolution",
        "Image.I0.Appearance.Compression",
        "Image.I0.Stream.FPS",
        "StreamProfile.MaxGroups",
        "StreamProfile.S0.Name",
        "StreamProfile.S0.Parameters",
        "IOPort.I0.Direction",
        "IOPort.I0.Output.Active",
        "IOPort.I0.Output.Name",
        "IOPort.I1.Direction",
        "IOPort.I1.Input.Trig",
        "Input.NbrOfInputs",
        "Output.NbrOfOutputs",
        "Network.eth0.MACAddress",
        "Network.HostName",
        "Time.SyncSource",
        "Time.NTP.Server",
        "Time.TimeZone",
    ):
        assert "root." + key in tree, key
    assert tree["root.Properties.System.SerialNumber"] == serial
    assert tree["root.Network.eth0.MACAddress"].replace(":", "") == serial
    assert tree["root.IOPort.I0.Direction"] == "output" and tree["root.IOPort.I1.Direction"] == "input"
    assert tree["root.Properties.Firmware.Version"] == "10.12.240"


@pytest.mark.parametrize("content_type", ["application/x-www-form-urlencoded", "text/plain"])
def test_param_cgi_by_post_with_a_form_body(rig_p1375, content_type):
    body = "action=list&group=root.Brand"
    r = _post(rig_p1375, "/axis-cgi/param.cgi", data=body, headers={"Content-Type": content_type})
    assert r.status_code == 200 and "root.Brand.ProdNbr=P1375\r\n" in r.text
    assert all(line.startswith("root.Brand.") for line in r.text.splitlines())
    r = _post(
        rig_p1375,
        "/axis-cgi/param.cgi",
        data="action=update&root.Image.I0.Appearance.Compression=40",
        headers={"Content-Type": content_type},
    )
    assert r.text == "OK\r\n"
    assert (
        _get(rig_p1375, "/axis-cgi/param.cgi?action=list&group=Image.I0.Appearance.Compression").text
        == "root.Image.I0.Appearance.Compression=40\r\n"
    )


def test_api_discovery_lists_apis_that_answer(rig_p1375):
    req = {"apiVersion": "1.0", "context": "c", "method": "getApiList"}
    reply = _post(rig_p1375, "/axis-cgi/apidiscovery.cgi", json=req).json()
    assert reply["method"] == "getApiList" and reply["context"] == "c"
    ids = {api["id"]: api for api in reply["data"]["apiList"]}
    assert {"api-discovery", "basic-device-info", "param-cgi", "time-service"} <= set(ids)
    assert all(api["version"] and api["name"] for api in ids.values())
    info = _post(
        rig_p1375,
        "/axis-cgi/basicdeviceinfo.cgi",
        json={"apiVersion": ids["basic-device-info"]["version"], "context": "c", "method": "getAllProperties"},
    ).json()
    props = info["data"]["propertyList"]
    for key in (
        "Architecture",
        "Brand",
        "BuildDate",
        "HardwareID",
        "ProdFullName",
        "ProdNbr",
        "ProdShortName",
        "ProdType",
        "ProdVariant",
        "SerialNumber",
        "Soc",
        "SocSerialNumber",
        "Version",
        "WebURL",
    ):
        assert key in props, key
    assert props["ProdNbr"] == "P1375" and props["HardwareID"] == "931"
    assert (
        _post(rig_p1375, "/axis-cgi/time.cgi", json={"apiVersion": "1.0", "method": "getDateTimeInfo"})
        .json()["data"]["dateTime"]
        .endswith("Z")
    )
    bad = _post(rig_p1375, "/axis-cgi/apidiscovery.cgi", json={"method": "nope"}).json()
    assert bad["error"]["code"] == 2004
    assert _post(rig_p1375, "/axis-cgi/apidiscovery.cgi", data=b"{not json").json()["error"]["code"] == 4000
    assert _get(rig_p1375, "/axis-cgi/usergroup.cgi").text == "root\nadmin operator viewer\n"


def test_an_unknown_model_is_refused():
    with pytest.raises(ValueError, match="no simulated Axis model 'p9999'; known: p1375, axis211"):
        Profile.load("p9999")
    assert set(MODELS) == {"p1375", "axis211"}


# ----------------------------------------------------------------------------------------
# The JPEGs: layout of the Axis segments, colour
# ----------------------------------------------------------------------------------------
def test_current_firmware_frame_is_laid_out_like_the_real_6x_frame(rig_p1375, axis_frames):
    real = (axis_frames / "tst.jpg").read_bytes()
    sim = _get(rig_p1375, "/axis-cgi/jpg/image.cgi").content
    assert layout(real) == layout(sim) == ["APP0", "time", "product", "DQT", "DQT", "SOF0"]
    for jpeg in (real, sim):  # 5.x and later repeat seconds and hundredths in the spare bytes
        time_seg = next(b for m, b in segments(jpeg) if m == 0xFE and b[:2] == b"\x0a\x01")
        assert time_seg[7:12] == time_seg[2:7]


def test_legacy_frame_is_laid_out_like_the_real_447_frame(rig_211, axis_frames):
    real = (axis_frames / "img00012680.jpg").read_bytes()
    sim = _get(rig_211, "/axis-cgi/jpg/image.cgi").content
    assert layout(real) == layout(sim) == ["APP0", "DQT", "DQT", "product", "time", "SOF0"]
    for jpeg in (real, sim):  # 4.x leaves the five spare bytes of the time segment zero
        time_seg = next(b for m, b in segments(jpeg) if m == 0xFE and b[:2] == b"\x0a\x01")
        assert time_seg[7:12] == b"\x00" * 5 and time_seg[12] == 1
    real_info, sim_info = inspect_jpeg(real), inspect_jpeg(sim)
    assert sim_info.problems == () and sim_info.timestamp is not None
    assert (
        (sim_info.product.hardware_id, sim_info.product.firmware)
        == (real_info.product.hardware_id, real_info.product.firmware)
        == (0x15B, (4, 47, 13))
    )
    assert sim_info.product.mac[:3] == real_info.product.mac[:3] == bytes.fromhex("00408C")


def test_frames_are_colour_420_like_the_real_ones(rig_p1375, axis_frames):
    real = (axis_frames / "tst.jpg").read_bytes()
    sim = _get(rig_p1375, "/axis-cgi/jpg/image.cgi").content
    assert components(real) == components(sim) == [(1, 0x22), (2, 0x11), (3, 0x11)]
    small = _get(rig_p1375, "/axis-cgi/jpg/image.cgi?resolution=320x240").content  # re-encoded: still colour
    assert components(small) == [(1, 0x22), (2, 0x11), (3, 0x11)] and layout(small)[1:3] == ["time", "product"]


def test_markers_are_white_on_a_dim_coloured_background(rig_p1375):
    with AxisCamera.from_config(rig_p1375.config().camera("cam1")) as cam:
        cam.led_on()
        jpeg = cam.snapshot().jpeg
    bgr = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR).astype(float)
    src = rig_p1375.sources["cam1"]
    truth = src.scene.truth("cam1", src.clock.now())
    marker = np.array([bgr[int(round(v)), int(round(u))] for _, u, v in truth])
    assert marker.mean(axis=1).min() > 150  # bright ...
    assert np.abs(marker[:, 0] - marker[:, 2]).max() < 12  # ... and white: blue and red alike
    b, g, r = (np.median(bgr[..., k]) for k in range(3))
    assert g < 60 and b > g + 4 and r < g - 1  # the background: dim, blue-grey


def test_detection_on_colour_frames_is_detection_on_their_luma():
    scene = Scene.reference(seed=5)
    scene.add_phantom()
    cam = scene.camera_names[0]
    scene.set_led(cam, True)
    r = Renderer(scene, seed=5)
    t = scene.start_epoch + 30
    img = r.render(cam, t)
    colour, grey = encode(img, 75), encode(img, 75, colour=False)
    assert components(colour)[0] == (1, 0x22) and len(components(grey)) == 1
    a, b = detect_jpeg(colour), detect_jpeg(grey)
    assert len(a.blobs) == len(b.blobs) == len(scene.truth(cam, t)) == 12
    for p, q in zip(a.blobs, b.blobs):
        assert abs(p.x - q.x) < 0.02 and abs(p.y - q.y) < 0.02
    luma = cv2.imdecode(np.frombuffer(colour, np.uint8), cv2.IMREAD_GRAYSCALE)
    assert detect(luma) == a


def test_restamp_replaces_the_segments_in_place():
    scene = Scene.reference()
    data = encode(Renderer(scene).render("cam1", scene.start_epoch), 75)
    product = scene.products["cam1"]
    once = restamp(data, 1_700_000_000.25, product)
    twice = restamp(once, 1_700_000_001.5, product, "after_tables", time_extra_zero=True)
    assert layout(once)[:3] == ["APP0", "time", "product"]
    assert layout(twice) == ["APP0", "DQT", "DQT", "product", "time", "SOF0"]
    assert inspect_jpeg(twice).timestamp == 1_700_000_001.5
    assert len(twice) == len(once) == len(data) + 34  # two 17-byte segments, never more


# ----------------------------------------------------------------------------------------
# The AXIS 211 (firmware 4.47, VAPIX 2)
# ----------------------------------------------------------------------------------------
def test_legacy_camera_has_vapix2_paths_only_and_closes_every_connection(rig_211):
    for path in (
        "/axis-cgi/param.cgi?action=list&group=Brand",
        "/axis-cgi/io/port.cgi?action=1%3A%2F",
        "/axis-cgi/date.cgi?action=get",
    ):
        assert _get(rig_211, path).status_code == 404, path
    for path in ("/axis-cgi/basicdeviceinfo.cgi", "/axis-cgi/apidiscovery.cgi", "/axis-cgi/time.cgi"):
        assert _post(rig_211, path, json={"apiVersion": "1.0", "method": "getApiList"}).status_code == 404, path
    tree = _get(rig_211, "/axis-cgi/view/param.cgi?action=list").text
    assert "root.Properties.API.HTTP.Version=2\r\n" in tree and "root.Brand.ProdNbr=211\r\n" in tree
    assert "root.Output.O0.Name=LED ring\r\n" in tree and "root.IOPort." not in tree
    # every answer, the 401 challenge included, is HTTP/1.0 and closes the connection
    server = rig_211.servers["cam1"]
    conn = http.client.HTTPConnection("127.0.0.1", server.port, timeout=5)
    conn.request("GET", "/axis-cgi/view/param.cgi?action=list&group=Brand")
    r = conn.getresponse()
    r.read()
    assert (r.status, r.version, r.getheader("Connection")) == (401, 10, "close")
    ok = _get(rig_211, "/axis-cgi/admin/date.cgi?action=get")
    assert ok.status_code == 200 and ok.raw.version == 10 and ok.headers["Connection"] == "close"
    assert _get(rig_211, "/axis-cgi/io/output.cgi?action=1%3A%2F").text == "OK\r\n"
    assert rig_211.sources["cam1"].led_on()
    assert _get(rig_211, "/axis-cgi/io/output.cgi?check=1").text == "output1=1\r\n"
    assert _get(rig_211, "/axis-cgi/io/input.cgi?check=1").text == "input1=0\r\n"


def test_our_driver_works_the_legacy_camera(rig_211):
    with AxisCamera.from_config(rig_211.config().camera("cam1")) as cam:
        assert cam.vapix_version == 2
        info = cam.device_info()
        assert (info["ProdNbr"], info["Version"]) == ("211", "4.47")
        assert info["SerialNumber"] == rig_211.servers["cam1"].product.mac.hex().upper()
        assert info["SerialNumber"].startswith("00408C")
        frame = cam.snapshot()
        assert frame.problems == () and frame.camera_time is not None
        cam.set_params({"Image.I0.Appearance.Compression": 35})
        assert cam.get_params("Image.I0")["Image.I0.Appearance.Compression"] == "35"
        cam.led_on()  # through io/output.cgi: port.cgi is a 404 on this firmware
        assert rig_211.sources["cam1"].led_on()
        cam.led_off()
        assert not rig_211.sources["cam1"].led_on()
        frames = [f for f in cam.stream(nbrofframes=5) if hasattr(f, "jpeg")]
        assert len(frames) == 5 and all(f.camera_time is not None for f in frames)
        offset = cam.clock_offset(samples=3)
        src = rig_211.sources["cam1"]
        assert offset.method == "snapshot"
        truth = src.camera_time(offset.host_time) - offset.host_time
        assert abs(offset.offset_s - truth) < offset.uncertainty_s + 0.02


@pytest.mark.parametrize("model", ["p1375", "axis211"])
def test_opencv_ffmpeg_reads_the_colour_stream_of_each_model(model):
    with SimRig(n_cameras=1, seed=6, firmware=model, password="pw") as rig:
        port = rig.servers["cam1"].port
        cap = cv2.VideoCapture(f"http://root:pw@127.0.0.1:{port}/axis-cgi/mjpg/video.cgi", cv2.CAP_FFMPEG)
        try:
            frames = [cap.read() for _ in range(3)]
        finally:
            cap.release()
    assert all(ok and img.shape == (480, 640, 3) for ok, img in frames)
    img = frames[-1][1].astype(int)
    assert np.median(img[..., 0] - img[..., 2]) >= 5  # decoded in colour: the blue-grey background
