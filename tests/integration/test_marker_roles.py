"""Every marker known by what it is (issue 33 §3, vts_hw/vision/marker_roles.py): the drift
baseline and the daily QA against the simulated rig over HTTP with a breathing patient, or the
phantom, on the table; the console names the markers as the QA does."""

import math

import numpy as np
import pytest

from vts_hw.console.markers import find_markers
from vts_hw.console.names import MarkerNames, wall_points
from vts_hw.drivers.registry import open_camera
from vts_hw.procedures.baseline import NoMarkers, take_baselines
from vts_hw.procedures.daily import QARun
from vts_hw.sim_devices.patient_rig import PatientOptions
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.sync_truth import write_true_calibration
from vts_hw.tolerance import State
from vts_hw.vision.marker_roles import PATIENT, PHANTOM, WALL, roles_of_positions

PX_DEG = math.degrees(math.atan(1.0 / 3370.0))  # one pixel of the reference camera's focal length


def _mapped(rig, folder):
    cal, mp = write_true_calibration(rig.scene, folder)
    return rig.config(calibration={"stereo": str(cal), "spect": str(mp)})


def _baselines(cfg):
    cams = [open_camera(c) for c in cfg.cameras]
    try:
        return {b.camera: b for b in take_baselines(cams, frames=5, rig=cfg).baselines}
    finally:
        for c in cams:
            c.close()


def _drift(cfg, baselines):
    """The drift QA of every camera (the daily set's drift step, its stray pass across cameras)."""
    return QARun(cfg, baselines=baselines, steps=("drift",), n_frames=3, open_camera=open_camera).run()


def _truth_walls(rig, cam, t):
    """The wall markers' true pixels in camera ``cam`` at ``t``."""
    _, markers, uv, visible = rig.scene.project_markers(cam, t)
    return np.array([uv[i] for i, m in enumerate(markers) if visible[i] and m.id.startswith("W")])


@pytest.fixture(scope="module")
def breathing(tmp_path_factory):
    folder = tmp_path_factory.mktemp("breathing")
    with SimRig(n_cameras=2, seed=0, patient=PatientOptions(moves=0)) as rig, rig.env():
        cfg = _mapped(rig, folder)
        yield rig, cfg, _baselines(cfg)


def test_baseline_with_the_patient_breathing_keeps_the_wall_markers_and_the_qa_is_ok(breathing):
    rig, cfg, baselines = breathing
    import time

    for name, b in baselines.items():
        walls = _truth_walls(rig, name, time.time())
        assert len(b.markers) == len(walls) >= 3, b
        for m in b.markers:  # every baseline marker is a wall marker (none of the patient's)
            assert np.min(np.hypot(*(walls - (m.x, m.y)).T)) < 1.0, (name, m)
        assert sum(r.role == PATIENT for _, _, r in b.others) >= 4  # the patient's markers, left out with why
    res = _drift(cfg, baselines)
    assert res.state == State.OK, res.results()
    for c in res.cameras:
        assert abs(c.drift.drift_px[0]) < 0.1 and abs(c.drift.drift_px[1]) < 0.1 and not c.drift.strays
        assert any(r.role == PATIENT for _, _, r in c.drift.others)
    _console_agrees(res, baselines)  # (4) the console names the same markers the same way


def test_a_camera_whose_markers_are_all_the_patients_sets_no_baseline(breathing):
    """The wall hidden (its markers gone from the scene), the patient breathing in view: every
    marker moves, none is a wall marker: no baseline, one sentence naming the camera, exit 4."""
    rig, cfg, _ = breathing
    walls = rig.scene.wall_markers
    rig.scene.wall_markers = []
    try:
        with pytest.raises(NoMarkers, match=r"camera cam\d: no wall markers found with the LED on") as e:
            _baselines(cfg)
    finally:
        rig.scene.wall_markers = walls
    assert e.value.exit_code == 4


def test_a_wall_drift_of_1_px_is_found_with_the_patient_breathing(breathing):
    rig, cfg, baselines = breathing
    rig.sources["cam1"].set_optics(yaw_deg=PX_DEG)  # cam1 turns 1 px to its right: the wall moves left
    try:
        res = _drift(cfg, baselines)
    finally:
        rig.sources["cam1"].set_optics(yaw_deg=0.0)
    by = {c.camera: c.drift for c in res.cameras}
    assert by["cam1"].drift_px[0] == pytest.approx(-1.0, abs=0.15), res.results()
    assert abs(by["cam2"].drift_px[0]) < 0.1 and abs(by["cam2"].drift_px[1]) < 0.1


def _console_agrees(res, baselines):
    """The QA's frames, labelled by the console's names (the baseline's wall markers, the
    worker's pictures one by one): a marker the QA matched to a wall marker has that name on the
    console, one the QA found moving is the patient's there too, and no other is."""
    names = MarkerNames()
    for c in res.cameras:
        d, base = c.drift, baselines[c.camera]
        names.set(c.camera, "wall", wall_points(base), source="baseline")
        for seq, f in enumerate(d.frames_on):
            found = find_markers(c.camera, seq, f.jpeg)
            names.seen(c.camera, [(m["x"], m["y"]) for m in found.markers])
        marks, _ = names.label(c.camera, list(found.markers))
        last = np.array([(b.x, b.y) for b in d.detections[-1].blobs])
        near = {i: int(np.argmin(np.hypot(*(last - p).T))) for i, p in enumerate(base.points())}
        console = {int(np.argmin(np.hypot(*(last - (mk["x"], mk["y"])).T))): mk for mk in marks}
        for i, j in near.items():  # the QA's wall markers in its last frame
            assert console[j]["kind"] == "wall" and console[j]["name"] == base.markers[i].id
        moving = [(x, y) for x, y, r in d.others if r.role == PATIENT]
        patient = [mk for mk in marks if mk["kind"] == "band" and mk["name"] == PATIENT]
        assert moving and len(patient) == len(moving), (marks, d.others)
        assert len(marks) == len(near) + len(patient) + sum(r.role != PATIENT for _, _, r in d.others)


def test_the_phantom_on_the_table_is_not_a_wall_marker(tmp_path):
    with SimRig(n_cameras=2, seed=5) as rig, rig.env():
        rig.scene.add_phantom()
        cfg = _mapped(rig, tmp_path)
        baselines = _baselines(cfg)
        import time

        for name, b in baselines.items():
            walls = _truth_walls(rig, name, time.time())
            assert len(b.markers) == len(walls), b
            spheres = [r for _, _, r in b.others if r.role == PHANTOM]
            assert len(spheres) >= 5 and all(r.name.startswith("S") for r in spheres), b.others
        res = _drift(cfg, baselines)
        assert res.state == State.OK, res.results()
        assert all(not c.drift.strays for c in res.cameras)


def test_roles_of_positions_for_the_patient_paths():
    """The 3D entry point: a still marker outside the volume is a wall marker, one inside is not;
    the breathing ones split into chest (head end) and abdomen."""
    t = np.linspace(0, 6, 60)
    breath = 3.0 * np.sin(2 * np.pi * t / 4)[:, None]
    xyz = np.zeros((60, 4, 3))
    xyz[:, 0] = (-222, 6, 486)  # a wall marker beyond the gantry (the sim's W1)
    xyz[:, 1] = (0, -50, -20)  # a still sphere on the table
    xyz[:, 2] = np.column_stack([np.zeros(60), 80 + breath[:, 0], np.full(60, -40.0)])
    xyz[:, 3] = np.column_stack([np.zeros(60), 85 + 3 * breath[:, 0], np.full(60, 200.0)])
    from vts_hw.vision.aim_settings import AimSettings
    from vts_hw.vision.marker_roles import TableSpace

    space = TableSpace.from_settings(AimSettings(table_z_mm=(-1200.0, 330.0)))
    roles = roles_of_positions(xyz, space=space)
    assert [r.role for r in roles] == [WALL, "unknown", "chest", "abdomen"], roles
    no_map = roles_of_positions(xyz, frame="vts")
    assert no_map[1].role == WALL and "no VTS -> SPECT mapping" in no_map[1].reason
