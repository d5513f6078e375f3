"""NaN, inf and nonsense numbers are refused as bad input, naming the option (issue 21, part A 3):
every float option of every command has the one finite type (found by walking the command tree),
and `vts sim up` ends in one sentence with a documented exit code for a bad --rate, a folder
where a rig already runs, and a full disk."""

from __future__ import annotations

import os
import subprocess
import sys

import click
import pytest

from inprocess_cli import vts
from vts_hw.cli import command_tree
from vts_hw.cli.common import FiniteFloat

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def float_options():
    return [
        (path, p) for path, cmd in command_tree() for p in cmd.params if isinstance(p.type, click.types.FloatParamType)
    ]


def test_every_float_option_is_a_finite_float():
    found = float_options()
    assert len(found) >= 14  # --square (2), --seconds, --fps, --rate, --clock-slack, --step-mm ...
    others = [
        f"vts {' '.join(path)} {p.opts[-1]}: {type(p.type).__name__}"
        for path, p in found
        if not isinstance(p.type, FiniteFloat)
    ]
    assert others == []


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e309", "NaN"])
def test_nan_and_inf_are_refused_naming_the_option(value, capsys):
    for path, p in float_options():
        if isinstance(p, click.Argument):
            continue
        opt = p.opts[-1]
        code, out, err = vts(capsys, *path, f"{opt}={value}")  # first: parsed before anything else
        assert code == 2, (path, opt, code, err)
        assert f"Invalid value for '{opt}'" in err or opt in err, err
        assert "not a finite number" in err and "Traceback" not in err, err
        assert out == ""


def test_negative_and_zero_where_a_positive_number_is_meant(capsys):
    cases = [
        ("sim", "up", "--rate=0"),
        ("sim", "up", "--rate=-1"),
        ("sim", "up", "--rate=1e7"),
        ("calibrate", "stereo", "--square=0"),
        ("calibrate", "cameras", "--square=-30"),
        ("demo", "--seconds=-1"),
        ("demo", "--seconds=0"),
        ("sync", "analyze", "--clock-slack=-1"),
        ("camera", "stream", "--fps=0"),
        ("qa", "steps", "--step-mm=0"),
    ]
    for args in cases:
        code, out, err = vts(capsys, *args)
        assert code == 2 and "out of range" in err and args[-1].split("=")[0] in err, (args, err)


def test_sim_up_with_a_bad_rate_starts_nothing(tmp_path, capsys):
    for rate in ("nan", "0", "-1", "inf"):
        code, out, err = vts(capsys, "sim", "up", "--rate", rate, "--detach", "--dir", tmp_path / rate)
        assert code == 2 and "--rate" in err and "Traceback" not in err, err
        assert not (tmp_path / rate).exists()


def test_sim_up_twice_on_one_folder_refuses_and_keeps_the_first(tmp_path, capsys):
    d = str(tmp_path / "sim")
    p = subprocess.run([*VTS, "sim", "up", "--detach", "--dir", d], capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr
    try:
        rig_yaml = (tmp_path / "sim" / "rig.yaml").read_bytes()
        code, out, err = vts(capsys, "sim", "up", "--detach", "--dir", d)  # detached again
        assert code == 2 and "already running" in err and d in err and "Traceback" not in err, err
        p = subprocess.run([*VTS, "sim", "up", "--dir", d], capture_output=True, text=True, timeout=60)  # foreground
        assert p.returncode == 2 and "already running" in p.stderr and d in p.stderr, p.stderr
        assert "Traceback" not in p.stderr and "Error:" not in p.stderr
        assert (tmp_path / "sim" / "rig.yaml").read_bytes() == rig_yaml
    finally:
        p = subprocess.run([*VTS, "sim", "down", "--dir", d], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0 and "stopped" in p.stdout  # the first one was still running, and is stopped


def test_sim_up_onto_a_full_disk_is_exit_3_in_one_sentence(small_disk):
    disk = small_disk(128)
    disk.fill()
    for args in (["--detach"], []):
        d = disk.path / ("det" if args else "fg")
        p = subprocess.run(
            [*VTS, "sim", "up", *args, "--dir", str(d)],
            capture_output=True,
            text=True,
            timeout=90,
            env=dict(os.environ),
        )
        err = p.stderr.strip()
        assert p.returncode == 3, (args, p.returncode, err)
        assert "\n" not in err and "Traceback" not in err and "no space left" in err and str(d) in err, err
    assert disk.files() == {}  # no empty sim.log (or anything else) left on the full disk
