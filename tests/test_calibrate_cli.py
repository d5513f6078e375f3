"""`vts calibrate stereo`: real checkerboard pairs, simulated views against the truth, bad inputs."""

import json
import subprocess
import sys

import pytest

from vts_hw.calibration_io import StereoCalibration


def vts(*args, cwd):
    return subprocess.run([sys.executable, "-m", "vts_hw.cli.__main__", "calibrate", "stereo", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=600)


@pytest.fixture(scope="module")
def boards(shared_data):
    return shared_data / "stereo-checkerboard"


def test_real_pairs_from_a_directory(boards, tmp_path):
    out = tmp_path / "cal.json"
    r = vts(boards, "-o", out, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    calib = StereoCalibration.load(out)
    assert calib.unit == "squares" and len(calib.per_view) + len(calib.skipped) == 13
    assert "RMS reprojection error" in r.stdout and f"stereo {calib.rms_stereo:.3f} px" in r.stdout
    assert f"wrote {out}" in r.stdout
    assert "Change from the previous" not in r.stdout
    # a second run over the existing file reports the change from it
    r = vts(boards, "-o", out, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert f"Change from the previous calibration {out}" in r.stdout
    assert "rotation between cameras changed by 0.0000 deg" in r.stdout


def test_real_pairs_from_files_json_and_previous(boards, tmp_path):
    files = [boards / f"{side}{n:02d}.jpg" for n in (1, 3, 4, 5, 6) for side in ("right", "left")]
    first = tmp_path / "first.json"
    assert vts(boards, "-o", first, cwd=tmp_path).returncode == 0
    r = vts(*files, "--square", "25", "-o", tmp_path / "b.json", "--previous", first, "--json",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert data["unit"] == "mm" and data["square"] == 25.0
    assert [v["name"] for v in data["per_view"]] + list(data["skipped"]) == ["01", "03", "04", "05", "06"]
    assert data["rms_stereo"] > 0 and "sim_truth" not in data
    assert data["change"]["previous"] == str(first) and data["change"]["translation"] is None
    assert StereoCalibration.load(tmp_path / "b.json").square == 25.0


def test_sim_recovers_the_simulated_cameras(tmp_path):
    r = vts("--sim", "--sim-poses", 15, "--json", "-o", tmp_path / "sim.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    truth = data["sim_truth"]
    assert data["unit"] == "mm" and data["square"] == 50.0 and not data["skipped"]
    assert len(data["per_view"]) == 15
    # Measured (seed 0, 15 poses): stereo RMS 0.058 px; focal errors -0.02 / +0.01 % (cam1),
    # +0.50 / +0.53 % (cam2); baseline +2.1 mm (+0.18 %); stereo rotation off by 0.33 deg,
    # with the principal points off by 9-22 px (at an 11 deg field of view the principal point
    # and the rotation trade off against each other: corner noise of 0.06 px alone gives 0.3-0.7 deg).
    assert data["rms_stereo"] < 0.1
    for cam in ("cam1", "cam2"):
        for key in ("fx", "fy"):
            assert abs(truth["cameras"][cam][key]["error_percent"]) < 0.8
        assert abs(truth["cameras"][cam]["cx"]["error"]) < 30
        assert abs(truth["cameras"][cam]["cy"]["error"]) < 30
    assert abs(truth["baseline"]["true"] - 1200.0) < 1.0
    assert abs(truth["baseline"]["error_percent"]) < 0.4
    assert truth["rotation"]["error_deg"] < 0.5
    assert StereoCalibration.load(tmp_path / "sim.json").unit == "mm"


def test_sim_text_output(tmp_path):
    r = vts("--sim", "--sim-poses", 6, "--sim-seed", 2, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "RMS reprojection error" in r.stdout
    assert "Compared with the simulated truth" in r.stdout and "baseline" in r.stdout
    assert (tmp_path / "calibration.json").is_file()


@pytest.mark.parametrize("make_args, words", [
    (lambda p, b: [p], "no leftNN/rightNN image pairs"),
    (lambda p, b: [p / "left01.jpg", p / "right01.jpg"], "no such file"),
    (lambda p, b: [b / "left01.jpg"], "no matching right image"),
    (lambda p, b: [b, "--previous", p / "missing.json"], "cannot read the calibration file"),
])
def test_bad_inputs_end_in_one_line(boards, tmp_path, make_args, words):
    r = vts(*make_args(tmp_path, boards), "-o", tmp_path / "out.json", cwd=tmp_path)
    assert r.returncode == 3
    assert r.stdout == ""
    assert len(r.stderr.strip().splitlines()) == 1 and words in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "out.json").exists()


def test_unrelated_output_file_is_not_overwritten(boards, tmp_path):
    out = tmp_path / "notes.json"
    out.write_text("{}")
    r = vts(boards, "-o", out, cwd=tmp_path)
    assert r.returncode == 3 and "is not a stereo calibration file" in r.stderr
    assert out.read_text() == "{}"


def test_usage_errors(tmp_path, boards):
    assert vts(cwd=tmp_path).returncode == 2
    assert vts("--sim", boards, cwd=tmp_path).returncode == 2
    assert vts(boards, "--pattern", "nine", cwd=tmp_path).returncode == 2
    assert vts(boards, "--unit", "squares", "--square", "30", cwd=tmp_path).returncode == 2
