"""End to end: a rendered recording of the simulated patient (2 cameras, breathing, one body
move) -> `vts motion analyze` (processing, analysis, HTML report, exports, the results store,
exit status) and `vts recording process`; scored against the patient's truth."""

import json
import subprocess
import sys

import numpy as np
import pytest

from vts_hw.sim_devices.patient import BodyMove
from vts_hw.sim_devices.recording_sim import simulate_recording
from vts_hw.store import ResultsStore
from vts_hw.tolerance import DEFAULT_TOLERANCES, worst
from vts_hw.tracking.tracks import Tracks
from vts_hw.vision.registration import RigidTransform

# rendering the recording (no real time) takes minutes on a loaded machine: the timeout is a hang detector
pytestmark = pytest.mark.timeout(600)
SEED = 0
START = 1_790_000_000.0 + 1000.0 * SEED + 5.0  # simulate_recording's default start
MOVE = BodyMove(START + 12.0, START + 12.8, (0.3, 0.2, 0.7), (1.0, 2.0, 1.0))


def _vts(*args, cwd=None):
    return subprocess.run(
        [sys.executable, "-m", "vts_hw.cli", *map(str, args)], capture_output=True, text=True, cwd=cwd, timeout=600
    )


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("motion_e2e")
    sim = simulate_recording(tmp / "session", duration_s=24.0, seed=SEED, patient={"moves": [MOVE]})
    cams = [
        {"name": n, **{k: np.asarray(getattr(c, k)).tolist() for k in ("K", "dist", "R", "t")}}
        for n, c in ((n, sim.scene.camera_at(n, START)) for n in sim.cameras)
    ]
    (tmp / "cameras.json").write_text(json.dumps({"unit": "mm", "cameras": cams}))
    RigidTransform.identity().save(tmp / "mapping.json")  # the true cameras are in the SPECT frame
    (tmp / "rig.yaml").write_text(
        f"rig: sim\ncameras:\n  - name: cam1\n    host: 127.0.0.1\n"
        f"results:\n  url: sqlite:///{tmp / 'results.sqlite'}\n"
        f"motion:\n  state_mm: 2.0\n  state_deg: 1.0\n"
    )
    return sim, tmp


def test_motion_analyze_end_to_end(session):
    sim, tmp = session
    out = _vts(
        "motion",
        "analyze",
        tmp / "session",
        "--calibration",
        tmp / "cameras.json",
        "--mapping",
        tmp / "mapping.json",
        "--config",
        tmp / "rig.yaml",
        "-o",
        tmp / "report.html",
        "--export",
        tmp / "export",
        "--workers",
        "2",
        "--json",
    )
    assert out.returncode in (0, 10, 20), out.stderr
    data = json.loads(out.stdout)
    # the state the true motion deserves, by the default windows (the rig.yaml sets none)
    R, T = sim.patient.body_transform(START + 20.0)
    c = np.mean([m.center for m in sim.patient.markers_at(START, np.zeros(3))], axis=0)
    true_mm = float(np.linalg.norm(R @ c + T - c))
    true_deg = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
    assert data["summary"]["motion_body_max_mm"] == pytest.approx(true_mm, abs=0.3)
    assert data["summary"]["motion_body_max_deg"] == pytest.approx(true_deg, abs=0.2)
    want = worst(
        [
            DEFAULT_TOLERANCES["motion_body_max_mm"].state(true_mm),
            DEFAULT_TOLERANCES["motion_body_max_deg"].state(true_deg),
        ]
    )
    assert (
        data["summary"]["state"] == str(want) and out.returncode == {"OK": 0, "TOLERANCE": 10, "ACTION": 20}[str(want)]
    )
    assert "host clock" in data["clock"] and data["frame"]["name"] == "SPECT frame"
    assert (
        len(data["events"]) == 1 and abs(data["events"][0]["t_start"] - (MOVE.t_start - sim.exposure["cam1"][0])) < 0.5
    )
    assert len(data["states"]) == 2
    truth = sim.patient.six_dof(START + 20.0)
    assert np.allclose(data["states"][1]["six_dof"][:3], truth[:3], atol=0.3)
    assert np.allclose(data["states"][1]["six_dof"][3:], truth[3:], atol=0.2)
    patient = [m for m in data["markers"] if m["patient"]]
    assert len(patient) >= 6 and all(set(m["points_by_camera"]) == {"cam1", "cam2"} for m in patient)
    html = (tmp / "report.html").read_text()
    assert "data:image/png;base64," in html and "TOLERANCE" in html and "host clock" in html
    names = {p.rsplit("/", 1)[-1] for p in data["export"]}
    assert {"motion_6dof.csv", "motion_6dof.json", "subsets.json", "trajectories.csv"} <= names
    # no list-mode: host-clock seconds, which CASToR would take for list-mode seconds -- no CASToR file
    assert not (tmp / "export" / "castor_motion.dyn").exists() and "castor_motion.dyn" not in names
    assert len(data["export_notes"]) == 2 and data["export_notes"][0].startswith(
        "CASToR files not written: the times are host-clock seconds"
    )
    assert data["export_notes"][1].startswith("YRT-PET LOR motion file not written: the times are host-clock")
    six = json.loads((tmp / "export" / "motion_6dof.json").read_text())
    assert "host clock" in six["clock"] and six["castor"]["written"] is False
    assert data["stored"]["run_id"] is not None
    with ResultsStore(f"sqlite:///{tmp / 'results.sqlite'}") as store:
        assert len(store.runs(procedure="motion")) == 1


def test_motion_pose_against_the_truth(session):
    from vts_hw.procedures.motion import MotionAnalysis

    sim, tmp = session
    a = MotionAnalysis(tmp / "session", None, tmp / "cameras.json", tmp / "mapping.json", workers=2).analyze()
    r = a.result
    six = r.pose.six_dof()
    true = np.array([sim.patient.six_dof(float(x)) for x in r.pose.t])
    sel = r.pose.valid & ~r.moving
    err = six[sel] - true[sel]
    assert np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1))) < 0.3
    assert np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1))) < 0.2
    b = sim.patient.breathing.value(r.pose.t)
    assert np.corrcoef(r.respiration.amplitude[r.pose.valid], b[r.pose.valid])[0, 1] > 0.98


def test_recording_process_writes_the_tracks(session):
    _, tmp = session
    out = _vts(
        "recording",
        "process",
        tmp / "session",
        "--calibration",
        tmp / "cameras.json",
        "-o",
        tmp / "tracks",
        "--workers",
        "2",
        "--json",
    )
    assert out.returncode == 0, out.stderr
    tr = Tracks.load(tmp / "tracks" / "trajectories.csv")
    assert len(tr) == json.loads(out.stdout)["frames"] > 500 and len(tr.marker_ids()) >= 8


def test_bad_inputs_are_one_sentence(session, tmp_path):
    _, tmp = session
    out = _vts(
        "motion", "analyze", tmp_path / "nowhere", "--calibration", tmp / "cameras.json", "--config", tmp / "rig.yaml"
    )
    assert out.returncode == 3 and out.stderr.startswith("vts: ") and "Traceback" not in out.stderr
    assert "nowhere" in out.stderr
    out = _vts("motion", "analyze", tmp / "session", "--config", tmp / "rig.yaml")
    assert out.returncode == 2 and "calibration" in out.stderr and "Traceback" not in out.stderr


def test_export_onto_a_full_disk_keeps_the_analysis_and_no_cut_file(session, small_disk):
    """Issue 21 §1: `--export DIR -o R --plot P` on a disk with room for part of the export only:
    every export file is whole or absent (no cut trajectories.csv, no temporary file left), the
    analysis is printed and stored all the same, and one sentence names the files (exit 3)."""
    _, tmp = session
    disk = small_disk(1024)
    disk.fill(leave=300_000)  # motion_6dof.* (~150 kB) fit, trajectories.csv (~900 kB) does not
    with ResultsStore(f"sqlite:///{tmp / 'results.sqlite'}") as store:
        before = len(store.runs(procedure="motion"))
    out = _vts(
        "motion",
        "analyze",
        tmp / "session",
        "--calibration",
        tmp / "cameras.json",
        "--mapping",
        tmp / "mapping.json",
        "--config",
        tmp / "rig.yaml",
        "--export",
        disk.path / "export",
        "-o",
        disk.path / "report.html",
        "--plot",
        disk.path / "plot.png",
        "--workers",
        "2",
    )
    err = out.stderr.strip().splitlines()[-1]
    assert out.returncode == 3 and "Traceback" not in out.stderr, out.stderr
    assert err.startswith("vts: ") and "trajectories.csv: could not be written (no space left on device)" in err
    assert "is stored as run" in err and "stored: run" in out.stdout and "motion_body_max_mm" in out.stdout
    with ResultsStore(f"sqlite:///{tmp / 'results.sqlite'}") as store:
        runs = store.runs(procedure="motion")
        assert len(runs) == before + 1 and "trajectories.csv" in (runs[-1].notes or "")
    left = disk.files()
    assert not any(".tmp" in name for name in left), left
    assert "export/trajectories.csv" not in left and "export/trajectories.json" not in left
    for name in ("report.html", "plot.png"):  # written whole (then not named), or absent and named
        assert (name in left) != (f"{name}: could not be written" in err), (name, left, err)
    if "report.html" in left:
        assert (disk.path / "report.html").read_text().rstrip().endswith("</html>")
    # what is there is whole: the files written before the disk filled read back
    assert json.loads((disk.path / "export" / "motion_6dof.json").read_text())["clock"]
    rows = (disk.path / "export" / "motion_6dof.csv").read_text().splitlines()
    assert len(rows) > 100 and len({r.count(",") for r in rows[1:]}) == 1
