"""The patient scan scenario (sim_devices/scenarios/patient_scan.py): `vts scan start` in a
subprocess against a simulated rig with a patient, the simulated SPECT counting its heart, and
the truth covering the recording."""

import json

import numpy as np
import pytest

from vts_hw.recording.folder import read_index
from vts_hw.sim_devices.patient import BAND_MARKERS
from vts_hw.sim_devices.patient_rig import PatientOptions
from vts_hw.sim_devices.patient_source import heart_source
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scenarios.patient_scan import patient_scan
from vts_hw.spect.listmode.base import read_listmode
from vts_hw.vision.detect import detect_jpeg

BAND = set(BAND_MARKERS["chest"]) | set(BAND_MARKERS["abdomen"])
SCAN_S = 12.0
# the scan's frames are made ahead first (minutes on a loaded machine): the timeout is a hang detector
pytestmark = pytest.mark.timeout(600)


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("patient-scan")
    rig = SimRig(
        n_cameras=2,
        seed=2,
        trigger="triggerbox",
        patient=PatientOptions(seed=1, moves=1, minutes=1.5, still_s=5.0, move_at_s=(9.0,)),
    ).start()
    try:
        rig_yaml, _ = rig.write(tmp / "rig")
        run = patient_scan(rig, rig_yaml, tmp / "scan", SCAN_S, truth_dir=tmp / "truth")
    finally:
        rig.stop()
    return run, rig, tmp


def test_the_recording_is_complete_and_the_truth_covers_it(scan):
    run, rig, tmp = scan
    m = json.loads((run.session / "manifest.json").read_text())
    assert m["status"] == "complete" and m["trigger"]["fired"]
    assert run.fire_host == pytest.approx(m["trigger"]["fire_time"])
    for name in ("cam1", "cam2"):
        rows = read_index(run.session / f"{name}.index.csv")
        assert len(rows) >= 0.9 * 25 * SCAN_S, name
    a, b = run.window  # the recording covers the scan: from before the fire to its end
    assert a <= run.fire_host and b >= run.fire_host + SCAN_S - 0.2 and b - a <= SCAN_S + 10.0
    t0 = run.patient.breathing.t0
    assert t0 < a and b < t0 + run.patient.breathing.duration_s  # the plan covers the scan
    (move,) = run.moves_in_window()  # the move happened while recording
    assert move.t_start == pytest.approx(t0 + 9.0) and move.t_end < b
    assert not np.allclose(run.patient.six_dof(a), run.patient.six_dof(b))
    assert not any(p.name.startswith("patient") for p in run.session.iterdir())  # no truth in the session
    assert [p.name for p in run.truth_files] == ["patient.json", "patient_motion.csv"]
    rows = (tmp / "truth" / "patient_motion.csv").read_text().splitlines()
    assert len(rows) - 1 == pytest.approx((b - a + 2.0) * 25, abs=2)


def test_the_recorded_frames_show_the_patient_where_the_truth_says(scan):
    run, rig, _ = scan
    for name in ("cam1", "cam2"):
        rows = read_index(run.session / f"{name}.index.csv")
        data = (run.session / f"{name}.mjpeg").read_bytes()
        clock = rig.scene.clocks[name]
        for row in (rows[3], rows[len(rows) // 2], rows[-3]):
            blobs = np.array([(b.x, b.y) for b in detect_jpeg(data[row.offset : row.offset + row.length]).blobs])
            t = clock.host_time(row.camera_time) + 0.005  # the stamp is truncated to 10 ms
            truth = {k: np.array((u, v)) for k, u, v in rig.scene.truth(name, t) if k in BAND}
            assert set(truth) == BAND
            for k, uv in truth.items():
                assert np.linalg.norm(blobs - uv, axis=1).min() < 0.6, (name, row.frame, k)


def test_the_listmode_counts_the_patients_heart(scan):
    run, rig, _ = scan
    assert run.listmode is not None and run.listmode.parent == run.session.parent
    assert run.spect.sources[0]["kind"] == "patient point source"
    lm = read_listmode(run.listmode)
    assert lm.n_events > 0.8 * 3000 * (SCAN_S - 3.0)
    host = run.spect.host_time(lm.t)
    heart = heart_source(run.patient)
    zs = np.array([heart.at(float(t))[2] for t in host[::50]])
    assert float(np.mean(lm.z)) == pytest.approx(float(np.mean(zs)), abs=0.5)
