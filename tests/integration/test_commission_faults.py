"""`vts commission`'s refusals and stops, each one sentence and its exit status (docs/faults.md):
a --skip without --why, an input a step needs and was not given, a camera that does not answer;
each recorded in the store as a step that did not pass, never as passed. (A camera still warming
up with --no-wait: tests/integration/test_commission_warmup.py.)"""

from __future__ import annotations

import socket

import pytest

from inprocess_cli import vts
from vts_hw.config import dump_rig
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore
from vts_hw.store.commission import load_state


@pytest.fixture(scope="module")
def rig():
    r = SimRig(n_cameras=2, seed=5).start()
    try:
        with r.env():
            yield r
    finally:
        r.stop()


def _yaml(rig, tmp_path, port=None):
    cfg = dump_rig(rig.config(rig_name="room2", results_url=f"sqlite:///{tmp_path / 'r.sqlite'}"))
    if port is not None:
        cfg = cfg.replace(f"port: {rig.servers['cam1'].port}", f"port: {port}")
    p = tmp_path / "rig.yaml"
    p.write_text(cfg)
    return p, f"sqlite:///{tmp_path / 'r.sqlite'}"


def test_a_skip_needs_a_why(capsys, tmp_path):
    code, _, err = vts(capsys, "commission", "--config", tmp_path / "none.yaml", "--skip", "sync")
    assert code == 2 and err.strip() == (
        "vts: --skip STEP needs --why TEXT (and --why a --skip): the report says why a step was left out"
    )


def test_an_input_not_given_stops_with_what_to_give(rig, capsys, tmp_path):
    y, url = _yaml(rig, tmp_path)
    code, _, err = vts(capsys, "commission", "--config", y, "-o", tmp_path / "c", "--from", "calibration")
    assert code == 2
    assert err.strip().endswith(
        "vts: the calibration needs --checkerboards DIR: checkerboard images of every camera "
        "(DIR/cam1/01.png, ... or cam1_01.png; each view seen by two cameras or more, 15-20 "
        "poses over the field of view); then `vts commission --resume` with it"
    )
    with ResultsStore(url) as store:
        runs = store.runs("commission-step")
        assert [r.status for r in runs] == ["aborted"]
        assert runs[0].notes.startswith(
            "commissioning (new) step calibration\naborted: the calibration needs --checkerboards DIR"
        )
        (s,) = load_state(store, "room2").steps.values()  # the newest attempt of the step: aborted, never passed
        assert s.step == "calibration" and s.aborted and not s.passed and s.why().startswith("the calibration needs")


def test_a_camera_that_does_not_answer_is_exit_4(rig, capsys, tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        free = s.getsockname()[1]
    y, _ = _yaml(rig, tmp_path, port=free)
    code, _, err = vts(capsys, "commission", "--config", y, "-o", tmp_path / "c", "--from", "warmup")
    last = err.strip().splitlines()[-1]
    assert code == 4 and last == f"vts: camera cam1 at http://127.0.0.1:{free} is unreachable (connection refused)", err


def test_a_ledger_run_with_no_commissioning_id_is_no_step_of_one(tmp_path):
    """A ``commission_id`` stored without a value (a store edited by hand: the ledger always
    writes one) is not taken for a step of a commissioning, and reading the state never fails."""
    from vts_hw.catalog import COMMISSION_STEP

    with ResultsStore(f"sqlite:///{tmp_path / 'r.sqlite'}") as store:
        with store.begin_run(COMMISSION_STEP.name, rig="room2") as h:
            h.measure("calibration", "commission_id", None, status="OK")
            h.measure("calibration", "step_passed", 1.0, status="OK")
        state = load_state(store, "room2")
    assert state.cid is None and state.steps == {}
