"""rig.yaml validation: a bad file ends in one sentence naming the file, the key and what was expected."""

import textwrap

import pytest
import yaml

from vts_hw.config import ConfigError, dump_rig, load_rig, parse_rig

GOOD = textwrap.dedent("""\
    rig: room-1
    cameras:
      - name: cam1
        host: 192.0.2.10
        password_env: VTS_CAM1_PASSWORD
      - name: cam2
        host: 192.0.2.11
        port: 8080
        resolution: 640x480
    trigger:
      backend: triggerbox
      address: /dev/ttyACM0
      frequency_hz: 10
    tolerances:
      drift_x_px:
        action_low: -2
        tolerance_low: -1
        tolerance_high: 1
        action_high: 2
        unit: px
    """)


def _write(tmp_path, text):
    p = tmp_path / "rig.yaml"
    p.write_text(text)
    return p


def test_good_file(tmp_path, monkeypatch):
    rig = load_rig(_write(tmp_path, GOOD))
    assert [c.name for c in rig.cameras] == ["cam1", "cam2"]
    assert rig.camera("cam2").base_url == "http://192.0.2.11:8080"
    assert rig.camera("cam1").resolution == (640, 480)
    monkeypatch.setenv("VTS_CAM1_PASSWORD", "s3cret")
    assert rig.camera("cam1").password() == "s3cret"
    assert rig.camera("cam2").password() is None
    assert parse_rig(__import__("yaml").safe_load(dump_rig(rig))).model_dump() == rig.model_dump()
    assert rig.digest and len(rig.digest) == 64


@pytest.mark.parametrize(
    "change, key, expected",
    [
        (("port: 8080", "port: eighty"), "cameras[1].port", "integer"),
        (("port: 8080", "port: 70000"), "cameras[1].port", "less than or equal to 65535"),
        (("resolution: 640x480", "resolution: big"), "cameras[1].resolution", "WIDTHxHEIGHT"),
        (("frequency_hz: 10", "frequency_hz: 5000"), "trigger.frequency_hz", "1000"),
        (("host: 192.0.2.10\n", "host: 192.0.2.10\n    password: hunter2\n"), "cameras[0].password", "not a known key"),
        (("tolerance_high: 1", "tolerance_high: 3"), "tolerances.drift_x_px", "action_low <= tolerance_low"),
        (("drift_x_px:", "drift_z_px:"), "tolerances", "'drift_z_px', which is not a metric with a tolerance"),
        (("name: cam2", "name: cam1"), "(top level)", "unique"),
        # a host with another URL part in it: its credentials would go to another host
        (("host: 192.0.2.10\n", "host: evil.example/x\n"), "cameras[0].host", "not a host name or address alone"),
        (("host: 192.0.2.10\n", "host: 192.0.2.10@evil.example\n"), "cameras[0].host", "not a host name"),
        (("host: 192.0.2.10\n", "host: '192.0.2.10:81'\n"), "cameras[0].host", "the port is port:"),
        (("host: 192.0.2.10\n", "host: 'cam?x=1'\n"), "cameras[0].host", "not a host name"),
        (("rig: room-1\n", "rig: room-1\nmotion:\n  blind_alert_s: 0\n"), "motion.blind_alert_s", "greater than 0"),
        (
            ("rig: room-1\n", "rig: room-1\nmotion:\n  blind_max_share: 1.5\n"),
            "motion.blind_max_share",
            "less than or equal to 1",
        ),
    ],
)
def test_bad_values_name_file_key_and_expectation(tmp_path, change, key, expected):
    p = _write(tmp_path, GOOD.replace(*change))
    with pytest.raises(ConfigError) as ei:
        load_rig(p)
    msg = str(ei.value)
    assert msg.startswith(str(p) + ":")
    assert key in msg and expected in msg
    assert "\n" not in msg
    assert "hunter2" not in msg or "password" in key  # the value is echoed only for the key at fault


def test_password_value_is_never_echoed(tmp_path):
    p = _write(tmp_path, GOOD.replace("host: 192.0.2.10\n", "host: 192.0.2.10\n    password: hunter2\n"))
    with pytest.raises(ConfigError) as ei:
        load_rig(p)
    assert "hunter2" not in str(ei.value)


def test_missing_and_unparsable_files(tmp_path):
    with pytest.raises(ConfigError, match="no such config file"):
        load_rig(tmp_path / "nope.yaml")
    with pytest.raises(ConfigError, match=r"not valid YAML at line \d"):
        load_rig(_write(tmp_path, "cameras:\n  - name: [unclosed\n"))
    with pytest.raises(ConfigError, match="cameras is required"):
        load_rig(_write(tmp_path, "rig: x\n"))


def test_unset_password_variable_is_named(tmp_path, monkeypatch):
    monkeypatch.delenv("VTS_CAM1_PASSWORD", raising=False)
    rig = load_rig(_write(tmp_path, GOOD))
    with pytest.raises(ConfigError, match="VTS_CAM1_PASSWORD"):
        rig.camera("cam1").password()
    with pytest.raises(ConfigError, match="no camera named 'cam9'"):
        rig.camera("cam9")


# ---- files that are not YAML text at all (found by bench/fuzz.py): one sentence, never a traceback


def _write_bytes(tmp_path, data: bytes):
    p = tmp_path / "rig.yaml"
    p.write_bytes(data)
    return p


@pytest.mark.parametrize(
    "data, expected",
    [
        (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", r"not a YAML text file \(a NUL byte at byte 8"),
        (
            "rig: x\n".encode("utf-16"),
            r"not a YAML text file \(a NUL byte at byte \d+: a binary file, or text saved as UTF-16\)",
        ),
        (b"rig: caf\xe9\n", r"not UTF-8 text \(byte 8 cannot be decoded\)"),
    ],
)
def test_a_binary_or_non_utf8_file(tmp_path, data, expected):
    p = _write_bytes(tmp_path, data)
    with pytest.raises(ConfigError, match=expected) as ei:
        load_rig(p)
    assert str(ei.value).startswith(f"{p}: ") and "\n" not in str(ei.value)


def test_yaml_bombs_are_refused_before_they_expand(tmp_path):
    laughs = 'a: &a ["x","x","x","x","x","x","x","x","x","x"]\n' + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [" + ",".join([f"*{chr(97 + i)}"] * 10) + "]\n" for i in range(9)
    )
    merges = "a: &a {x: 1, y: 2, z: 3}\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} {{<<: [" + ",".join([f"*{chr(97 + i)}"] * 3) + "]}\n" for i in range(20)
    )  # 3**20 keys once merged
    for text in (laughs, merges):
        with pytest.raises(ConfigError, match=r"aliases \(\*name\) expand to more than 100,000 values"):
            load_rig(_write(tmp_path, text))


def test_deep_nesting_and_values_yaml_cannot_build(tmp_path):
    with pytest.raises(ConfigError, match="nested more than 32 levels deep at line 2"):
        load_rig(_write(tmp_path, "rig: x\ncameras: " + "[" * 2000 + "]" * 2000 + "\n"))
    with pytest.raises(ConfigError, match=r"not valid YAML \(a value cannot be read: day is out of range"):
        load_rig(_write(tmp_path, "rig: x\nrecordings_dir: 2024-02-30\n"))
    with pytest.raises(ConfigError, match=r"not valid YAML at line 1 \(could not determine a constructor"):
        load_rig(_write(tmp_path, "cameras: !!python/object/apply:os.system [echo]\n"))


def test_a_document_that_is_not_a_mapping(tmp_path):
    for text, got in (("", "an empty document"), ("- a\n", "a list"), ("cam1\n", "a single string")):
        with pytest.raises(ConfigError, match=f"expected a mapping .* at the top level, got {got}$"):
            load_rig(_write(tmp_path, text))


def test_vts_with_a_binary_rig_yaml_is_one_sentence_and_exit_2(tmp_path, axis_frames):
    """`vts qa daily --config FILE` where FILE is a JPEG: as a user runs it."""
    import subprocess
    import sys

    p = tmp_path / "rig.yaml"
    p.write_bytes((axis_frames / "tst.jpg").read_bytes())
    r = subprocess.run(
        [sys.executable, "-m", "vts_hw.cli.__main__", "qa", "daily", "--config", str(p)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2
    assert r.stderr.strip() == (
        f"vts: {p}: not a YAML text file (a NUL byte at byte 4: a binary file, or text saved as UTF-16)"
    )


def test_a_file_too_large_to_be_a_rig_config(tmp_path):
    p = _write(tmp_path, "rig: x\n" + "#" * (1 << 20) + "\n")
    with pytest.raises(ConfigError, match=r"larger than 1 MB, so not a rig config file$"):
        load_rig(p)


def test_a_relative_calibration_path_is_the_file_beside_rig_yaml_from_any_folder(tmp_path, monkeypatch):
    """Every command reads rig.yaml through load_rig: a relative calibration entry is the file
    beside rig.yaml whatever the working folder (camera aim, the step test and the live scan
    once took it from the working folder, sync, motion and the console from rig.yaml's)."""
    room = tmp_path / "room"
    room.mkdir()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    absolute = tmp_path / "kept" / "spect.json"
    p = _write(room, GOOD + f"calibration:\n  stereo: calib/cameras.json\n  spect: {absolute}\n")
    monkeypatch.chdir(elsewhere)
    rig = load_rig(p)
    assert rig.calibration.cameras == room / "calib" / "cameras.json"
    assert rig.calibration.mapping == absolute
    monkeypatch.chdir(tmp_path)  # rig.yaml named relative to the working folder
    rig = load_rig("room/rig.yaml")
    assert rig.calibration.cameras.resolve() == (room / "calib" / "cameras.json").resolve()
    data = yaml.safe_load(GOOD + "calibration:\n  stereo: calib/cameras.json\n")
    assert parse_rig(data, "x").calibration.cameras.as_posix() == "calib/cameras.json"  # not read from a file
