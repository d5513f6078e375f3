"""`vts --config FILE COMMAND`: the room's file given before the command's name, as a newcomer
tried it (issue 34 §4: it was "No such option"). A command's own --config wins over it, it wins
over $VTS_CONFIG, and a command that reads no rig.yaml refuses it rather than leave it unused."""

from __future__ import annotations

import pytest

from inprocess_cli import vts


def _rig(path, camera):
    path.write_text(f"rig: {camera}-room\ncameras:\n  - name: {camera}\n    host: 127.0.0.1\n    port: 9\n")
    return path


@pytest.fixture
def rigs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("VTS_CONFIG", raising=False)
    return _rig(tmp_path / "a.yaml", "cama"), _rig(tmp_path / "b.yaml", "camb")


def test_the_global_config_names_the_room(rigs, capsys):
    a, _ = rigs
    code, out, err = vts(capsys, "--config", a, "qa", "daily", "--dry-run")
    assert code == 0, err
    assert "cama: ask http://127.0.0.1:9" in out


def test_the_commands_own_config_wins_and_the_global_one_wins_over_the_environment(rigs, capsys, monkeypatch):
    a, b = rigs
    code, out, err = vts(capsys, "--config", a, "qa", "daily", "--config", b, "--dry-run")
    assert code == 0 and "camb:" in out and "cama:" not in out, err
    monkeypatch.setenv("VTS_CONFIG", str(b))
    code, out, err = vts(capsys, "--config", a, "qa", "daily", "--dry-run")
    assert code == 0 and "cama:" in out and "camb:" not in out, err


def test_a_missing_file_and_a_command_that_reads_no_rig_are_one_sentence(rigs, capsys):
    a, _ = rigs
    code, out, err = vts(capsys, "--config", "nope.yaml", "qa", "daily", "--dry-run")
    assert code == 2 and err.strip() == "vts: nope.yaml: no such config file (give --config or set VTS_CONFIG)"
    code, out, err = vts(capsys, "--config", a, "sim", "up", "--dir", "sim")
    assert code == 2 and err.strip() == "vts: vts --config: `vts sim` reads no rig.yaml; leave --config out"
    assert not (a.parent / "sim").exists()
