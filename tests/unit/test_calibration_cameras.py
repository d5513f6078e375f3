"""N-camera calibration: the real pairs against plain OpenCV, simulated rooms of 3 and 4 cameras
whose views no view spans fully, refused view graphs, the calibration file and the files
written before one calibration record (stereo and N-camera)."""

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from vts_hw.errors import DataError
from vts_hw.vision.calibration import calibrate_cameras, calibrate_stereo
from vts_hw.vision.calibration_io import CameraCalibration, load_calibration
from vts_hw.vision.checkerboard import board_points, find_corners, find_pairs
from vts_hw.vision.multi_compare import compare_cameras
from vts_hw.vision.view_graph import ViewGraph

SIZE = (640, 480)


@pytest.fixture(scope="module")
def real(shared_data):
    """Corners of the 13 real pairs as camera -> view -> corners."""
    out = {"left": {}, "right": {}}
    for lp, rp in find_pairs(shared_data / "stereo-checkerboard"):
        out["left"][lp.stem[4:]] = find_corners(cv2.imread(str(lp), 0))
        out["right"][rp.stem[5:]] = find_corners(cv2.imread(str(rp), 0))
    return out


@pytest.fixture(scope="module")
def plain_opencv(real):
    """Default flags everywhere: calibrateCamera per camera, then stereoCalibrate."""
    views = sorted(real["left"])
    obj = [board_points()] * len(views)
    left = [real["left"][v] for v in views]
    right = [real["right"][v] for v in views]
    _, k1, d1, _, _ = cv2.calibrateCamera(obj, left, SIZE, None, None)
    _, k2, d2, _, _ = cv2.calibrateCamera(obj, right, SIZE, None, None)
    rms, *_, t, _e, _f = cv2.stereoCalibrate(obj, left, right, k1, d1, k2, d2, SIZE)
    return {"rms": rms, "baseline": float(np.linalg.norm(t))}


@pytest.fixture(scope="module")
def real_calib(real):
    return calibrate_cameras(real, {"left": SIZE, "right": SIZE})


# ---- N = 2 on real data ---------------------------------------------------------------------
def test_real_pairs_equal_plain_opencv(real_calib, plain_opencv):
    """The bundle adjustment refines the intrinsics too, with a robust loss; on the real pairs it
    stays on OpenCV's figures (measured: RMS +0.7 %, baseline -0.3 %)."""
    assert real_calib.rms == pytest.approx(plain_opencv["rms"], rel=0.01)
    assert real_calib.baseline == pytest.approx(plain_opencv["baseline"], rel=0.005)
    assert real_calib.initial["rms"] == pytest.approx(plain_opencv["rms"], rel=1e-6)  # the pairwise start
    assert real_calib.names == ["left", "right"] and real_calib.outliers == ["02"]
    assert [v.name for v in real_calib.per_view] == sorted(real_calib.view_graph["views"])
    assert real_calib.view_graph["connected"] is True
    assert all(c.sd and 0 < c.sd["fx"] < 5 for c in real_calib.camera_fits)


def test_stereo_is_the_two_camera_case(real, real_calib, shared_data):
    """`calibrate_stereo` runs the same steps with the intrinsics fixed: OpenCV's figures exactly."""
    st = calibrate_stereo(find_pairs(shared_data / "stereo-checkerboard"))
    assert st.rms == pytest.approx(real_calib.initial["rms"], rel=1e-6)
    assert st.names == real_calib.names and st.pair is not None and real_calib.pair is None
    fixed = calibrate_cameras(real, {"left": SIZE, "right": SIZE}, intrinsics="fixed", loss="linear")
    assert fixed.rms == pytest.approx(st.rms, rel=1e-6)
    assert [c.rms for c in fixed.camera_fits] == pytest.approx([c.rms for c in st.camera_fits], rel=1e-9)  # own fits
    assert fixed.baseline == pytest.approx(st.baseline, rel=1e-5)
    np.testing.assert_allclose(fixed.R, st.R, atol=1e-6)


def test_the_robust_loss_keeps_a_wrong_pairing_from_pulling(real, plain_opencv):
    """Right images of views 03 and 13 swapped: a plain squared loss refining everything is
    dragged off (baseline about 9x), the robust loss flags both views and keeps the baseline."""
    swapped = {"left": real["left"], "right": dict(real["right"])}
    swapped["right"]["03"], swapped["right"]["13"] = real["right"]["13"], real["right"]["03"]
    robust = calibrate_cameras(swapped, {"left": SIZE, "right": SIZE})
    assert {"03", "13"} <= set(robust.outliers)
    assert robust.baseline == pytest.approx(plain_opencv["baseline"], rel=0.01)
    plain = calibrate_cameras(swapped, {"left": SIZE, "right": SIZE}, loss="linear")
    assert abs(plain.baseline / plain_opencv["baseline"] - 1) > 0.05


# ---- simulated rooms -------------------------------------------------------------------------
def _sim_corners(scene, per_pair, seed, noise_px=0.1):
    from vts_hw.sim_devices import checkerboard as cb
    from vts_hw.sim_devices.board_plan import plan_views

    rng = np.random.default_rng(seed)
    corners = {c: {} for c in scene.camera_names}
    k = 0
    for (a, b), poses in plan_views(scene, per_pair, seed):
        for pose in poses:
            k += 1
            for cam in (a, b):
                uv = cb.truth_corners(scene, cam, pose)
                corners[cam][f"v{k:02d}"] = uv + rng.normal(0, noise_px, uv.shape)
    return corners


def _head_and_foot(seed=0):
    """Four cameras in pairs at the head and foot ends of the table, facing each other."""
    from vts_hw.sim_devices.scene import CameraModel, Scene

    scene = Scene.reference(seed, n_cameras=4, start_epoch=0.0)
    cams = []
    for i, c in enumerate(scene.cameras.values()):
        x, z = (-600.0 if i % 2 == 0 else 600.0), (-3530.0 if i < 2 else 3530.0)
        cams.append(CameraModel.look_at(c.name, (x, 1100.0, z), (0.0, 0.0, 0.0), c.K, c.dist))
    scene.cameras = {c.name: c for c in cams}
    return scene


@pytest.mark.parametrize("layout", ["reference-3", "reference-4", "head-and-foot-4"])
def test_simulated_rooms_against_the_truth(layout):
    from vts_hw.sim_devices.scenarios.calibration_views import cameras_against_truth, fov_points, true_cameras
    from vts_hw.sim_devices.scene import Scene

    scene = (
        _head_and_foot()
        if layout.startswith("head")
        else Scene.reference(3, n_cameras=int(layout[-1]), start_epoch=0.0)
    )
    ends = {int(np.sign(c.center[2])) for c in scene.cameras.values()}
    assert ends == {-1, 1}  # the reference rooms too: cameras at the head and at the foot end
    corners = _sim_corners(scene, 6, 3)
    graph = ViewGraph(list(corners), {c: list(v) for c, v in corners.items()})
    assert graph.connected
    assert max(len(cams) for cams in graph.seen_by.values()) < len(corners)  # no view spans all
    calib = calibrate_cameras(corners, {c: SIZE for c in corners}, square=50.0, unit="mm", distortion="k1")
    truth = true_cameras(scene, square_mm=50.0)
    t = cameras_against_truth(calib, truth, fov_points(scene))
    print(layout, json.dumps(t["points_3d"]))
    assert calib.rms < 0.2 and calib.outliers == []
    assert t["points_3d"]["n"] > 300
    assert t["points_3d"]["rms_after_rigid_fit"] < 0.1  # mm: the shape of the field is right
    # mm, mostly the scale along the view: a focal length 0.1 % off is 4 mm at 3.7 m (0024)
    assert t["points_3d"]["rms"] < 25.0
    for name, rows in t["cameras"].items():
        sd = calib.camera(name).sd
        assert abs(rows["fx"]["error_percent"]) < 0.5, (name, rows["fx"])
        for key in ("fx", "cx", "cy", "k1"):  # honest standard deviations (measured: within 2.5)
            assert abs(rows[key]["error"]) < 4 * rows[key]["sd"], (name, key, rows[key])
        if name != calib.reference:
            assert rows["rotation_error_deg"] < 4 * np.hypot(sd["rx"], np.hypot(sd["ry"], sd["rz"])), name
            assert rows["position_error"] < 4 * np.hypot(sd["tx"], np.hypot(sd["ty"], sd["tz"])), name


# ---- view graphs that are refused ----------------------------------------------------------
def test_disconnected_views_are_refused(real):
    corners = {"a": {"1": 0, "2": 0}, "b": {"1": 0, "2": 0}, "c": {"3": 0, "4": 0}, "d": {"3": 0, "4": 0}}
    with pytest.raises(DataError) as err:
        calibrate_cameras(corners, {c: SIZE for c in corners})
    assert str(err.value) == (
        "the checkerboard views do not connect the cameras: a, b | c, d share no view"
        " across the groups; add views that a camera of each group sees together."
    )


def test_a_camera_in_no_shared_view_is_named():
    graph = ViewGraph(["a", "b", "c"], {"a": ["1", "2"], "b": ["1", "2"], "c": ["3"]})
    with pytest.raises(DataError, match="^camera c found the board in no view that another camera also saw"):
        graph.check()
    assert graph.spanning_tree() == [("a", "b")] and not graph.connected


# ---- the file ------------------------------------------------------------------------------
def test_n_camera_file_round_trip_and_readers(real_calib, tmp_path):
    from vts_hw.tracking.processing import cameras_from_calibration
    from vts_hw.vision.calibration_io import read_calibration as sync_load

    path = real_calib.save(tmp_path / "cal.json")
    back = load_calibration(path)
    assert isinstance(back, CameraCalibration) and back == real_calib
    assert sync_load(path) == real_calib
    assert back.baseline == pytest.approx(real_calib.baseline)
    cams = back.cameras()
    assert [c.name for c in cams] == ["left", "right"] and np.allclose(cams[0].R, np.eye(3))
    # its first two cameras as a pair (camera 2 from camera 1), named after the recording's
    assert np.allclose(back.T, back.camera_fits[1].t) and back.unit == "squares"
    mm = CameraCalibration(back.camera_fits, back.pattern, 25.0, "mm", back.rms, back.per_view, back.outlier_rule)
    assert set(cameras_from_calibration(mm, ["cam1", "cam2"])) == {"cam1", "cam2"}
    assert set(cameras_from_calibration(mm, ["left", "right", "x"])) == {"left", "right"}
    # every camera of an N-camera file reaches tracking (not only the first two)
    third = type(back.camera_fits[0])(
        "third",
        back.camera_fits[1].K,
        back.camera_fits[1].d,
        back.camera_fits[1].R,
        back.camera_fits[1].t + 100.0,
        back.camera_fits[1].image_size,
    )
    three = CameraCalibration(
        [*mm.camera_fits, third], back.pattern, 25.0, "mm", back.rms, back.per_view, back.outlier_rule
    )
    assert list(cameras_from_calibration(three, ["cam1", "cam2", "cam3"])) == ["cam1", "cam2", "cam3"]
    from vts_hw.vision.camera_set import load_cameras

    cams3 = load_cameras(three.save(tmp_path / "three.json"))
    assert list(cams3) == ["left", "right", "third"] and np.allclose(cams3["third"].t, third.t)


@pytest.mark.parametrize(
    "change, key",
    [
        (lambda d: d["cameras"][1].pop("K"), "'cameras[1].K'"),
        (lambda d: d["cameras"][0].update(t=[0, "x", 1]), "'cameras[0].t'"),
        (lambda d: d.update(cameras=d["cameras"][:1]), "'cameras'"),
        (lambda d: d.update(unit="inch"), "'unit'"),
        (lambda d: d["per_view"][0]["errors"].update(left=None), "'per_view[0].errors.left'"),
        (lambda d: d.update(format="x"), "'format'"),
    ],
)
def test_bad_n_camera_file_names_file_and_key(real_calib, tmp_path, change, key):
    data = real_calib.results_data()
    change(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(DataError) as err:
        load_calibration(path)
    assert str(err.value).startswith(f"{path}: key {key}")


OLD_STEREO_FILE = {  # a stereo file as vts-hw wrote it before N cameras (and before 0024's keys)
    "format": "vts-hw stereo calibration",
    "format_version": 1,
    "K1": [[3370.0, 0.0, 320.0], [0.0, 3370.0, 240.0], [0.0, 0.0, 1.0]],
    "d1": [-0.05, 0.0, 0.0, 0.0, 0.0],
    "K2": [[3360.0, 0.0, 318.0], [0.0, 3360.0, 241.0], [0.0, 0.0, 1.0]],
    "d2": [-0.05, 0.0, 0.0, 0.0, 0.0],
    "R": [[0.98, 0.0, -0.19899748742132398], [0.0, 1.0, 0.0], [0.19899748742132398, 0.0, 0.98]],
    "T": [-1190.0, 2.0, 120.0],
    "image_size": [640, 480],
    "pattern": [9, 6],
    "square": 50.0,
    "unit": "mm",
    "baseline": 1196.05,
    "rms_left": 0.06,
    "rms_right": 0.07,
    "rms_stereo": 0.065,
    "per_view": [{"name": "sim01", "left": 0.05, "right": 0.07, "outlier": False}],
    "outlier_rule": "pair RMS (both images) > 3 x median of the pairs",
    "outliers": [],
    "skipped": {},
    "created": "2026-10-01T08:00:00+00:00",
    "software": "0.1.0",
}


def test_old_two_camera_file_still_loads(tmp_path):
    from vts_hw.tracking.processing import cameras_from_calibration
    from vts_hw.vision.calibration_io import read_calibration as sync_load

    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(OLD_STEREO_FILE))
    two = load_calibration(path)
    assert isinstance(two, CameraCalibration) and two.baseline == pytest.approx(np.linalg.norm([-1190, 2, 120]))
    assert sync_load(path) == two
    assert set(cameras_from_calibration(two, ["cam1", "cam2"])) == {"cam1", "cam2"}
    # a stereo file's cameras have no names of their own: the rig's first two, in order
    assert list(cameras_from_calibration(two, ["head1", "cam1", "cam2"])) == ["head1", "cam1"]
    assert two.names == ["cam1", "cam2"] and np.allclose(two.T, OLD_STEREO_FILE["T"])
    assert np.allclose(two.R, OLD_STEREO_FILE["R"]) and two.uncertainty is None
    assert two.per_view[0].errors == {"cam1": 0.05, "cam2": 0.07}
    # a new calibration is compared with it camera by camera
    diff = compare_cameras(two, two)
    assert diff["cameras"]["cam2"]["rotation_deg"] == 0.0 and diff["warnings"] == []


def test_an_n_camera_file_written_before_loads_as_it_was(real_calib):
    """The file of tests/data as `vts calibrate cameras` wrote it before one calibration record
    (the real pairs): every figure as written, and what the same images give now."""
    path = Path(__file__).parents[1] / "data" / "calibration-cameras-v1.json"
    data = json.loads(path.read_text())
    old = load_calibration(path)
    assert old.names == ["left", "right"] and old.pair is None and old.uncertainty is None
    assert old.rms == data["rms"] and [c.rms for c in old.camera_fits] == [c["rms"] for c in data["cameras"]]
    np.testing.assert_array_equal(old.camera_fits[1].t, data["cameras"][1]["t"])
    assert old.camera_fits[1].sd == data["cameras"][1]["sd"] and old.outliers == data["outliers"]
    assert old.adjustment == data["adjustment"] and old.view_graph == data["view_graph"]
    assert real_calib.rms == pytest.approx(old.rms, rel=1e-6)
    assert real_calib.baseline == pytest.approx(old.baseline, rel=1e-6)


def test_not_a_calibration_file(tmp_path):
    path = tmp_path / "notes.json"
    path.write_text("{}")
    with pytest.raises(DataError, match="is neither 'vts-hw camera calibration' nor"):
        load_calibration(path)
