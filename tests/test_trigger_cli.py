"""`vts trigger` with the simulated function generator (pyvisa-sim), as a user runs it."""

import subprocess
import sys

import yaml

from vts_hw.drivers.function_generator import SIM_RESOURCE
from vts_hw.drivers.trigger import read_log

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def _rig(tmp_path, **trigger):
    cfg = {"rig": "t", "cameras": [{"name": "cam1", "host": "127.0.0.1"}],
           "trigger": {"backend": "visa", "address": SIM_RESOURCE, "simulated": True, **trigger}}
    p = tmp_path / "rig.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def vts(*args):
    return subprocess.run([*VTS, *args], capture_output=True, text=True, timeout=60)


def test_start_prints_what_the_instrument_confirms(tmp_path):
    rig = _rig(tmp_path, frequency_hz=1.0, duty=0.5, high_v=2.5, low_v=0.0)
    log = tmp_path / "trigger.csv"
    p = vts("trigger", "start", "--config", str(rig), "--log", str(log))
    assert p.returncode == 0, p.stderr
    assert "output ON" in p.stdout and "1 Hz" in p.stdout and "duty 50 %" in p.stdout and "0..2.5 V" in p.stdout
    rows = read_log(log)
    sent = [r["text"] for r in rows if r["kind"] == "cmd"]
    assert any(t.startswith("FREQ") for t in sent) and "OUTP 1" in sent
    assert all(r["host_time"] for r in rows)


def test_what_the_backend_cannot_do_is_one_clear_sentence(tmp_path):
    rig = _rig(tmp_path)
    p = vts("trigger", "pulse", "1", "100", "--config", str(rig), "--log", str(tmp_path / "t.csv"))
    assert p.returncode == 4 and "cannot" in p.stderr.lower() and "Traceback" not in p.stderr
    p = vts("trigger", "fire", "--config", str(rig), "--log", str(tmp_path / "t.csv"))
    assert p.returncode == 4 and "Traceback" not in p.stderr


def test_no_trigger_configured(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(yaml.safe_dump({"cameras": [{"name": "cam1", "host": "127.0.0.1"}]}))
    p = vts("trigger", "status", "--config", str(cfg))
    assert p.returncode == 2 and "backend: none" in p.stderr
    assert not (tmp_path / "trigger.csv").exists()  # nothing written for a device that is not there
