"""The daily drift QA on a four-camera rig (a pair at each end) with the SPECT heads in the
room: per camera, over HTTP, each against its own wall; parked heads hide nothing, heads on
their orbit hide wall markers and the QA says which camera lost which."""

import pytest

from qa_runs import baselines_now, run_qa
from vts_hw.config import parse_rig
from vts_hw.drivers.registry import open_camera
from vts_hw.sim_devices.gantry import Gantry
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore
from vts_hw.store.baselines import load_baseline
from vts_hw.tolerance import State


@pytest.fixture()
def rig(tmp_path):
    with SimRig(n_cameras=4, seed=1) as r, r.env():
        r.scene.gantry = Gantry()  # the heads in the room, parked
        data = r.config().model_dump(mode="json", exclude_none=True)
        data["results"] = {"url": f"sqlite:///{tmp_path / 'results.sqlite'}"}
        cfg = parse_rig(data, "test rig")
        with ResultsStore(cfg.results.url) as store:
            yield r, cfg, store


def test_drift_qa_per_camera_with_four_cameras(rig):
    sim, cfg, store = rig
    baselines_now(cfg, store, frames=3)
    for name in ("cam1", "cam2", "cam3", "cam4"):
        assert len(load_baseline(store, name).markers) == 5, name  # each sees its own wall
    res = run_qa(cfg, store, open_camera=open_camera, n_frames=2, steps=("drift",))
    assert res.state == State.OK, res.results()
    assert [c.camera for c in res.cameras] == ["cam1", "cam2", "cam3", "cam4"]
    # the heads on a body-contouring orbit at 30 deg hide wall markers from some cameras
    sim.scene.gantry.step_and_shoot(sim.clock.now() - 1.0, n_steps=0, start_deg=30.0, radius_mm=230.0)
    hidden = run_qa(cfg, store, open_camera=open_camera, n_frames=2, steps=("drift",))
    missing = {
        c.camera: v
        for c in hidden.cameras
        for subj, metric, v, _, _ in c.measures
        if metric == "markers_missing" and subj == c.camera
    }
    assert hidden.state == State.ACTION and sum(missing.values()) > 0, missing
    for c in hidden.cameras:  # judged per camera: one that lost markers is not OK
        assert (c.state != State.OK) == (missing[c.camera] > 0), (c.camera, missing)
