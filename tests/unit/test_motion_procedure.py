"""MotionAnalysis in the one result shape, on synthetic patient tracks (the recording path is
tested end to end in tests/integration/test_motion_e2e.py)."""

import json

import numpy as np

from motion_truth import patient_tracks
from vts_hw.procedures.motion import MotionAnalysis
from vts_hw.results import Analysis
from vts_hw.tolerance import State, Window


def test_result_shape_measures_and_states(tmp_path):
    patient, tracks, _, _ = patient_tracks(seed=5, duration_s=60.0, n_moves=2)
    a = MotionAnalysis(tmp_path / "session", tracks=tracks).analyze()
    assert isinstance(a, Analysis) and a.procedure == "motion"
    f = a.figures()
    six = np.array([patient.six_dof(x) for x in tracks.host_time])
    assert np.max(np.abs(six[:, 3:])) > 1.0
    by = {m.metric: m for m in a.measures}
    assert set(by) == {"motion_body_max_mm", "motion_body_max_deg", "motion_pose_coverage"}
    # this patient moved by more than a SPECT pixel: ACTION; its coverage is complete
    assert f["motion_body_max_mm"] > 6.4 and by["motion_body_max_mm"].state == State.ACTION
    assert by["motion_pose_coverage"].state == State.OK and a.state == State.ACTION
    d = a.results_data()
    json.dumps(d)
    assert d["summary"]["state"] == "ACTION" and d["vts_hw_version"] and d["date"]
    assert "host clock" in d["clock"] and len(d["events"]) == 2 and len(d["states"]) == 3
    assert any("host clock" in p for p in d["problems"])
    text = a.results()
    assert "event 2" in text and "state: ACTION" in text and "host clock" in text
    png = a.plot(tmp_path / "m.png")
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and (tmp_path / "m.png").stat().st_size == len(png)
    paths = a.export(tmp_path / "out")
    names = sorted(p.name for p in paths)
    # host-clock times (no list-mode): no CASToR file, and one sentence says why
    assert names == sorted(
        [
            "motion_6dof.csv",
            "motion_6dof.json",
            "respiration.csv",
            "subsets.json",
            "trajectories.csv",
            "trajectories.json",
        ]
    )
    assert (
        len(a.export_notes) == 2
        and a.export_notes[0].startswith("CASToR files not written")
        and "--listmode" in a.export_notes[0]
        and a.export_notes[1].startswith("YRT-PET LOR motion file not written")
    )


def test_breathing_only_is_ok_and_the_rig_windows_judge(tmp_path):
    _, tracks, _, _ = patient_tracks(seed=3, duration_s=40.0, n_moves=0)
    a = MotionAnalysis(tmp_path, tracks=tracks).analyze()
    assert a.state == State.OK and a.results_data()["events"] == []
    strict = {"motion_body_max_mm": Window(tolerance_high=0.0001, action_high=10.0, unit="mm")}
    b = MotionAnalysis(tmp_path, tracks=tracks).analyze(tolerances=strict)
    assert b.state == State.TOLERANCE
