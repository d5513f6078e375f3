"""The simulated patient on the simulated rig (`vts sim up --patient`): seen through the real
Axis driver over HTTP on 127.0.0.1, its truth in DIR/truth, the SPECT counting its heart."""

import csv
import json
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import vts_hw.cli.sim  # noqa: F401  (registers `vts sim`)
from vts_hw.cli import cli
from vts_hw.drivers.registry import open_camera
from vts_hw.sim_devices.patient import BAND_MARKERS, BodyMove, add_patient
from vts_hw.sim_devices.patient_rig import PatientOptions
from vts_hw.sim_devices.patient_source import heart_source
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scene import Scene
from vts_hw.sim_devices.spect_listmode import SimSpectSettings, TriggerEdges, write_sim_listmode
from vts_hw.spect.listmode.base import read_listmode
from vts_hw.vision.detect import detect_jpeg

T0 = 1_700_000_000.0
BAND = set(BAND_MARKERS["chest"]) | set(BAND_MARKERS["abdomen"])


def test_a_snapshot_through_the_driver_shows_the_eight_band_markers():
    with SimRig(n_cameras=2, seed=1, patient=PatientOptions(seed=3, moves=1, minutes=1.0)) as rig, rig.env():
        assert rig.patient is not None and rig.scene.bodies["patient"] is rig.patient
        for name in ("cam1", "cam2"):
            with open_camera(rig.config().camera(name)) as cam:
                cam.led_on()
                frame = cam.snapshot()
            blobs = np.array([(b.x, b.y) for b in detect_jpeg(frame.jpeg).blobs])
            # the instant the frame shows: its camera stamp (10 ms, truncated) back on host time
            clock = rig.scene.clocks[name]
            t = clock.host_time(frame.camera_time) + 0.005
            truth = {m: np.array((u, v)) for m, u, v in rig.scene.truth(name, t) if m in BAND}
            assert set(truth) == BAND, name
            for m, uv in truth.items():
                d = np.linalg.norm(blobs - uv, axis=1)
                assert d.min() < 0.5, (name, m, d.min())
            assert len(blobs) == len(rig.scene.truth(name, t))  # the wall markers the torso leaves in view


def test_the_listmode_source_follows_the_body(tmp_path):
    """A body move of 30 mm along the table shifts the mean axial position of the heart's
    counts by that much; counts before the move sit where the heart was."""
    scene = Scene.reference(seed=0, start_epoch=T0)
    patient = add_patient(
        scene,
        T0,
        60.0,
        seed=2,
        breathing=True,
        moves=[BodyMove(T0 + 10.0, T0 + 10.8, (0.0, 0.0, 0.0), (0.0, 0.0, 30.0))],
    )
    heart = heart_source(patient, rate_cps=4000.0)
    rising = T0 + 0.5 + np.arange(0, 20, 0.5)
    trig = TriggerEdges(rising, rising + 0.25, start_pulse=T0 + 0.5, source="by hand")
    settings = SimSpectSettings(start_delay_s=0.1, clock_offset_s=0.0, clock_skew_ppm=0.0, stop_s=100.0)
    truth = write_sim_listmode(tmp_path / "heart.vtslm", scene, [heart], trig, 18.0, settings, seed=4)
    lm = read_listmode(tmp_path / "heart.vtslm")
    host = truth.host_time(lm.t)
    before, after = lm.z[host < T0 + 9.5], lm.z[host > T0 + 11.5]
    assert before.size > 20000 and after.size > 20000
    assert float(np.mean(before)) == pytest.approx(heart.at(T0 + 5.0)[2], abs=1.0)
    assert float(np.mean(after) - np.mean(before)) == pytest.approx(30.0, abs=1.0)
    assert truth.sources[0]["kind"] == "patient point source"
    assert truth.sources[0]["moves"][0]["translation_mm"] == [0.0, 0.0, 30.0]


def test_the_heart_moves_with_body_turns_and_a_little_with_breathing():
    scene = Scene.reference(seed=0, start_epoch=T0)
    p = add_patient(scene, T0, 60.0, seed=5, moves=[BodyMove(T0 + 20, T0 + 21, (0.0, 6.0, 0.0), (0, 0, 0))])
    h = heart_source(p)
    for t in (T0 + 3.0, T0 + 30.0):
        R, tr = p.body_transform(t)
        b = float(p.breathing.value(t))
        rest = p.placement + np.array(h.point_mm)
        assert np.allclose(h.at(t), R @ (rest + b * np.array(h.breath_mm)) + tr)
    assert 0 < h.breath_mm[1] < h.breath_mm[2]  # more head-foot than anterior-posterior
    times = T0 + np.linspace(19.0, 23.0, 401)
    exact = np.array([h.at(float(t)) for t in times])
    assert np.abs(h.positions(scene, times) - exact).max() < 0.05


def test_sim_up_patient_writes_the_truth_beside_rig_yaml(tmp_path):
    d = tmp_path / "sim"
    up = subprocess.run(
        [
            sys.executable,
            "-m",
            "vts_hw.cli.__main__",
            "sim",
            "up",
            "--patient",
            "--patient-seed",
            "4",
            "--patient-minutes",
            "1",
            "--patient-moves",
            "2",
            "--detach",
            "--dir",
            str(d),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    try:
        assert up.returncode == 0, up.stderr
        meta = json.loads((d / "truth" / "patient.json").read_text())
        assert len(meta["moves"]) == 2 and meta["bands"]["chest"] == list(BAND_MARKERS["chest"])
        with open(d / "truth" / "patient_motion.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        assert len(rows) == 60 * 25
        t = np.array([float(r["t"]) for r in rows])
        assert np.allclose(np.diff(t), 0.04, atol=1.5e-3)
        assert meta["moves"][0]["t_start"] > t[0] + 15.0 and meta["moves"][-1]["t_end"] < t[-1]
        assert "truth" not in (d / "rig.yaml").read_text()  # nothing a procedure reads points at it
    finally:
        subprocess.run(
            [sys.executable, "-m", "vts_hw.cli.__main__", "sim", "down", "--dir", str(d)],
            capture_output=True,
            timeout=60,
        )


@pytest.mark.parametrize(
    "args, words",
    [
        (["--patient-moves", "3"], "--patient-moves needs --patient"),
        (["--no-breathing", "--patient-seed", "2"], "--patient-seed, --no-breathing needs --patient"),
        (["--patient", "--patient-minutes", "0.2", "--patient-moves", "2"], "too short for 2 body moves"),
    ],
)
def test_bad_patient_options_are_one_line_and_exit_2(args, words):
    res = CliRunner().invoke(cli, ["sim", "up", *args])
    assert res.exit_code == 2
    assert words in res.output and "Traceback" not in res.output


def test_patient_options_travel_to_the_detached_rig_and_are_checked():
    o = PatientOptions(seed=7, moves=2, minutes=1.5, breathing=False, still_s=4.0, creep_mm=2.5, move_at_s=(6.0, 20.5))
    assert PatientOptions.from_arg(o.to_arg()) == o
    assert PatientOptions.from_arg(PatientOptions().to_arg()) == PatientOptions()
    scene = Scene.reference(seed=0, start_epoch=T0)
    from vts_hw.sim_devices.patient_rig import put_patient

    p = put_patient(scene, o, T0)
    assert [m.t_start - T0 for m in p.motion.moves] == pytest.approx([6.0, 20.5])
    assert not p.breathing.enabled and len(p.motion.creeps) == 1
    for bad, words in (
        (PatientOptions(moves=2, move_at_s=(5.0,)), "one start time per body move"),
        (PatientOptions(moves=2, move_at_s=(9.0, 5.0)), "in order"),
        (PatientOptions(moves=3, minutes=0.5), "too short for 3 body moves"),
        (PatientOptions(moves=-1), "0 or more"),
    ):
        with pytest.raises(ValueError, match=words):
            put_patient(scene, bad, T0)


def test_with_a_patient_the_simulated_spect_counts_its_heart_not_a_source_marker(tmp_path):
    from vts_hw.sim_devices.spect_follower import SpectFollower

    with_patient = SimRig(n_cameras=2, trigger="triggerbox", patient=PatientOptions(minutes=1.0))
    heart = heart_source(with_patient.patient)
    follower = SpectFollower(with_patient, tmp_path / "spect", sources=[heart], log=lambda m: None)
    assert follower.sources == [heart] and follower.marker is None
    assert list(with_patient.scene.bodies) == ["patient"]  # no source marker on the table
    plain = SimRig(n_cameras=2, trigger="triggerbox")
    assert SpectFollower(plain, tmp_path / "spect2", log=lambda m: None).marker is not None
    assert "source" in plain.scene.bodies
