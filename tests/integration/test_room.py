"""The room as one object (issue 34 §1, docs/decisions/0099-the-room.md): ``Room.open(config)`` on
real peers (two simulated Axis cameras over HTTP on loopback, the trigger box's firmware in the
emulator over a pty): a part is opened only when it is first used; ``close()`` closes what was
opened (the camera's connection, the trigger's serial port) and nothing else; an error in one
part's close does not stop the others; the calibration and mapping come through the one loaders;
a calibration path that names no file is one sentence naming the key and the file, exit 2, from
the CLI; rig.yaml's renamed calibration keys (old names still read, both at once an error)."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
import yaml

from inprocess_cli import vts
from sim_axis_kit import PASSWORD, FakeSource
from vts_hw.config import ConfigError, dump_rig, load_rig
from vts_hw.errors import DataError, DeviceError
from vts_hw.room import Room
from vts_hw.sim_devices.axis_camera import SimAxisCamera
from vts_hw.sim_devices.trigger_box import SimTriggerBox
from vts_hw.vision.registration import RigidTransform


@pytest.fixture(scope="module")
def peers():
    """Two simulated cameras and the trigger box, shared by the module's tests."""
    with (
        SimAxisCamera(FakeSource("cam1"), password=PASSWORD) as c1,
        SimAxisCamera(FakeSource("cam2"), password=PASSWORD) as c2,
        SimTriggerBox() as box,
    ):
        yield c1, c2, box


def _rig(folder, peers, **more) -> dict:
    c1, c2, box = peers
    cams = [
        {"name": n, "host": "127.0.0.1", "port": c.port, "password_env": "VTS_ROOM_TEST_PW"}
        for n, c in (("cam1", c1), ("cam2", c2))
    ]
    return {
        "rig": "room",
        "cameras": cams,
        "trigger": {"backend": "triggerbox", "address": box.port},
        "store": {"url": f"sqlite:///{folder / 'r.sqlite'}"},
        **more,
    }


def _write(folder, data: dict):
    p = folder / "rig.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


@pytest.fixture()
def env(monkeypatch):
    monkeypatch.setenv("VTS_ROOM_TEST_PW", PASSWORD)


def _wait_closed(cam, limit_s: float = 20.0) -> int:
    """The simulated camera's open connections once the client's are gone (the server notices a
    closed socket on its own thread: waited for, not timed)."""
    end = time.monotonic() + limit_s
    while cam.counter("connections") and time.monotonic() < end:
        time.sleep(0.02)
    return cam.counter("connections")


def test_parts_open_when_first_used_and_close_closes_what_was_opened(tmp_path, peers, env):
    c1, c2, box = peers
    requests_before = c2.counter("requests")
    room = Room.open(_write(tmp_path, _rig(tmp_path, peers)))
    assert room.opened() == []  # nothing opened by Room.open
    cam = room.camera("cam1")
    assert room.camera("cam1") is cam and room.opened() == ["camera cam1"]
    assert cam.snapshot().jpeg.startswith(b"\xff\xd8") and c1.counter("connections") >= 1
    gen = room.trigger
    assert gen.status().device and room.opened() == ["camera cam1", "trigger"]
    assert gen._serial.is_open
    assert room.calibration is None and room.mapping is None  # none named: the room still opens
    room.close()
    assert room.opened() == [] and not gen._serial.is_open  # the serial port closed
    assert _wait_closed(c1) == 0  # the camera's connection closed
    assert c2.counter("requests") == requests_before  # cam2 was never opened
    assert not (tmp_path / "r.sqlite").exists()  # nor the store


def test_all_cameras_and_the_store(tmp_path, peers, env):
    with Room.open(_write(tmp_path, _rig(tmp_path, peers))) as room:
        assert [c.name for c in room.cameras] == ["cam1", "cam2"]
        assert room.store.runs() == [] and room.opened() == ["camera cam1", "camera cam2", "store"]
        store = room.store
    assert (tmp_path / "r.sqlite").exists()
    with pytest.raises(RuntimeError, match="is closed"):
        store.runs()  # closed with the room


def test_an_error_closing_one_part_does_not_stop_the_others(tmp_path, peers, env):
    c1, c2, box = peers
    room = Room.open(_write(tmp_path, _rig(tmp_path, peers)))
    cam1, cam2, gen = room.camera("cam1"), room.camera("cam2"), room.trigger
    cam1.snapshot()

    def broken():
        raise DeviceError("camera cam2 would not let go")

    cam2.close = broken
    with pytest.raises(DeviceError, match="cam2 would not let go"):
        room.close()
    assert not gen._serial.is_open and _wait_closed(c1) == 0  # closed before and after the failing one

    # an error on its way out of `with` is never masked by one while closing: said beside it
    room = Room.open(_write(tmp_path, _rig(tmp_path, peers)))
    with pytest.raises(ConfigError, match="no camera named 'cam9'") as err:
        with room:
            room.camera("cam2").close = broken
            room.camera("cam9")
    assert any("cam2 would not let go" in n for n in err.value.__notes__)


def test_close_closes_the_last_opened_first(tmp_path, peers, env):
    """The store opened first (as vts commission and vts qa open it) is closed last, after the
    devices whose results went into it; the trigger before the camera opened before it."""
    closed: list[str] = []
    room = Room.open(_write(tmp_path, _rig(tmp_path, peers)))
    parts = {"store": room.store, "camera cam2": room.camera("cam2"), "trigger": room.trigger}
    for what, part in parts.items():
        part.close = lambda close=part.close, what=what: (closed.append(what), close())[1]
    room.close()
    assert closed == ["trigger", "camera cam2", "store"] and room.opened() == []
    room.close()  # a second close closes nothing again
    assert closed == ["trigger", "camera cam2", "store"]


def test_the_calibration_and_the_mapping_through_the_one_loaders(tmp_path, peers):
    rows = [
        {
            "name": n,
            "K": [[800, 0, 320], [0, 800, 240], [0, 0, 1]],
            "dist": [0, 0, 0, 0, 0],
            "R": np.eye(3).tolist(),
            "t": [i * 100.0, 0, 0],
        }
        for i, n in enumerate(("cam1", "cam2"))
    ]
    (tmp_path / "cameras.json").write_text(json.dumps({"cameras": rows, "unit": "mm"}))
    RigidTransform(np.eye(3), np.array([1.0, 2.0, 3.0])).save(tmp_path / "map.json")
    rig = _rig(tmp_path, peers, calibration={"cameras": "cameras.json", "mapping": "map.json"})
    with Room.open(_write(tmp_path, rig)) as room:
        assert sorted(room.calibration) == ["cam1", "cam2"] and room.calibration is room.calibration
        assert np.allclose(room.mapping.t, [1, 2, 3]) and room.opened() == []  # files, not devices
    (tmp_path / "cameras.json").write_text("{")
    with Room.open(_write(tmp_path, rig)) as room, pytest.raises(DataError, match="not a JSON calibration file"):
        room.calibration  # there but unreadable: exit 3


def test_a_calibration_path_that_names_no_file_is_one_sentence_exit_2(tmp_path, peers, capsys):
    rig = _write(tmp_path, _rig(tmp_path, peers, calibration={"cameras": "gone.json"}))
    with Room.open(rig) as room, pytest.raises(ConfigError) as err:
        room.calibration
    assert str(err.value) == f"{rig}: calibration.cameras names {tmp_path / 'gone.json'}, which does not exist"
    (tmp_path / "a_folder.json").mkdir()
    gone_map = _write(tmp_path, _rig(tmp_path, peers, calibration={"mapping": "a_folder.json"}))
    with Room.open(gone_map) as room, pytest.raises(ConfigError) as map_err:
        room.mapping
    assert (
        str(map_err.value) == f"{gone_map}: calibration.mapping names {tmp_path / 'a_folder.json'}, which is not a file"
    )
    rig = _write(tmp_path, _rig(tmp_path, peers, calibration={"cameras": "gone.json"}))
    (tmp_path / "v.npz").write_bytes(b"")
    code, out, se = vts(
        capsys,
        "calibrate",
        "spect",
        "--from-cameras",
        "--volume",
        tmp_path / "v.npz",
        "--config",
        rig,
        "-o",
        tmp_path / "m.json",
    )
    assert code == 2 and se.strip() == f"vts: {err.value}", se
    assert not (tmp_path / "m.json").exists()


# ---- rig.yaml's calibration keys: new names, the old ones still read -------------------------------

CAMS = [{"name": "cam1", "host": "127.0.0.1"}]


@pytest.mark.parametrize(
    "section",
    [
        {"cameras": "c.json", "mapping": "m.json"},
        {"stereo": "c.json", "spect": "m.json"},
        {"cameras": "c.json", "spect": "m.json"},
    ],
)
def test_calibration_keys_new_and_old_names(tmp_path, section):
    rig = load_rig(_write(tmp_path, {"cameras": CAMS, "calibration": section}))
    assert (rig.calibration.cameras, rig.calibration.mapping) == (tmp_path / "c.json", tmp_path / "m.json")
    written = yaml.safe_load(dump_rig(rig))["calibration"]
    assert written == {"cameras": str(tmp_path / "c.json"), "mapping": str(tmp_path / "m.json")}


@pytest.mark.parametrize(
    "section, new, old",
    [
        ({"cameras": "a.json", "stereo": "b.json"}, "cameras", "stereo"),
        ({"mapping": "a.json", "spect": "b.json"}, "mapping", "spect"),
    ],
)
def test_both_names_of_one_calibration_entry_is_one_error_exit_2(tmp_path, capsys, section, new, old):
    p = _write(tmp_path, {"cameras": CAMS, "calibration": section})
    want = f"{p}: calibration has both {new} and {old} (the old name of {new}); keep only {new}"
    with pytest.raises(ConfigError) as err:
        load_rig(p)
    assert str(err.value) == want
    code, out, se = vts(capsys, "trigger", "status", "--config", p)
    assert code == 2 and se.strip() == f"vts: {want}", se
