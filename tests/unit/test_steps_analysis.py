"""The step test's analysis on made-up data with known answers."""

import json

import numpy as np
import pytest

from vts_hw.errors import DataError
from vts_hw.procedures.steps_analysis import StepAnalysis, six_dof
from vts_hw.sim_devices.scene import PHANTOM_LAYOUT
from vts_hw.tolerance import State, Window
from vts_hw.vision.registration import RigidTransform

TEMPLATE = np.array([PHANTOM_LAYOUT[f"S{k}"] for k in range(1, 8)], float) + [0.0, -80.0, 0.0]
FINAL = RigidTransform.from_euler_xyz_deg((2.0, -5.0, 3.0), (12.0, 100.0, 95.0))


def positions():
    """Baseline, 4 vertical, 4 axial steps of 10 mm, then a known free move: P×7×3."""
    out = [TEMPLATE]
    y = z = 0.0
    for _ in range(4):
        y += 10.0
        out.append(TEMPLATE + [0.0, y, z])
    for _ in range(4):
        z += 10.0
        out.append(TEMPLATE + [0.0, y, z])
    out.append(FINAL.apply(TEMPLATE))
    return np.array(out)


def labels(n):
    return ["baseline"] + [f"P{i:02d}" for i in range(1, n - 1)] + ["free"]


def test_identical_systems_give_a_perfect_result():
    spect = positions()
    a = StepAnalysis(labels(len(spect)), spect.copy(), spect).analyze()
    for r in a.regressions.values():
        assert r.slope == pytest.approx(1.0) and r.intercept_mm == pytest.approx(0.0, abs=1e-9)
        assert r.r2 == pytest.approx(1.0)
    assert a.diffs.max() == pytest.approx(0.0, abs=1e-9)
    assert np.allclose(a.move_spect.rotation_xyz_deg, (2.0, -5.0, 3.0), atol=1e-9)
    true_shift = FINAL.apply(TEMPLATE).mean(axis=0) - TEMPLATE.mean(axis=0)
    assert np.allclose(a.move_spect.translation_mm, true_shift)
    assert a.state == State.OK


def test_a_scale_error_shows_in_the_slope_and_an_offset_in_the_distances():
    spect = positions()
    vts = spect * [1.0, 1.03, 1.0] + [0.0, 0.0, 0.8]  # 3 % vertical scale, 0.8 mm axial shift
    a = StepAnalysis(labels(len(spect)), vts, spect).analyze()
    assert a.regressions["y"].slope == pytest.approx(1.03, abs=1e-9)
    assert a.regressions["z"].intercept_mm == pytest.approx(0.8, abs=1e-9)
    states = {(m.subject, m.metric): m.state for m in a.measures}
    assert states[("y", "steps_slope")] == State.ACTION  # beyond the 1.02 action limit
    assert states[("x", "steps_slope")] == State.OK
    assert states[("z", "steps_intercept_mm")] == State.OK  # 0.8 < 1 mm
    assert a.diffs.min() >= 0.8 - 1e-9
    assert a.state == State.ACTION


def test_rotation_difference_of_the_free_move_is_measured():
    spect = positions()
    vts = spect.copy()
    extra = RigidTransform.from_euler_xyz_deg((0.0, 0.0, 1.0))  # the VTS sees 1 deg more about z
    c = spect[-1].mean(axis=0)
    vts[-1] = extra.apply(spect[-1] - c) + c
    a = StepAnalysis(labels(len(spect)), vts, spect).analyze()
    assert a.rotation_diff_deg[2] == pytest.approx(1.0, abs=0.02)
    assert np.abs(a.translation_diff_mm).max() < 1e-9
    rot = {m.subject: m.state for m in a.measures if m.metric == "steps_rotation_diff_deg"}
    assert rot["move_z"] == State.TOLERANCE and rot["move_x"] == State.OK


def test_tolerances_given_override_the_defaults():
    spect = positions()
    vts = spect + [0.3, 0.0, 0.0]
    tight = {"steps_diff_mean_mm": Window(tolerance_high=0.1, action_high=0.2, unit="mm")}
    a = StepAnalysis(labels(len(spect)), vts, spect).analyze(tight)
    st = {m.metric: m.state for m in a.measures if m.subject == "all"}
    assert st["steps_diff_mean_mm"] == State.ACTION
    assert StepAnalysis(labels(len(spect)), vts, spect).analyze().state == State.OK


def test_results_data_text_and_plot(tmp_path):
    spect = positions()
    rng = np.random.default_rng(0)
    a = StepAnalysis(labels(len(spect)), spect + rng.normal(0, 0.1, spect.shape), spect).analyze()
    data = json.loads(json.dumps(a.results_data()))
    assert data["procedure"] == "sphere-steps" and data["vts_hw_version"] and data["date"]
    assert len(data["positions"]) == len(spect) and set(data["regression"]) == {"x", "y", "z"}
    assert data["differences_mm"]["mean"] == pytest.approx(a.diffs.mean())
    text = a.results()
    assert "slope" in text and "6-DOF move baseline → free" in text
    png = tmp_path / "steps.png"
    a.plot(png)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_bad_inputs_are_one_line_errors():
    spect = positions()
    with pytest.raises(DataError, match="positions × spheres × 3"):
        StepAnalysis(labels(len(spect)), spect[:, :6], spect)
    with pytest.raises(DataError, match="labels"):
        StepAnalysis(["a"], spect, spect)
    bad = spect.copy()
    bad[2, 3, 1] = np.nan
    with pytest.raises(DataError, match="missing"):
        StepAnalysis(labels(len(spect)), bad, spect)
    with pytest.raises(RuntimeError, match="analyze"):
        StepAnalysis(labels(len(spect)), spect, spect).results_data()


def test_six_dof_of_a_pure_translation():
    mv = six_dof(TEMPLATE, TEMPLATE + [1.0, 2.0, 3.0])
    assert np.allclose(mv.rotation_xyz_deg, 0.0, atol=1e-9) and np.allclose(mv.translation_mm, (1, 2, 3))


def test_the_qa_report_shows_the_latest_step_test_and_refuses_a_changed_plot(tmp_path):
    from vts_hw.report import build_drift_report
    from vts_hw.store import ResultsStore
    from vts_hw.store.recorder import record

    spect = positions()
    vts = spect + [0.0, 0.0, 0.8]  # the VTS 0.8 mm off axially: TOLERANCE
    a = StepAnalysis(labels(len(spect)), vts, spect).analyze()
    png = tmp_path / "steps.png"
    a.plot(png)
    with ResultsStore(f"sqlite:///{tmp_path / 'r.sqlite'}") as store:
        run_id = record(store, a, rig="r", operator="me", artifacts=[png]).run_id
        rep = build_drift_report(store, tmp_path / "report.html")
        html = (tmp_path / "report.html").read_text()
        assert rep.steps is not None and rep.steps.latest.id == run_id
        assert f'alt="7-sphere step test, run {run_id}"' in html and 'data-plots-expected="1"' in html
        assert any("7-sphere step test: TOLERANCE" in line for line in rep.attention())
        assert "steps_diff_mean_mm (all)" in " ".join(rep.attention())
        data = rep.results_data()["steps"]
        assert data["latest"]["status"] == "TOLERANCE" and data["plot"] is True
        build_drift_report(store, tmp_path / "report.pdf")
        assert (tmp_path / "report.pdf").read_bytes()[:5] == b"%PDF-"
        png.write_bytes(png.read_bytes() + b"tampered")
        rep2 = build_drift_report(store, tmp_path / "report2.html")
        assert rep2.steps.plot_png is None and "changed after the run" in rep2.steps.plot_problem
        assert 'data-plots-expected="0"' in (tmp_path / "report2.html").read_text()


@pytest.mark.parametrize(
    "doc", [b"[]", b'{"plan": [{"x": 1}], "positions": []}', b"\xff\xfe", b"[" * 5000, b'{"plan": 1e999999}']
)
def test_a_step_session_file_of_the_wrong_shape_is_a_data_error(tmp_path, doc):
    from vts_hw.errors import DataError
    from vts_hw.procedures.steps import load_positions

    (tmp_path / "positions.json").write_bytes(doc)
    with pytest.raises(DataError, match="positions.json"):
        load_positions(tmp_path)
