"""`vts camera setup`: each simulated model (AXIS P1375 on current firmware, AXIS 211 on 4.47) is
set and read back as its firmware takes it, what was set becomes the camera's locked_params in
rig.yaml (comments kept, the old file kept), and the daily QA checks exactly that; a value the
camera refuses is one sentence naming it; the VAPIX exchanges byte for byte."""

from __future__ import annotations

import json

import pytest
import requests
from requests.auth import HTTPDigestAuth

from inprocess_cli import vts
from scripted_http import ScriptedHTTP
from vts_hw.config import dump_rig, load_rig, parse_rig
from vts_hw.drivers.axis import AxisCamera
from vts_hw.drivers.axis_setup import SetupRefused, setup_camera
from vts_hw.drivers.registry import open_camera
from vts_hw.procedures.daily import QARun
from vts_hw.sim_devices.rig import SimRig

SETUP = "camera_setup:\n  ntp_server: ntp.example.org   # the hospital's time server\n  time_zone: Europe/Stockholm\n"


@pytest.fixture
def room(tmp_path):
    with SimRig(n_cameras=2, seed=5, firmware=["p1375", "axis211"]) as rig, rig.env():
        path = tmp_path / "rig.yaml"
        path.write_text("# our room: two cameras over the gantry\n" + dump_rig(rig.config()) + SETUP)
        yield rig, path


def test_setup_all_sets_both_models_writes_locked_params_and_the_daily_qa_checks_them(room, capsys):
    rig, path = room
    old = path.read_text()
    code, out, err = vts(capsys, "camera", "setup", "--all", "--config", path)
    assert code == 0, err
    p1375, m211 = rig.servers["cam1"].params, rig.servers["cam2"].params
    for params in (p1375, m211):  # what the cameras now hold
        assert params.get("ImageSource.I0.Sensor.Exposure") == "hold"
        assert params.get("ImageSource.I0.Sensor.WhiteBalance") == "hold"
        assert params.get("Time.NTP.Server") == "ntp.example.org" and params.get("Time.SyncSource") == "NTP"
        assert params.get("Image.I0.Text.TextEnabled") == "no"
    assert p1375.get("Time.TimeZone") == "Europe/Stockholm"  # through the Time API
    assert m211.get("Time.TimeZone") == "UTC0"  # VAPIX 2: the parameter, a POSIX string
    text = path.read_text()
    assert text.startswith("# our room") and "# the hospital's time server" in text  # comments kept
    assert (path.parent / "rig.yaml.bak").read_text() == old  # the old file kept
    cfg = load_rig(path)
    locked = cfg.camera("cam1").locked_params
    assert locked["Image.I0.Text.TextEnabled"] == "no" and locked["Time.TimeZone"] == "Europe/Stockholm"
    assert locked["ImageSource.I0.Sensor.MaxGain"] == "48"  # not set: locked as the camera has it
    assert "Image.I0.Overlay.Enabled" not in cfg.camera("cam2").locked_params  # the 211 has none
    assert "Image.I0.Overlay.Enabled: not on this firmware" in out

    qa = QARun(cfg, steps=("reachable", "params"), open_camera=open_camera)
    assert all(p in " ".join(qa.plan()) for p in locked)  # the QA checks exactly what was set ...
    result = qa.run()
    assert [m.value for m in result.measures if m.metric == "params_changed"] == [0.0, 0.0], result.results()
    m211.update([("ImageSource.I0.Sensor.WhiteBalance", "auto")])  # ... and sees a change
    result = QARun(cfg, steps=("reachable", "params"), open_camera=open_camera).run()
    cam2 = next(c for c in result.cameras if c.camera == "cam2")
    assert "parameter ImageSource.I0.Sensor.WhiteBalance is 'auto', locked at 'hold'" in cam2.problems


def test_a_refused_value_names_the_parameter_and_the_other_camera_is_still_written(room, capsys):
    rig, path = room
    text = path.read_text().replace("- name: cam1\n", "- name: cam1\n  fps: 12.5\n", 1)  # no whole frame rate
    assert "fps: 12.5" in text  # (dump_rig leaves the default fps out: the entry had none)
    path.write_text(text)
    code, out, err = vts(capsys, "camera", "setup", "--all", "--config", path)
    assert code == 4, err
    assert (
        "vts: camera cam1 refused Image.I0.Stream.FPS=12.5: it is not a value this firmware takes "
        "(the camera said: Error setting 'root.Image.I0.Stream.FPS' to '12.5')"
    ) in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert rig.servers["cam1"].params.get("ImageSource.I0.Sensor.Exposure") == "auto"  # all or nothing
    cfg = load_rig(path)
    assert cfg.camera("cam1").locked_params == {} and cfg.camera("cam2").locked_params


def test_an_unknown_time_zone_is_refused_by_the_time_api(room, capsys):
    rig, path = room
    path.write_text(path.read_text().replace("Europe/Stockholm", "Mars/Olympus_Mons"))
    code, out, err = vts(capsys, "camera", "setup", "cam1", "--config", path)
    assert code == 4
    assert err.strip() == (
        "vts: camera cam1 refused time zone Mars/Olympus_Mons through the Time API: "
        "Invalid time zone: Mars/Olympus_Mons"
    )


def test_a_parameter_the_firmware_lacks_is_refused_before_anything_is_sent(room):
    rig, path = room
    cfg = load_rig(path)
    setup = cfg.camera_setup.model_copy(update={"max_exposure_us": 8000})
    with AxisCamera.from_config(cfg.camera("cam2")) as cam, pytest.raises(SetupRefused) as err:
        setup_camera(cam, cfg.camera("cam2"), setup)
    assert str(err.value) == (
        "camera cam2 has no parameter ImageSource.I0.Sensor.MaxExposureTime: its firmware "
        "(AXIS 211 4.47) cannot be set to MaxExposureTime=8000"
    )
    assert rig.servers["cam2"].params.get("ImageSource.I0.Sensor.Exposure") == "auto"


def test_setup_of_an_unknown_camera_or_without_a_name_is_bad_input(room, capsys):
    rig, path = room
    assert vts(capsys, "camera", "setup", "cam9", "--config", path)[0] == 2
    assert vts(capsys, "camera", "setup", "--config", path)[0] == 2


# -- the simulated firmware refuses as the real one does ------------------------------------
@pytest.mark.parametrize("model", ["p1375", "axis211"])
@pytest.mark.parametrize(
    "param, value",
    [
        ("Image.I0.No.Such", "1"),  # unknown
        ("Brand.ProdNbr", "P9999"),  # read-only
        ("Properties.System.SerialNumber", "1"),  # read-only
        ("ImageSource.I0.Sensor.Exposure", "sometimes"),  # not a value it takes
        ("Image.I0.Text.TextEnabled", "false"),
        ("Time.NTP.Server", "ntp example"),
        ("Time.TimeZone", "Nowhere/Special"),
    ],
)
def test_the_simulated_firmware_refuses_unknown_read_only_and_bad_values(model, param, value):
    with SimRig(n_cameras=1, seed=2, firmware=model) as rig:
        srv = rig.servers["cam1"]
        path = "/axis-cgi/param.cgi" if model == "p1375" else "/axis-cgi/admin/param.cgi"
        before = srv.params.find(param)
        r = requests.get(
            srv.url + path,
            params={"action": "update", param: value},
            auth=HTTPDigestAuth("root", rig.password),
            timeout=5,
        )
        assert r.status_code == 200 and r.text == f"# Error: Error setting 'root.{param}' to '{value}'!\r\n"
        assert srv.params.find(param) == before


# -- byte for byte ---------------------------------------------------------------------------
def _listing(group: str, values: dict[str, str]) -> str:
    return "".join(f"root.{k}={v}\r\n" for k, v in values.items() if k.startswith(group + "."))


TREE = {
    "Image.I0.Appearance.Resolution": "640x480",
    "Image.I0.Appearance.Compression": "25",
    "Image.I0.Stream.FPS": "25",
    "Image.I0.Text.TextEnabled": "no",
    "Image.I0.Text.ClockEnabled": "yes",
    "Image.I0.Text.DateEnabled": "no",
    "ImageSource.I0.Sensor.Exposure": "auto",
    "ImageSource.I0.Sensor.WhiteBalance": "auto",
    "Time.SyncSource": "NTP",
    "Time.NTP.Server": "10.0.0.1",
    "Time.TimeZone": "GMT",
}
UPDATE = (
    "Image.I0.Appearance.Resolution=640x480&Image.I0.Stream.FPS=25&Image.I0.Appearance.Compression=25"
    "&ImageSource.I0.Sensor.Exposure=hold&ImageSource.I0.Sensor.WhiteBalance=hold"
    "&Image.I0.Text.TextEnabled=no&Image.I0.Text.ClockEnabled=no&Image.I0.Text.DateEnabled=no"
    "&Time.SyncSource=NTP&Time.NTP.Server=ntp.example.org"
)


def _setup_against(script):
    """setup_camera of cam1 against a peer that expects exactly ``script``, all of it."""
    with ScriptedHTTP(script) as peer:
        host, port = peer.url.split("//")[1].split(":")
        rig = parse_rig(
            {
                "cameras": [{"name": "cam1", "host": host, "port": int(port)}],
                "camera_setup": {"ntp_server": "ntp.example.org", "time_zone": "Europe/Stockholm"},
            }
        )
        with AxisCamera.from_config(rig.camera("cam1")) as cam:
            result = setup_camera(cam, rig.camera("cam1"), rig.camera_setup)
    peer.assert_complete()
    return result


def test_vapix2_setup_byte_for_byte():
    after = {**TREE, **dict(kv.split("=") for kv in UPDATE.split("&")), "Time.TimeZone": "UTC0"}
    script = [
        ("GET /axis-cgi/param.cgi?action=list&group=Brand", None, (404, "<HTML>404</HTML>")),
        ("GET /axis-cgi/view/param.cgi?action=list&group=Brand", None, "root.Brand.Brand=AXIS\r\n"),
        *[
            (f"GET /axis-cgi/view/param.cgi?action=list&group={g}", None, _listing(g, TREE))
            for g in ("Image.I0", "ImageSource.I0", "Time")
        ],
        (f"GET /axis-cgi/admin/param.cgi?action=update&{UPDATE}&Time.TimeZone=UTC0", None, "OK\r\n"),
        *[
            (f"GET /axis-cgi/view/param.cgi?action=list&group={g}", None, _listing(g, after))
            for g in ("Image.I0", "ImageSource.I0", "Time")
        ],
    ]
    result = _setup_against(script)
    assert result.locked["Time.TimeZone"] == "UTC0" and "Image.I0.Text.ClockEnabled" in result.changed


def test_current_firmware_setup_and_time_api_byte_for_byte():
    after = {**TREE, **dict(kv.split("=") for kv in UPDATE.split("&"))}
    stockholm = {**after, "Time.TimeZone": "Europe/Stockholm"}
    set_tz = json.dumps(
        {"apiVersion": "1.0", "method": "setTimeZone", "params": {"timeZone": "Europe/Stockholm"}}
    ).encode()
    get_tz = json.dumps({"apiVersion": "1.0", "method": "getDateTimeInfo"}).encode()
    info = json.dumps(
        {
            "apiVersion": "1.0",
            "method": "getDateTimeInfo",
            "data": {"dateTime": "2026-01-01T00:00:00Z", "timeZone": "Europe/Stockholm"},
        }
    )
    script = [
        ("GET /axis-cgi/param.cgi?action=list&group=Brand", None, "root.Brand.Brand=AXIS\r\n"),
        *[
            (f"GET /axis-cgi/param.cgi?action=list&group={g}", None, _listing(g, TREE))
            for g in ("Image.I0", "ImageSource.I0", "Time")
        ],
        (f"GET /axis-cgi/param.cgi?action=update&{UPDATE}", None, "OK\r\n"),
        *[
            (f"GET /axis-cgi/param.cgi?action=list&group={g}", None, _listing(g, after))
            for g in ("Image.I0", "ImageSource.I0", "Time")
        ],
        ("POST /axis-cgi/time.cgi", set_tz, '{"apiVersion": "1.0", "method": "setTimeZone", "data": {}}'),
        ("POST /axis-cgi/time.cgi", get_tz, info),
        ("GET /axis-cgi/param.cgi?action=list&group=Time", None, _listing("Time", stockholm)),
    ]
    result = _setup_against(script)
    assert result.locked["Time.TimeZone"] == "Europe/Stockholm" and "Time.TimeZone" in result.changed
