"""The camera contract by role (issue 34 §2): each kind implements exactly the roles it has, and
the callers ask the role (the LED ring, parameters, uptime) rather than catch a kind that fakes
it. In process, without a running camera: opening an HTTP camera connects to nothing, and a
replay is one frame written here."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from inprocess_cli import vts
from vts_hw.camera import ROLES, Camera, Illumination, Parameters, RunningTime, roles_of
from vts_hw.camera_led import pulse_led, switch_led
from vts_hw.config import parse_rig
from vts_hw.console.room import RoomFacts
from vts_hw.drivers.registry import CAMERA_KINDS, camera_settings, kind_has, open_camera
from vts_hw.drivers.replay import ReplayCamera
from vts_hw.errors import ConfigError
from vts_hw.procedures.drift import acquire_led_frames
from vts_hw.recording.folder import INDEX_HEADER

EVERY = ("frames", "device information", "clock")
#: the roles each kind (and option) claims
CLAIMED = {
    "axis": EVERY + ("illumination", "parameters", "running time", "setup"),
    "mjpeg": EVERY,
    "mjpeg led vapix": EVERY + ("illumination",),
    "replay": EVERY,
}


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A recording folder of one camera and one frame (what a replay needs)."""
    folder = tmp_path_factory.mktemp("roles") / "rec"
    folder.mkdir()
    ok, jpeg = cv2.imencode(".jpg", np.full((48, 64), 90, np.uint8))
    data = jpeg.tobytes()
    (folder / "cam1.mjpeg").write_bytes(data)
    (folder / "cam1.index.csv").write_text(",".join(INDEX_HEADER) + f"\n0,0,{len(data)},1795000000.0,1795000000.01\n")
    return folder


def _entries(folder) -> dict[str, dict]:
    return {
        "axis": {"name": "cam1", "host": "127.0.0.1", "port": 9},
        "mjpeg": {"name": "cam2", "kind": "mjpeg", "host": "127.0.0.1", "port": 9},
        "mjpeg led vapix": {
            "name": "cam3",
            "kind": "mjpeg",
            "host": "127.0.0.1",
            "port": 9,
            "options": {"led": "vapix"},
        },
        "replay": {"name": "cam1", "kind": "replay", "options": {"folder": str(folder)}},
    }


def _camera(entry: dict):
    return open_camera(parse_rig({"rig": "roles", "cameras": [entry]}, "test rig.yaml").cameras[0])


def test_each_kind_implements_exactly_the_roles_it_claims(recording):
    assert set(CAMERA_KINDS) == {k.split()[0] for k in CLAIMED}
    assert set(ROLES) == set(CLAIMED["axis"])
    for what, entry in _entries(recording).items():
        with _camera(entry) as cam:
            assert isinstance(cam, Camera), what
            assert roles_of(cam) == CLAIMED[what], what


def test_a_planted_role_is_seen(recording):
    """The check above fails on a kind that fakes a role: a replay given no-op LED calls (as it
    had before the roles) is Illumination, and no longer what the replay kind claims."""

    class FakingReplay(ReplayCamera):
        def led_on(self): ...

        def led_off(self): ...

        def led_pulse(self, ms): ...

        def led_state(self):
            return None

    with FakingReplay("cam1", recording) as cam:
        assert roles_of(cam) != CLAIMED["replay"] and isinstance(cam, Illumination)


def test_roles_asked_of_a_kind_before_opening(recording):
    rig = parse_rig({"rig": "roles", "cameras": list(_entries(recording).values())[1:]}, "test rig.yaml")
    axis = parse_rig({"rig": "roles", "cameras": [_entries(recording)["axis"]]}, "x").cameras[0]
    assert kind_has(axis, Parameters) and kind_has(axis, RunningTime)
    assert not any(kind_has(c, Parameters) or kind_has(c, RunningTime) for c in rig.cameras)


def test_each_kind_checks_its_own_settings(recording):
    def rig(entry):
        return parse_rig({"rig": "roles", "cameras": [entry]}, "test rig.yaml").cameras[0]

    assert camera_settings(rig(_entries(recording)["mjpeg led vapix"])).led == "vapix"
    assert camera_settings(rig(_entries(recording)["replay"])).speed == 1.0
    for entry, said in (
        ({"name": "cam1"}, r"camera 'cam1' \(kind axis\) needs a host \(network cameras: address\)"),
        ({"name": "cam1", "kind": "mjpeg"}, r"camera 'cam1' \(kind mjpeg\) needs a host"),
        (
            {"name": "cam1", "host": "h", "options": {"speed": 2}},
            r"camera 'cam1' \(kind axis\): options.speed: Extra inputs",
        ),
        (
            {"name": "cam1", "kind": "mjpeg", "host": "h", "options": {"led": "usb"}},
            r"camera 'cam1' \(kind mjpeg\): options.led: Input should be 'none' or 'vapix'",
        ),
        (  # a path not from / would join onto the host: http://h + .evil.example/x is another host
            {"name": "cam1", "kind": "mjpeg", "host": "h", "options": {"stream_path": ".evil.example/x"}},
            r"camera 'cam1' \(kind mjpeg\): options.stream_path: String should match pattern",
        ),
        (
            {"name": "cam1", "kind": "mjpeg", "host": "h", "options": {"snapshot_path": "@evil.example/x.jpg"}},
            r"camera 'cam1' \(kind mjpeg\): options.snapshot_path: String should match pattern",
        ),
        (
            {"name": "cam1", "kind": "mjpeg", "host": "h", "options": {"host": "k"}},
            r"options.host: host is a key of the camera entry itself",
        ),
        (
            {"name": "cam1", "kind": "replay"},
            r"camera 'cam1' \(kind replay\): options.folder: "
            r"Field required",
        ),
    ):
        with pytest.raises(ConfigError, match=said):
            camera_settings(rig(entry))


def test_callers_ask_the_role_of_a_camera_without_it(recording):
    """The LED switch and pulse, the drift QA's LED frames and the console's LED, on a replay:
    nothing is sent, the state is not known (never off), no LED-off frame is taken (the LED
    check is not made)."""
    with _camera(_entries(recording)["replay"]) as cam:
        assert switch_led(cam, True).state is None
        assert pulse_led(cam, 300).state is None
        on, off = acquire_led_frames(cam, n_frames=1, settle_s=0)
        facts = RoomFacts({"cam1": cam}, "roles")
        shown = facts.switch_led("cam1", False)
    assert len(on) == 1 and off is None
    assert shown["led"] == "unknown" and "cannot tell" in shown["led_why"] and shown["led_error"] == ""


def test_the_commands_ask_the_role(recording, tmp_path, capsys):
    """`vts camera led` on a replay says it is a no-op (exit 0); `vts camera setup` refuses a kind
    without parameters (exit 2), before anything is touched."""
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"rig": "roles", "cameras": [_entries(recording)["replay"]]}))
    code, out, err = vts(capsys, "camera", "led", "cam1", "on", "--config", path)
    assert code == 0, err
    assert "whether it took is not known" in out and "a no-op on this camera: it cannot switch an LED" in out
    code, out, err = vts(capsys, "camera", "setup", "cam1", "--config", path)
    assert code == 2 and "camera cam1 is of kind replay, which has no parameters" in err, err
    assert "Traceback" not in err


class _ParametersOnly(ReplayCamera):
    """A kind with named parameters but no setup of its own (what a second network camera kind
    may well be): `vts camera setup` needs the Setup role, not parameters alone."""

    def get_params(self, group: str) -> dict[str, str]:
        return {}

    def set_params(self, values) -> None:
        raise AssertionError("setup sent parameters to a kind it cannot set up")


def test_setup_asks_the_setup_role_not_parameters(recording, tmp_path, capsys, monkeypatch):
    """A kind with Parameters but not Setup is refused by `vts camera setup` in one sentence,
    exit 2, before anything is touched (the guard once asked for Parameters and let it through
    to the Axis setup, an AttributeError)."""
    monkeypatch.setitem(CAMERA_KINDS, "replay", f"{__name__}:_ParametersOnly")
    entry = _entries(recording)["replay"]
    assert kind_has(parse_rig({"cameras": [entry]}, "r").cameras[0], Parameters)
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"rig": "roles", "cameras": [entry]}))
    for dry in ([], ["--dry-run"]):
        code, out, err = vts(capsys, "camera", "setup", "cam1", *dry, "--config", path)
        assert code == 2 and "camera cam1 is of kind replay, which has no setup: only Axis" in err, err
        assert "Traceback" not in err


def test_led_command_names_no_port_on_a_camera_without_an_led(recording, tmp_path, capsys):
    """`vts camera led` on an MJPEG camera without an LED (it holds a led_port all the same)
    names no output port: nothing is sent to one."""
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump({"rig": "roles", "cameras": [_entries(recording)["mjpeg"]]}))
    code, out, err = vts(capsys, "camera", "led", "cam2", "on", "--config", path)
    assert code == 0, err
    assert "(no port)" in out and "output port" not in out, out
    assert "a no-op on this camera: it cannot switch an LED" in out
