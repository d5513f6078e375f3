"""The one patient model (vts_hw/motion/patient_model.py): learned from a still period of the
simulated patient, fitted over a whole table and one instant at a time with the same numbers,
kept in a session and read back, and the live/offline comparison (issue 33 §1)."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vts_hw.errors import DataError
from vts_hw.motion.agreement import compare_live, explain_alerts
from vts_hw.motion.patient_model import PatientModel, learn_model
from vts_hw.sim_devices.patient import BodyMotion, Breathing, Patient
from vts_hw.tracking.live.estimator import LivePose
from vts_hw.tracking.live.pose_log import MODEL_FILE, POSES_FILE, PoseLog, load_model, read_poses, save_model


def _markers(patient, times, noise=0.1, seed=0):
    rng = np.random.default_rng(seed)
    P = np.array([[m.center for m in patient.markers_at(float(t), np.zeros(3))] for t in times])
    return P + rng.normal(0, noise, P.shape)


@pytest.fixture(scope="module")
def learned():
    p = Patient(Breathing(0.0, 60.0, 2), BodyMotion([]), 2)
    t = np.arange(0.0, 10.0, 0.04)
    return p, learn_model(t, _markers(p, t), frame="spect")


def test_the_model_learned_from_a_still_period_keeps_breathing_out_of_the_pose(learned):
    """The reference period's pose noise is that of the markers' noise, not of breathing (a pose
    per instant put the chest's lift into the pose: 3 mm RMS); breathing is mostly up (+Y)."""
    p, m = learned
    assert m.breathes
    assert m.pose_noise_mm < 0.2 and m.pose_noise_deg < 0.1
    assert np.max(np.linalg.norm(m.vectors, axis=1)) == pytest.approx(1.0)
    assert np.all(m.vectors[:, 1] > np.abs(m.vectors[:, 0]))  # up, more than sideways
    t = np.arange(20.0, 40.0, 0.2)
    R, T, s, rms, used = m.fit(_markers(p, t, seed=1))
    truth = np.array([p.six_dof(float(x)) for x in t])
    assert np.nanmax(np.abs(T - truth[:, :3])) < 0.3  # the truth is still
    assert np.nanstd(s) > 1.0  # and the signal breathes


def test_one_instant_is_fitted_as_a_frame_of_a_recording(learned):
    """fit_instant and fit give the same pose for the same points from the same start."""
    p, m = learned
    t = np.arange(30.0, 31.0, 0.04)
    P = _markers(p, t, seed=3)
    R, T, s, rms, used = m.fit(P)
    for f in range(0, len(t), 5):
        seen = np.flatnonzero(np.isfinite(P[f, :, 0]))
        one = m.fit_instant(seen, P[f, seen])
        assert np.allclose(one.R, R[f], atol=1e-9) and np.allclose(one.T, T[f], atol=1e-6)
        assert one.s == pytest.approx(s[f], abs=1e-6) and one.n_markers == used[f].sum()
    assert m.fit_instant([0, 1], P[0, :2]) is None  # two markers: no pose


def test_the_model_goes_through_the_session_and_bad_copies_are_refused(learned, tmp_path):
    _, m = learned
    save_model(tmp_path, m)
    back = load_model(tmp_path)
    assert np.allclose(back.reference, m.reference, atol=1e-5) and np.allclose(back.vectors, m.vectors, atol=1e-5)
    assert back.bands == m.bands and back.frame == "spect"
    d = json.loads((tmp_path / MODEL_FILE).read_text())
    for bad in (
        {**d, "format": "x"},
        {**d, "reference_mm": [[1, 2]]},
        {**d, "bands": [[0, 99]]},
        {**d, "frame": "mri"},
        {k: v for k, v in d.items() if k != "breathing_vectors"},
    ):
        with pytest.raises(DataError):
            PatientModel.from_dict(bad)
    (tmp_path / MODEL_FILE).write_text("{not json")
    with pytest.raises(DataError, match=MODEL_FILE):
        load_model(tmp_path)


def test_live_poses_are_appended_and_a_torn_last_row_is_skipped(tmp_path):
    poses = [
        LivePose(
            1000.0 + k,
            Rotation.from_rotvec([0, 0.01 * k, 0]).as_matrix(),
            np.array([k, 0.0, 1.0]),
            0.5,
            0.05,
            8,
            2.0 if k else float("nan"),
            "still",
            0.1,
            0.01,
            "known",
            0.8,
            (k, -1, k + 1),
        )
        for k in range(5)
    ]
    log = PoseLog(tmp_path)
    log.write(poses[:3])
    log.write(poses[3:])
    log.close()
    with open(tmp_path / POSES_FILE, "a") as f:
        f.write("1005.0,1,0,0,0,1")  # killed mid-row
    back = read_poses(tmp_path)
    assert len(back) == 5 and back.skipped == 1
    assert np.allclose(back.R[4], poses[4].R, atol=1e-8) and back.T[3, 0] == 3.0 and back.state[0] == "still"
    assert np.isnan(back.cameras[0]) and back.cameras[1] == 2.0  # cameras not known: kept so
    assert back.health[2] == "known" and back.confidence[2] == pytest.approx(0.8)
    assert back.frames[3] == (3, -1, 4)  # the frames it was made from
    (tmp_path / POSES_FILE).write_text("time,x\n1,2\n")
    with pytest.raises(DataError, match="not a live pose file"):
        read_poses(tmp_path)


def test_the_comparison_measures_the_difference_and_explains_alerts():
    F = 50
    t = np.arange(F) * 0.04
    R = np.repeat(np.eye(3)[None], F, 0)
    T = np.zeros((F, 3))
    centre = np.array([0.0, 100.0, 0.0])
    same = compare_live(t + 0.001, R, T, t, R, T, centre, 0.016)
    assert same.compared == F and same.rms_mm == pytest.approx(0.0, abs=1e-9)
    T2 = T.copy()
    T2[10, 0] = 0.5
    T_off = T.copy()
    T_off[20] = np.nan
    a = compare_live(t, R, T2, t, R, T_off, centre, 0.016)
    assert a.compared == F - 1 and a.no_offline_pose == 1 and a.worst_mm == pytest.approx(0.5)
    assert compare_live(t + 1.0, R, T, t[:10], R[:10], T[:10], centre, 0.016).unpaired == F
    moved = T.copy()
    moved[30:] = [5.0, 0.0, 0.0]
    out = explain_alerts(
        [{"onset": 1.0, "time": 1.5}, {"onset": 0.1, "time": 0.5}], [], t, R, moved, centre, 3.0, 2.0, margin_s=0.2
    )
    assert out[0]["explained"] and "5.0 mm" in out[0]["by"]
    assert not out[1]["explained"] and "at most 0.00 mm" in out[1]["why"]


def test_the_analysis_fits_the_sessions_live_model_and_a_bad_one_never_stops_it(tmp_path):
    """A session holding a live model and poses: the offline analysis fits that model (the same
    poses where the live path had the same points) and compares; a model of another patient, or
    one that cannot be read, is said and the analysis learns its own."""
    from motion_truth import patient_tracks
    from vts_hw.procedures.motion import MotionAnalysis

    _, tracks, _, _ = patient_tracks(seed=5, duration_s=30.0, n_moves=1)
    first = MotionAnalysis(tmp_path / "none", tracks=tracks).analyze()
    session = tmp_path / "session"
    session.mkdir()
    save_model(session, first.result.model)
    pose = first.result.pose
    rows = np.flatnonzero(pose.valid)[::7]
    log = PoseLog(session)
    log.write(
        [
            LivePose(
                float(pose.t[k]) + 0.002,
                pose.R[k],
                pose.T[k],
                float(pose.resp[k]),
                float(pose.rms_mm[k]),
                int(pose.n_markers[k]),
                2.0,
                "still",
                0.0,
                0.0,
                "known",
                0.8,
            )
            for k in rows
        ]
    )
    log.close()
    a = MotionAnalysis(session, tracks=tracks).analyze()
    assert any("learned live" in p for p in a.problems)
    live = a.results_data()["live"]
    assert live["compared"] == len(rows) and live["rms_mm"] < 0.01 and live["rms_deg"] < 0.005, live
    assert "live: live and offline poses agree to" in a.results()
    (session / MODEL_FILE).write_text(
        json.dumps(
            {
                **first.result.model.to_dict(),
                "reference_mm": [[5000.0 + k, 0.0, 0.0] for k in range(8)],
                "breathing_vectors": [[0.0, 1.0, 0.0]] * 8,
                "bands": [list(range(8))],
            }
        )
    )
    b = MotionAnalysis(session, tracks=tracks).analyze()
    assert any(p.startswith("live model not used: only") for p in b.problems), b.problems
    assert b.live_agreement is None and b.result.pose.valid.sum() == first.result.pose.valid.sum()
    (session / MODEL_FILE).unlink()
    os.mkfifo(session / MODEL_FILE)
    c = MotionAnalysis(session, tracks=tracks).analyze()
    assert any(p.startswith("live model not used:") and "not a regular file" in p for p in c.problems), c.problems


def test_live_poses_that_cannot_be_kept_are_said_once_and_the_scan_goes_on(learned, tmp_path):
    """The scan's folder unwritable (here not a folder at all): the model and poses are not kept,
    one note and one manifest entry say so, and the live path's keeping never raises."""
    from types import SimpleNamespace

    from vts_hw.procedures.scan_live import LiveMotion

    _, m = learned
    pose = LivePose(1.0, np.eye(3), np.zeros(3), 0.0, 0.05, 8, 2.0, "still", 0.0, 0.0, "known", 0.8)
    lm = LiveMotion.__new__(LiveMotion)
    notes, meta = [], {"live_motion": {}}
    unjudged = LivePose(2.0, np.eye(3), np.zeros(3), 0.0, 0.05, 3, 2.0, "still", 0.0, 0.0, model_markers=8)
    lm.tracker = SimpleNamespace(estimator=SimpleNamespace(model=m, poses=[pose, unjudged]))
    lm._log, lm._kept, lm._model_saved, lm.keep_problem, lm.on_note = None, 0, False, "", notes.append
    (tmp_path / "not-a-folder").write_text("x")
    session = SimpleNamespace(folder=tmp_path / "not-a-folder", update_manifest=lambda change: change(meta))
    lm._keep(session)
    lm._keep(session)
    assert len(notes) == 1 and "could not be kept" in notes[0]
    assert meta["live_motion"]["keep_problem"] == lm.keep_problem and lm._kept == 0
    good = SimpleNamespace(folder=tmp_path, update_manifest=lambda change: change(meta))
    lm.keep_problem = ""
    lm._keep(good)
    kept = read_poses(tmp_path)
    assert lm._kept == 2 and len(kept) == 2 and load_model(tmp_path) is not None
    # the live path leaves a pose's health to the log (off its worker): 3 markers of 8 is bounded
    assert list(kept.health) == ["known", "bounded"] and 0.0 < kept.confidence[1] < 0.8
    assert meta["live_motion"]["model_file"] == MODEL_FILE and meta["live_motion"]["poses_file"] == POSES_FILE


def test_the_fit_stops_once_converged_at_the_pose_it_would_reach(learned, monkeypatch):
    """A frame stops iterating once its step is below CONVERGED at the last robust scale (the
    live path's fit after a gap asks for 30 iterations): far fewer steps, the same pose to 1e-9
    as iterating to the end; the same frame stops at the same step alone or in a recording."""
    import vts_hw.motion.patient_model as pm

    p, m = learned
    P = _markers(p, np.arange(30.0, 32.0, 0.04), seed=5)
    idx = np.arange(m.n_markers)
    start = m.fit_instant(idx, P[0])
    solves = []
    real_solve = np.linalg.solve
    monkeypatch.setattr(pm.np.linalg, "solve", lambda N, g: solves.append(len(N)) or real_solve(N, g))
    quick = [m.fit_instant(idx, P[f], start, iterations=30) for f in range(1, 6)]
    assert len(solves) <= 5 * 10  # at most 10 steps a frame, not 30
    R, T, s, _, _ = m.fit(
        P[1:6], None, np.repeat(start.R[None], 5, 0), np.repeat(start.T[None], 5, 0), np.full(5, start.s), iterations=30
    )
    monkeypatch.setattr(pm, "_TOL7", np.zeros(7))  # never converged: every iteration
    solves.clear()
    full = [m.fit_instant(idx, P[f], start, iterations=30) for f in range(1, 6)]
    assert len(solves) == 5 * 30
    for k, (a, b) in enumerate(zip(quick, full)):
        assert np.abs(a.R - b.R).max() < 1e-10 and np.abs(a.T - b.T).max() < 1e-8 and abs(a.s - b.s) < 1e-8
        assert np.allclose(a.R, R[k], rtol=0, atol=1e-12) and np.allclose(a.T, T[k], rtol=0, atol=1e-9)
        assert a.s == pytest.approx(s[k], abs=1e-9)
