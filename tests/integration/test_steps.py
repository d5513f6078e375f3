"""The 7-sphere step test end to end on the simulated rig: stereo calibration from rendered
checkerboards, VTS -> SPECT mapping, 22 table positions through the Axis driver over HTTP,
the simulated SPECT's volumes; scored against the truth, stored, re-analysed from disk."""

import json
import os
import shutil

import numpy as np
import pytest

from inprocess_cli import run
from vts_hw.errors import DataError
from vts_hw.procedures.steps import OperatorPositioner, VolumeFolder, load_positions, step_plan
from vts_hw.sim_devices.scenarios.step_chain import run_sim_steps
from vts_hw.store import ResultsStore

SEED = 3


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    out = tmp_path_factory.mktemp("steps")
    with ResultsStore(f"sqlite:///{out / 'results.sqlite'}") as store:
        res = run_sim_steps(out, SEED, store=store)
    return res


def vts(*args, env=None, input=None):
    """`vts ARGS` in this process (tests/inprocess_cli.py) with the variables ``env`` added."""
    return run(*args, env={**os.environ, **(env or {})}, input=input)


def test_regression_r2_at_least_0999_and_the_chain_meets_its_accuracy_goals(chain):
    a = chain.analysis
    assert len(a.labels) == 22 and a.labels[0] == "baseline" and a.labels[-1] == "free"
    for ax, r in a.regressions.items():
        assert r.r2 >= 0.999, ax
        assert abs(r.slope - 1.0) < 0.005, ax
    s = chain.scores
    assert s["position_rms_mm"] <= 0.15
    assert s["move_rotation_error_deg"] <= 0.05
    assert s["move_translation_error_mm"] <= 0.1
    # the VTS and the SPECT see the same free move (a few degrees, a few centimetres)
    assert 3.0 <= np.linalg.norm(s["true_move"]["rotation_xyz_deg"]) <= 12.0
    assert np.abs(a.rotation_diff_deg).max() < 0.2 and np.abs(a.translation_diff_mm).max() < 0.5
    assert a.state.value == "OK"


def test_the_simulated_table_made_real_steps_of_9_5_to_10_5_mm(chain):
    truth = chain.truth
    ys = [
        truth[f"V{i:02d}"][:, 1].mean() - truth[f"V{i - 1:02d}" if i > 1 else "baseline"][:, 1].mean()
        for i in range(1, 11)
    ]
    assert all(9.5 <= d <= 10.5 for d in ys)
    assert len(set(np.round(ys, 3))) > 5  # not all the same: the table is not perfect


def test_the_run_is_stored_with_its_windows_and_plot(chain):
    with ResultsStore(f"sqlite:///{chain.out_dir / 'results.sqlite'}") as store:
        runs = store.runs(procedure="sphere-steps")
        assert [r.id for r in runs] == [chain.run_id]
        assert runs[0].status == str(chain.analysis.state) and runs[0].operator == "sim"
        ms = store.measurements(run_id=chain.run_id)
        assert len(ms) == len(chain.analysis.measures) == 3 * 3 + 3 + 2 * 3
        assert all(m.tolerance_id is not None for m in ms)  # judged by the stored windows
        r2 = {m.subject: m.value for m in ms if m.metric == "steps_r2"}
        assert r2 == pytest.approx({ax: r.r2 for ax, r in chain.analysis.regressions.items()})
        arts = store.artifacts(chain.run_id)
        assert [a.kind for a in arts] == ["plot"] and arts[0].path.endswith("steps.png")


def test_what_the_vts_saw_is_on_disk_position_by_position(chain):
    seen, plan = load_positions(chain.out_dir)
    assert [s.label for s in seen] == [p.label for p in plan] == [p.label for p in step_plan()]
    for s in seen:
        assert set(s.points_px) == {"cam1", "cam2"} and all(len(v) >= 7 for v in s.points_px.values())
        assert (chain.out_dir / f"{s.label}-cam1.jpg").read_bytes()[:2] == b"\xff\xd8"


def _rig_yaml(tmp_path):
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        "rig: steps-test\ncameras:\n"
        "  - {name: cam1, host: 127.0.0.1, port: 9, password_env: VTS_T_PW}\n"
        "  - {name: cam2, host: 127.0.0.1, port: 9, password_env: VTS_T_PW}\n"
    )
    return cfg


def _files(chain):
    d = chain.out_dir
    return ["--calibration", str(d / "calibration.json"), "--mapping", str(d / "spect_mapping.json")]


def test_analyze_again_from_disk_gives_the_same_figures(chain, tmp_path):
    session = tmp_path / "session"
    shutil.copytree(chain.out_dir, session, ignore=shutil.ignore_patterns("results.sqlite*", "spect"))
    r = vts(
        "qa",
        "steps",
        "--config",
        str(_rig_yaml(tmp_path)),
        "--analyze",
        str(session),
        "--volumes",
        str(chain.out_dir / "spect"),
        *_files(chain),
        "--store",
        f"sqlite:///{tmp_path / 'r.sqlite'}",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    for ax, reg in chain.analysis.regressions.items():
        assert data["regression"][ax]["slope"] == pytest.approx(reg.slope, abs=1e-12)
    assert data["differences_mm"]["max"] == pytest.approx(float(chain.analysis.diffs.max()))
    assert (session / "steps.png").exists()


def test_analyze_with_push_posts_the_step_test_to_qatrack(chain, tmp_path):
    """`vts qa steps ... --push`: the stored run goes to (the simulated) QATrack+ with its plot."""
    from vts_hw.sim_devices.qatrack_server import QATrackSim

    macros = {"x/steps_slope": "x_slope", "y/steps_slope": "y_slope", "z/steps_slope": "z_slope"}
    with QATrackSim({"VTS steps": list(macros.values())}, {"SPECT 1": ["VTS steps"]}, token="t-123") as peer:
        cfg = _rig_yaml(tmp_path)
        cfg.write_text(
            cfg.read_text()
            + f"qatrack:\n  url: {peer.url}\n  unit: SPECT 1\n  time_zone: America/Toronto\n  token_env: QT_TOKEN\n"
            f"  report: none\n  lists:\n    sphere-steps:\n      test_list: VTS steps\n"
            f"      macros: {json.dumps(macros)}\n      ignore: ['*']\n"
        )
        r = vts(
            "qa",
            "steps",
            "--config",
            str(cfg),
            "--analyze",
            str(chain.out_dir),
            "--volumes",
            str(chain.out_dir / "spect"),
            *_files(chain),
            "--store",
            f"sqlite:///{tmp_path / 'r.sqlite'}",
            "--push",
            env={"QT_TOKEN": "t-123"},
        )
        assert r.returncode == 0 and "posted in QATrack+" in r.stderr, r.stderr
        (tli,) = peer.instances
        assert tli["tests"]["x_slope"]["value"] == pytest.approx(chain.analysis.regressions["x"].slope)
        assert tli["attachments"] == ["steps.png"]


def test_a_plot_on_a_full_disk_never_costs_the_step_test(chain, tmp_path, small_disk):
    """Issue 21 §2: `vts qa steps --analyze S --out FULL`: the plot cannot be written, the test is
    printed and stored all the same, one sentence names steps.png (exit 3), no cut PNG is left."""
    disk = small_disk(64)
    disk.fill()
    url = f"sqlite:///{tmp_path / 'r.sqlite'}"
    r = vts(
        "qa",
        "steps",
        "--config",
        str(_rig_yaml(tmp_path)),
        "--analyze",
        str(chain.out_dir),
        "--volumes",
        str(chain.out_dir / "spect"),
        *_files(chain),
        "--store",
        url,
        "--out",
        str(disk.path),
    )
    line = r.stderr.strip().splitlines()[-1]
    assert r.returncode == 3 and "Traceback" not in r.stderr, r.stderr
    assert line.startswith("vts: ") and "steps.png: could not be written (no space left on device)" in line
    assert "the step test is stored as run" in line and "plot not written" in r.stdout
    assert "slope" in r.stdout and disk.files() == {}
    with ResultsStore(url) as store:
        (run,) = store.runs(procedure="sphere-steps")
        assert store.artifacts(run.id) == []


def test_a_missing_volume_names_the_position_and_keeps_the_vts_part(chain, tmp_path):
    vols = tmp_path / "vols"
    shutil.copytree(chain.out_dir / "spect", vols)
    (vols / "A03.npz").unlink()
    r = vts(
        "qa",
        "steps",
        "--config",
        str(_rig_yaml(tmp_path)),
        "--analyze",
        str(chain.out_dir),
        "--volumes",
        str(vols),
        *_files(chain),
        "--store",
        f"sqlite:///{tmp_path / 'r.sqlite'}",
    )
    assert r.returncode == 3
    line = r.stderr.strip().splitlines()[-1]  # after the progress lines: one line, no traceback
    assert line.startswith("vts: ") and "A03" in line and "--analyze" in line
    assert "Traceback" not in r.stderr


def test_real_rig_without_a_calibration_is_a_config_error(tmp_path):
    r = vts("qa", "steps", "--config", str(_rig_yaml(tmp_path)), "--volumes", str(tmp_path))
    assert r.returncode == 2 and "calibration.cameras" in r.stderr


def test_real_rig_dry_run_lists_the_plan_and_touches_nothing(chain, tmp_path):
    r = vts(
        "qa",
        "steps",
        "--config",
        str(_rig_yaml(tmp_path)),
        "--volumes",
        str(tmp_path),
        *_files(chain),
        "--dry-run",
        "--vertical",
        "2",
        "--axial",
        "1",
        env={"VTS_T_PW": "x"},
    )
    assert r.returncode == 0, r.stderr
    assert "Raise the table 10 mm (vertical step 2 of 2)" in r.stdout and "free" in r.stdout
    assert not any(tmp_path.glob("steps-*"))


def test_operator_positioner_asks_and_waits():
    asked = []
    plan = step_plan(2, 1, 10.0)
    OperatorPositioner(asked.append).move_to(plan[3])
    assert asked == [
        "[A01] Move the table 10 mm into the gantry (axial step 1 of 1). Press Enter when the table has stopped."
    ]


def test_volume_folder_finds_each_position_and_names_what_is_missing(tmp_path):
    (tmp_path / "V01.img").write_bytes(b"")
    (tmp_path / "V01.h33").write_text("!INTERFILE :=\n")
    plan = step_plan(1, 0)
    vf = VolumeFolder(tmp_path)
    assert vf.volume(plan[1]).name == "V01.h33"
    with pytest.raises(DataError, match="no SPECT volume for position baseline"):
        vf.volume(plan[0])


def test_cli_sim_short_plan_json(tmp_path):
    out = tmp_path / "sim"
    r = vts(
        "qa",
        "steps",
        "--sim",
        "--seed",
        "1",
        "--vertical",
        "1",
        "--axial",
        "1",
        "--frames",
        "3",
        "-o",
        str(out),
        "--json",
    )
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert [p["label"] for p in data["positions"]] == ["baseline", "V01", "A01", "free"]
    assert data["sim_truth"]["position_rms_mm"] < 0.15 and data["run_id"] == 1
    assert (out / "results.sqlite").exists() and (out / "steps.png").exists()
