"""The step test's analysis with four cameras: the phantom found among the points matched across
every view, scored against the simulated SPECT's truth, beside the head pair alone."""

import numpy as np
import pytest

from vts_hw.errors import DataError
from vts_hw.procedures.steps import SeenPosition, analyze_positions, step_plan
from vts_hw.sim_devices.scene import Scene
from vts_hw.sim_devices.step_table import SimSpectSource, SimTable
from vts_hw.vision.registration import RigidTransform

T0 = 1_700_000_000.0


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    """Six positions seen by four cameras (projected centres + 0.05 px noise, walls included),
    the SPECT's volume of each; the true cameras (world frame = SPECT frame)."""
    out = tmp_path_factory.mktemp("steps4")
    scene = Scene.reference(seed=0, n_cameras=4, start_epoch=T0)
    scene.add_phantom()
    now = [T0]

    def clock():
        now[0] += 10.0
        return now[0]

    table, spect = SimTable(scene, clock, seed=1), SimSpectSource(scene, clock, out / "spect", seed=1)
    rng = np.random.default_rng(2)
    plan = step_plan(2, 2)[:-1]  # no hand-made free move: its view check is for the stereo pair
    seen = []
    for pos in plan:
        table.move_to(pos)
        t = clock()
        pts = {
            c: (np.array([(u, v) for _, u, v in scene.truth(c, t)]) + rng.normal(0, 0.05, (1, 2))).tolist()
            for c in scene.camera_names
        }
        spect.acquired(pos)
        seen.append(SeenPosition(pos.label, pos.kind, t, pts))
    cams = {c: scene.camera_at(c, T0) for c in scene.camera_names}
    return seen, plan, cams, spect


def test_four_cameras_find_the_phantom_and_agree_with_the_spect(session):
    seen, plan, cams, spect = session
    identity = RigidTransform(np.eye(3), np.zeros(3))
    four = analyze_positions(seen, plan, cams, identity, spect)
    pair = analyze_positions(
        [SeenPosition(s.label, s.kind, s.host_time, {c: s.points_px[c] for c in ("cam1", "cam2")}) for s in seen],
        plan,
        {c: cams[c] for c in ("cam1", "cam2")},
        identity,
        spect,
    )
    truth = np.array([spect.truth[s.label] for s in seen])
    # the analysis orders spheres as the SPECT found them: each against its nearest true centre
    err4 = np.linalg.norm(four.vts[:, :, None] - truth[:, None], axis=3).min(axis=2)
    err2 = np.linalg.norm(pair.vts[:, :, None] - truth[:, None], axis=3).min(axis=2)
    assert err4.max() < 0.5 and np.sqrt(np.mean(err4**2)) < np.sqrt(np.mean(err2**2))
    assert four.diffs.mean() < 1.0  # VTS against the SPECT's own centroids (voxel noise)
    assert len(four.labels) == len(plan) and four.vts.shape == (len(plan), 7, 3)


def test_a_camera_missing_from_the_calibration_is_named(session):
    seen, plan, cams, spect = session
    three = {c: cams[c] for c in ("cam1", "cam2", "cam4")}
    with pytest.raises(DataError, match="cam3 not in the calibration"):
        analyze_positions(seen, plan, three, RigidTransform(np.eye(3), np.zeros(3)), spect)
