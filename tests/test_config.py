"""rig.yaml validation: a bad file ends in one sentence naming the file, the key and what was expected."""

import textwrap

import pytest

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


@pytest.mark.parametrize("change, key, expected", [
    (("port: 8080", "port: eighty"), "cameras[1].port", "integer"),
    (("port: 8080", "port: 70000"), "cameras[1].port", "less than or equal to 65535"),
    (("resolution: 640x480", "resolution: big"), "cameras[1].resolution", "WIDTHxHEIGHT"),
    (("frequency_hz: 10", "frequency_hz: 5000"), "trigger.frequency_hz", "1000"),
    (("host: 192.0.2.10\n", "host: 192.0.2.10\n    password: hunter2\n"), "cameras[0].password", "not a known key"),
    (("tolerance_high: 1", "tolerance_high: 3"), "tolerances.drift_x_px", "action_low <= tolerance_low"),
    (("drift_x_px:", "drift_z_px:"), "tolerances", "'drift_z_px', which is not a metric with a tolerance"),
    (("name: cam2", "name: cam1"), "(top level)", "unique"),
])
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
