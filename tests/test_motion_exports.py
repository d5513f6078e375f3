"""The motion exports read back: the 6-DOF series (CSV and JSON), the respiratory trace, the
list-mode subsets, and CASToR's two files through a reader written here from CASToR's rules
(not from the writer): keyword lines, comma- or space-separated numbers, the first trigger 0."""

import csv
import json
import re

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vts_hw.motion import analyze_motion, marker_series
from vts_hw.motion.castor import write_castor
from vts_hw.motion.exports import export_motion

from motion_truth import patient_tracks


def read_castor_keyword(path, key):
    """The values after ``key:`` in a CASToR ASCII file (one line, or the lines that follow
    when nothing follows the colon), as float rows."""
    lines = path.read_text(encoding="ascii").splitlines()
    for i, line in enumerate(lines):
        if line.split(":", 1)[0].strip().lower() == key.lower():
            rest = line.split(":", 1)[1].strip()
            if rest:
                return [[float(x) for x in re.split(r"[,\s]+", rest) if x]]
            rows = []
            for nxt in lines[i + 1:]:
                if not nxt.strip() or ":" in nxt:
                    break
                rows.append([float(x) for x in re.split(r"[,\s]+", nxt.strip()) if x])
            return rows
    raise KeyError(key)


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    patient, tracks, _, t0 = patient_tracks(seed=5, duration_s=60.0, n_moves=2)
    r = analyze_motion(marker_series(tracks))
    out = tmp_path_factory.mktemp("export")
    paths = export_motion(r, out, n_bins=4)
    return patient, r, out, paths, t0


def test_castor_files_have_one_trigger_and_one_line_per_state(exported):
    _, r, out, _, _ = exported
    dyn, rig = out / "castor_motion.dyn", out / "castor_motion_rigid.txt"
    n = int(read_castor_keyword(dyn, "nb_motion_triggers")[0][0])
    stamps = read_castor_keyword(dyn, "timestamp_motion_triggers")[0]
    params = read_castor_keyword(rig, "Transformation_parameters")
    assert n == len(r.states) == len(stamps) == len(params) == 3
    assert stamps[0] == 0.0 and all(b > a for a, b in zip(stamps, stamps[1:]))
    assert all(len(p) == 6 for p in params) and np.allclose(params[0], 0.0, atol=0.05)
    assert rig.read_text().count("Rotation_convention: XYZ") == 1
    assert read_castor_keyword(rig, "Transformation_mode")[0] == [0.0]
    # host clock here: triggers are seconds from the first frame; the states start at the moves
    for s, stamp in zip(r.states, stamps):
        assert stamp == pytest.approx(s.t_start - r.series.t[0], abs=1e-3)


def castor_matrix_from_source_rules(p):
    """The 4x4 matrix CASToR 3.1.1's iDeformationRigid builds from one parameter line (written
    here from its source, not from our writer): Translation(-t) times Rx(rA) Ry(rB) Rz(rC)."""
    tx, ty, tz = p[:3]
    a, b, c = np.radians(p[3:])
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    trs = np.eye(4)
    trs[:3, 3] = [-tx, -ty, -tz]
    rot = np.eye(4)
    rot[:3, :3] = rx @ ry @ rz
    return trs @ rot


def test_castor_parameters_undo_the_true_pose_of_each_state(exported):
    """CASToR pulls: an output voxel at x takes the input at M x. For the reference image to be
    carried into a state's pose, M must take a point of that state back to the reference."""
    patient, r, out, _, _ = exported
    params = read_castor_keyword(out / "castor_motion_rigid.txt", "Transformation_parameters")
    assert np.allclose(castor_matrix_from_source_rules(params[0]), np.eye(4), atol=0.05)   # the reference state
    for s, p in zip(r.states, params):
        R, T = patient.body_transform(0.5 * (s.t_start + s.t_end))
        x_ref = np.array([[0.0, 0.0, 0.0], [100.0, 50.0, -80.0], [-120.0, 80.0, 150.0]])
        x_state = x_ref @ R.T + T
        M = castor_matrix_from_source_rules(p)
        back = x_state @ M[:3, :3].T + M[:3, 3]
        assert np.abs(back - x_ref).max() < 0.5, (s.index, back - x_ref)


def test_six_dof_csv_and_json_agree_and_quaternions_match_the_angles(exported):
    _, r, out, _, _ = exported
    with open(out / "motion_6dof.csv") as f:
        rows = list(csv.DictReader(f))
    doc = json.loads((out / "motion_6dof.json").read_text())
    assert len(rows) == len(doc["columns"]["time_s"]) == len(r.pose.t)
    assert "host clock" in doc["clock"] and doc["frame"].startswith("SPECT frame")
    ok = [k for k, row in enumerate(rows) if row["quality"] == "ok"][::50]
    assert len(ok) > 10
    for k in ok:
        e = [float(rows[k][c]) for c in ("rx_deg", "ry_deg", "rz_deg")]
        q = [float(rows[k][c]) for c in ("qx", "qy", "qz", "qw")]
        assert Rotation.from_quat(q).as_euler("xyz", degrees=True) == pytest.approx(e, abs=1e-3)
        assert float(rows[k]["tx_mm"]) == pytest.approx(doc["columns"]["tx_mm"][k], abs=1e-3)
    states = {int(row["state"]) for row in rows}
    assert states == {0, 1, 2}
    assert len(doc["events"]) == 2


def test_respiration_and_subsets(exported):
    patient, r, out, _, t0 = exported
    with open(out / "respiration.csv") as f:
        rows = list(csv.DictReader(f))
    amp = np.array([float(x["amplitude_mm"]) for x in rows])
    t = np.array([float(x["time_s"]) for x in rows]) + r.series.t[0]
    assert np.corrcoef(amp, patient.breathing.value(t))[0, 1] > 0.98
    sub = json.loads((out / "subsets.json").read_text())
    ms = sub["motion_states"]
    assert [s["state"] for s in ms] == [0, 1, 2]
    assert all(a["interval_s"][1] == pytest.approx(b["interval_s"][0]) for a, b in zip(ms, ms[1:]))
    for kind in ("amplitude", "phase"):
        bins = sub["respiratory_bins"][kind]
        assert len(bins) == 4 and all(b["frames"] > 0 and b["intervals"] for b in bins)
    # amplitude bins: equal frame counts within a few frames, and their amplitudes really differ
    counts = [b["frames"] for b in sub["respiratory_bins"]["amplitude"]]
    assert max(counts) - min(counts) <= 0.05 * sum(counts)
    lo = [b["amplitude_mm"][0] for b in sub["respiratory_bins"]["amplitude"]]
    assert lo == sorted(lo) and lo[-1] > lo[0]


def test_castor_writer_refuses_a_state_without_a_pose(tmp_path):
    with pytest.raises(ValueError, match="without a pose"):
        write_castor([0.0, 5.0], [[0] * 6, [np.nan] * 6], tmp_path)
    p1, p2 = write_castor([3.0, 8.5], [[0] * 6, [1, 2, 3, 0.5, 0, 0]], tmp_path)
    assert read_castor_keyword(p1, "timestamp_motion_triggers") == [[0.0, 8.5]]


def test_on_the_spect_clock_times_are_list_mode_seconds(tmp_path):
    """Tracks with SPECT times (as the sync analysis makes them): every time in the exports is
    list-mode seconds, the CASToR triggers from the acquisition start (list-mode 0)."""
    patient, tracks, _, t0 = patient_tracks(seed=5, duration_s=60.0, n_moves=2)
    lead = 2.5                                 # the SPECT started 2.5 s before the first frame
    synced = tracks.with_spect(None, lambda h: np.asarray(h) - t0 + lead)
    r = analyze_motion(marker_series(synced))
    assert r.series.clock == "spect"
    export_motion(r, tmp_path)
    doc = json.loads((tmp_path / "motion_6dof.json").read_text())
    assert "SPECT list-mode" in doc["clock"] and doc["time_origin"] == 0.0
    assert doc["columns"]["time_s"][0] == pytest.approx(lead, abs=1e-6)
    stamps = read_castor_keyword(tmp_path / "castor_motion.dyn", "timestamp_motion_triggers")[0]
    assert stamps[0] == 0.0
    moves = sorted(m.t_start for m in patient.motion.moves)
    for stamp, true_start in zip(stamps[1:], moves):
        assert true_start - t0 + lead - 0.5 <= stamp <= true_start - t0 + lead + 2.0
