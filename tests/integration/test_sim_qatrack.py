"""`vts sim up --qatrack`: the simulated QATrack+ beside the simulated rig, named in the rig.yaml it
writes (url, unit, time_zone, lists; the token only in sim.env), so that `vts qa push` can be
tried from the QATrack+ page of the documentation (docs/operate/qatrack.md; issue 21, part A 5)."""

from __future__ import annotations

import os

import pytest
import yaml

from inprocess_cli import vts
from vts_hw.config import load_rig
from vts_hw.sim_devices.qatrack_rig import TOKEN_ENV
from vts_hw.sim_devices.rig import SimRig, load_env_file


def test_sim_qatrack_in_rig_yaml_and_a_push_from_the_readme(tmp_path, capsys, monkeypatch):
    with SimRig(n_cameras=2, seed=2, qatrack=True) as rig:
        rig_yaml, env_file = rig.write(tmp_path / "sim")
        text = rig_yaml.read_text()
        env = load_env_file(env_file)
        token = rig.qatrack_site.token
        assert token not in text and env[TOKEN_ENV] == token  # the token: in sim.env only
        q = yaml.safe_load(text)["qatrack"]
        assert q["url"] == rig.qatrack_site.url and q["time_zone"] and q["token_env"] == TOKEN_ENV
        cfg = load_rig(rig_yaml)
        assert cfg.qatrack.unit in rig.qatrack_site.site.unit_names and cfg.qatrack.time_zone == q["time_zone"]
        for k, v in env.items():
            monkeypatch.setenv(k, v)
        monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
        assert os.environ["VTS_CONFIG"] == str(rig_yaml.resolve())
        assert vts(capsys, "qa", "drift", "--set-baseline", "--frames", "2")[0] == 0
        code, out, err = vts(capsys, "qa", "daily", "--frames", "2")
        assert code == 0, out + err
        code, out, err = vts(capsys, "qa", "push")
        assert code == 0 and "1 of 1 run sent" in out, out + err
        assert len(rig.qatrack_site.instances) == 1
        inst = rig.qatrack_site.instances[0]
        assert {"cam1_dx", "cam2_dy", "cam2_missing"} <= set(inst["tests"])
        code, out, err = vts(capsys, "qa", "push")  # never twice
        assert code == 0 and len(rig.qatrack_site.instances) == 1
    assert rig.qatrack_site is None  # stopped with the rig


def test_without_the_flag_there_is_no_qatrack_section(tmp_path):
    with SimRig(n_cameras=2, seed=2) as rig:
        rig_yaml, env_file = rig.write(tmp_path / "sim")
    assert "qatrack" not in yaml.safe_load(rig_yaml.read_text())
    assert TOKEN_ENV not in load_env_file(env_file)


@pytest.mark.parametrize("flag", ["--qatrack"])
def test_the_flag_is_documented(flag, capsys):
    code, out, _ = vts(capsys, "sim", "up", "--help")
    assert code == 0 and flag in out and "vts qa push" in out
