"""The short run of bench/fuzz.py: every parser of outside bytes fed 2,000 coverage-guided
inputs (the benchmark feeds 100,000); any exception other than the project's typed errors is
a crash, and there must be none. The bench is run as a user runs it, and its table read."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

FUZZ = Path(__file__).resolve().parents[2] / "bench" / "fuzz.py"
TARGETS = [
    "mjpeg",
    "axis_jpeg",
    "recording_index",
    "manifest",
    "listmode",
    "interfile",
    "dicom",
    "npz",
    "calibration",
    "camera_calibration",
    "mapping",
    "rig_yaml",
    # the devices' replies, and the files a user may hand back
    "axis_vapix",
    "qatrack",
    "trigger_box",
    "function_generator",
    "trigger_log",
    "spect_points",
    "tracks",
    "step_positions",
    "unsaved",
    "listmode_failures",
]
ROW = re.compile(r"^(\w+)\s+(\d+)\s+(\d+)\s+(\d+)\s+(\d+)\s+([\d.]+)$", re.M)


def fuzz(tmp_path, *args, timeout=900):
    p = subprocess.run(
        [sys.executable, str(FUZZ), "--work", str(tmp_path / "work"), "--crashes", str(tmp_path / "crashes"), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
    )
    rows = {m[0]: tuple(int(x) for x in m[1:5]) for m in ROW.findall(p.stdout) if m[0] != "total"}
    return p, rows


@pytest.mark.timeout(900)
def test_every_parser_survives_2000_fuzzed_inputs_with_typed_errors_only(tmp_path, axis_frames):
    p, rows = fuzz(tmp_path, "--runs", "2000", "--frames", str(axis_frames))
    assert "engine atheris" in p.stdout  # the coverage-guided fuzzer, installed by the dev extra
    assert sorted(rows) == sorted(TARGETS), p.stdout + p.stderr
    for name, (inputs, typed, sites, crashes) in rows.items():
        assert inputs >= 2000, f"{name} ran {inputs} inputs"
        assert typed > 0, f"{name}: no input was answered with a typed error: the fuzzer did not reach it"
        assert (sites, crashes) == (0, 0), f"{name} crashed:\n{p.stdout}"
    assert p.returncode == 0
    assert not (tmp_path / "crashes").exists()


@pytest.mark.timeout(300)
def test_the_hypothesis_fallback_runs_the_same_targets(tmp_path, axis_frames):
    p, rows = fuzz(
        tmp_path, "--engine", "hypothesis", "--runs", "300", "--only", "manifest,rig_yaml", "--frames", str(axis_frames)
    )
    assert "engine hypothesis" in p.stdout
    assert sorted(rows) == ["manifest", "rig_yaml"], p.stdout + p.stderr
    for inputs, typed, sites, crashes in rows.values():
        assert inputs >= 300 and typed > 0 and (sites, crashes) == (0, 0), p.stdout
    assert p.returncode == 0
