"""Software written against real Axis cameras, by others, works against the simulated ones.

* ``axis`` (PyPI; the VAPIX library behind Home Assistant's Axis integration): it connects
  over HTTP with digest auth, reads the whole parameter tree it needs without a ``KeyError``,
  reads the identity and switches the output port -- and the LED ring of the simulated room
  really goes on and off (the markers show in the next frame).
* curl and requests over HTTPS with basic authentication and a self-signed certificate this
  test makes; our own driver over HTTPS with ``ca_cert`` in the rig config, and its one-sentence
  errors when the certificate is not trusted or a camera asks for basic auth over plain http.
"""

from __future__ import annotations

import asyncio
import shutil
import subprocess

import cv2
import httpx
import numpy as np
import pytest
import requests
from axis.device import AxisDevice  # axis==60 from the dev extra
from axis.models.configuration import Configuration

from vts_hw.config import parse_rig
from vts_hw.drivers.axis import AxisCamera, CameraUnauthorized, CameraUnreachable
from vts_hw.sim_devices.axis_camera import SimAxisCamera
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.tls import self_signed


def _marker_levels(rig: SimRig, cam: str, jpeg: bytes) -> np.ndarray:
    """Grey levels at the wall markers where the scene's ground truth puts them."""
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    src = rig.sources[cam]
    truth = src.scene.truth(cam, src.clock.now())
    assert len(truth) >= 4
    return np.array([img[int(round(v)), int(round(u))] for _, u, v in truth])


async def _connect(port: int, password: str, session: httpx.AsyncClient) -> AxisDevice:
    device = AxisDevice(Configuration(session, "127.0.0.1", port=port, username="root", password=password))
    await device.vapix.initialize()  # API discovery, basic device info, param.cgi groups, ports
    await device.vapix.load_user_groups()
    return device


def test_axis_library_reads_identity_and_switches_the_output_port():
    with SimRig(n_cameras=1, seed=3) as rig, rig.env():
        server = rig.servers["cam1"]
        driver = AxisCamera.from_config(rig.config().camera("cam1"))

        async def scenario():
            async with httpx.AsyncClient() as session:
                device = await _connect(server.port, rig.password, session)
                vapix = device.vapix
                identity = (vapix.serial_number, vapix.product_number, vapix.product_type, vapix.firmware_version)
                # the identity came from basicdeviceinfo.cgi, listed by apidiscovery.cgi ...
                assert vapix.basic_device_info.initialized
                assert "basic-device-info" in vapix.api_discovery
                # ... and the whole parameter tree parses into the library's models
                await vapix.initialize_param_cgi(preload_data=True)
                props = vapix.params.property_handler["0"]
                brand = vapix.params.brand_handler["0"]
                image = vapix.params.image_handler["0"]
                assert image.appearance["Resolution"] == "640x480" and image.stream["FPS"] == 25
                assert [p.id for p in vapix.streaming_profiles] == ["vts"]
                ports = vapix.ports
                assert "0" in ports and ports["0"].direction == "output" and ports["0"].name == "LED ring"
                assert ports["1"].direction == "input"
                await ports.close("0")  # close the circuit: the output active, the LED ring on
                lit = _marker_levels(rig, "cam1", driver.snapshot().jpeg)
                on_after_close = rig.sources["cam1"].led_on()
                await ports.open("0")
                dark = _marker_levels(rig, "cam1", driver.snapshot().jpeg)
                return identity, props, brand, vapix.access_rights, on_after_close, lit, dark

        identity, props, brand, rights, on_after_close, lit, dark = asyncio.run(scenario())
        driver.close()
        serial = server.params.get("Properties.System.SerialNumber")
        assert identity == (serial, "P1375", "Network Camera", "10.12.240")
        assert serial == server.product.mac.hex().upper()
        assert props.api_http_version == 3 and props.firmware_build_number == 11
        assert props.system_serial_number == serial and "640x480" in props.image_resolution
        assert brand.product_full_name == "AXIS P1375 Network Camera"
        assert rights.name == "ADMIN"
        assert on_after_close and not rig.sources["cam1"].led_on()
        assert lit.min() > dark.max() + 80, (lit, dark)


def test_axis_library_on_the_legacy_camera_finds_no_v3_api():
    """On the AXIS 211 (VAPIX 2) the library's VAPIX 3 requests get 404s, as from the real
    camera: it reports no identity rather than crashing."""
    with SimRig(n_cameras=1, firmware="axis211") as rig:

        async def scenario():
            async with httpx.AsyncClient() as session:
                device = await _connect(rig.servers["cam1"].port, rig.password, session)
                return device.vapix.serial_number, device.vapix.params.property_handler.initialized

        assert asyncio.run(scenario()) == ("", False)
        assert rig.servers["cam1"].counter("auth_failures") >= 1  # it did talk to the camera


# ----------------------------------------------------------------------------------------
# HTTPS with basic authentication
# ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def certificate(tmp_path_factory):
    return self_signed(tmp_path_factory.mktemp("tls"))


@pytest.fixture
def https_rig(certificate):
    cert, key = certificate
    with SimRig(n_cameras=1, seed=2, tls=(str(cert), str(key))) as rig, rig.env():
        yield rig


def test_https_rig_config_names_the_certificate(https_rig, certificate):
    cfg = https_rig.config().camera("cam1")
    assert cfg.scheme == "https" and cfg.ca_cert == certificate[0].resolve()
    assert cfg.base_url == f"https://127.0.0.1:{https_rig.servers['cam1'].port}"


def test_driver_over_https_with_basic_auth(https_rig, monkeypatch):
    # requests lets this variable override a session's verify: ca_cert must win all the same
    monkeypatch.setenv("REQUESTS_CA_BUNDLE", requests.certs.where())
    server = https_rig.servers["cam1"]
    with AxisCamera.from_config(https_rig.config().camera("cam1")) as cam:
        assert cam.device_info()["ProdNbr"] == "P1375"
        frame = cam.snapshot()
        assert frame.problems == () and frame.camera_time is not None
        cam.led_on()
        assert https_rig.sources["cam1"].led_on()
        frames = [f for f in cam.stream(nbrofframes=3) if hasattr(f, "jpeg")]
        assert len(frames) == 3
    # each request was first challenged for basic credentials, then answered
    assert server.auth.challenge().startswith("Basic ")


def test_curl_and_requests_over_https(https_rig, certificate, tmp_path):
    server = https_rig.servers["cam1"]
    url = server.url + "/axis-cgi/jpg/image.cgi"
    r = requests.get(url, auth=("root", https_rig.password), verify=str(certificate[0]), timeout=5)
    assert r.status_code == 200 and r.content.startswith(b"\xff\xd8")
    assert requests.get(url, auth=("root", "wrong"), verify=str(certificate[0]), timeout=5).status_code == 401
    with pytest.raises(requests.exceptions.SSLError):  # not trusted without the certificate
        requests.get(url, verify=True, timeout=5)
    if shutil.which("curl") is None:
        pytest.fail("curl is missing: make test installs it (TEST_DEBS)")
    out = tmp_path / "snap.jpg"
    done = subprocess.run(
        [
            "curl",
            "-sS",
            "--fail",
            "--cacert",
            str(certificate[0]),
            "-u",
            f"root:{https_rig.password}",
            "-o",
            str(out),
            url,
        ],
        capture_output=True,
        text=True,
        timeout=30,
    )
    assert done.returncode == 0, done.stderr
    assert out.read_bytes().startswith(b"\xff\xd8")


def test_untrusted_certificate_is_one_sentence(https_rig):
    cfg = https_rig.config().camera("cam1")
    with AxisCamera("cam1", cfg.base_url, "root", https_rig.password) as cam:  # no ca_cert
        with pytest.raises(CameraUnreachable) as err:
            cam.snapshot()
    msg = str(err.value)
    assert msg.startswith("camera cam1 at https://127.0.0.1:") and "could not be verified" in msg
    assert "ca_cert" in msg and https_rig.password not in msg


def test_config_checks_the_certificate_option(certificate, tmp_path):
    from vts_hw.errors import ConfigError

    base = {"name": "cam1", "host": "10.0.0.2", "scheme": "https"}
    assert parse_rig({"cameras": [base | {"ca_cert": str(certificate[0])}]}).cameras[0].ca_cert == certificate[0]
    with pytest.raises(ConfigError, match=r"cameras\[0\]\.ca_cert no such certificate file"):
        parse_rig({"cameras": [base | {"ca_cert": str(tmp_path / "none.pem")}]}, "rig.yaml")
    with pytest.raises(ConfigError, match=r"ca_cert needs scheme: https"):
        parse_rig({"cameras": [base | {"scheme": "http", "ca_cert": str(certificate[0])}]}, "rig.yaml")
    assert parse_rig({"cameras": [base]}).cameras[0].base_url == "https://10.0.0.2"  # 443 by default


def test_basic_auth_is_never_sent_in_clear():
    """A plain-http camera that asks for basic auth gets no password: one sentence instead."""
    from vts_hw.sim_devices.camera_source import SimCameraSource
    from vts_hw.sim_devices.clock import RealClock
    from vts_hw.sim_devices.render import Renderer
    from vts_hw.sim_devices.scene import Scene

    scene = Scene.reference()
    src = SimCameraSource(scene, Renderer(scene), "cam1", RealClock())
    with SimAxisCamera(src, password="pw", auth="basic") as server:
        with AxisCamera("cam1", server.url, "root", "pw") as cam:
            with pytest.raises(CameraUnauthorized) as err:
                cam.snapshot()
        assert "basic authentication over plain http" in str(err.value) and "scheme: https" in str(err.value)
        assert server.counter("requests") == 1  # the challenge was not answered


# ----------------------------------------------------------------------------------------
# As a user: vts sim up --model axis211 --https, then vts camera ...
# ----------------------------------------------------------------------------------------
def test_vts_against_a_legacy_https_rig(tmp_path):
    import json
    import os
    import sys

    from vts_hw.sim_devices.rig import load_env_file

    def vts(*args, env=None):
        return subprocess.run(
            [sys.executable, "-m", "vts_hw.cli.__main__", *args], capture_output=True, text=True, env=env, timeout=90
        )

    d = tmp_path / "sim"
    up = vts("sim", "up", "--model", "axis211", "--https", "--cameras", "1", "--detach", "--dir", str(d))
    assert up.returncode == 0, up.stderr
    try:
        env = dict(os.environ, **load_env_file(d / "sim.env"))
        rig_yaml = (d / "rig.yaml").read_text()
        assert "scheme: https" in rig_yaml and f"ca_cert: {(d / 'sim-camera-cert.pem').resolve()}" in rig_yaml
        p = vts("camera", "info", "cam1", "--json", env=env)
        assert p.returncode == 0, p.stderr
        info = json.loads(p.stdout)
        assert info["url"].startswith("https://127.0.0.1:") and info["vapix"] == 2
        assert (info["device"]["ProdNbr"], info["device"]["Version"]) == ("211", "4.47")
        assert info["clock_method"] == "snapshot"
        p = vts("camera", "led", "cam1", "on", env=env)
        assert p.returncode == 0 and p.stdout.strip() == "cam1: LED on (output port 1): read back: on", p.stderr
        # the same rig without the certificate: one sentence, exit 4
        (d / "no-cert.yaml").write_text("\n".join(line for line in rig_yaml.splitlines() if "ca_cert" not in line))
        p = vts(
            "camera",
            "snapshot",
            "cam1",
            "-o",
            str(tmp_path / "x.jpg"),
            env=dict(env, VTS_CONFIG=str(d / "no-cert.yaml")),
        )
        assert p.returncode == 4 and "Traceback" not in p.stderr
        assert p.stderr.strip().splitlines() == [p.stderr.strip()]
        assert "could not be verified" in p.stderr and "ca_cert" in p.stderr
        assert not (tmp_path / "x.jpg").exists()
    finally:
        vts("sim", "down", "--dir", str(d))
