"""Stereo calibration (the two-camera case of the one calibration) on the 13 real checkerboard
pairs (shared data, 9 × 6 inner corners), and the stereo files written before one record."""

import copy
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from vts_hw.errors import DataError
from vts_hw.vision.calibration import calibrate_from_corners, calibrate_stereo
from vts_hw.vision.calibration_io import load_calibration
from vts_hw.vision.calibration_uncertainty import compare_pair, rotation_angle_deg
from vts_hw.vision.checkerboard import board_points, find_corners, find_pairs

PATTERN = (9, 6)
NAMES = [f"{i:02d}" for i in range(1, 15) if i != 10]
#: a stereo file as `vts calibrate stereo` wrote them before one calibration record (the real pairs)
OLD_STEREO = Path(__file__).parents[1] / "data" / "calibration-stereo-v1.json"


def own_rms(cal):
    """Each camera's RMS (its own OpenCV fit, where its intrinsics come from)."""
    return [c.rms for c in cal.camera_fits]


@pytest.fixture(scope="module")
def pairs(shared_data):
    return find_pairs(shared_data / "stereo-checkerboard")


@pytest.fixture(scope="module")
def calib(pairs):
    return calibrate_stereo(pairs)


@pytest.fixture(scope="module")
def corners(pairs):
    """Corners of every real pair, found by the module (all 13 pairs have them)."""
    left = [find_corners(cv2.imread(str(lp), cv2.IMREAD_GRAYSCALE)) for lp, _ in pairs]
    right = [find_corners(cv2.imread(str(rp), cv2.IMREAD_GRAYSCALE)) for _, rp in pairs]
    return left, right


@pytest.fixture(scope="module")
def plain_reference(pairs):
    """Straightforward OpenCV: default flags everywhere, findChessboardCorners + cornerSubPix."""
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 0.001)
    obj = np.zeros((54, 3), np.float32)
    obj[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2)
    objs, left, right = [], [], []
    for lp, rp in pairs:
        gl = cv2.imread(str(lp), cv2.IMREAD_GRAYSCALE)
        gr = cv2.imread(str(rp), cv2.IMREAD_GRAYSCALE)
        okl, cl = cv2.findChessboardCorners(gl, PATTERN)
        okr, cr = cv2.findChessboardCorners(gr, PATTERN)
        if okl and okr:
            objs.append(obj)
            left.append(cv2.cornerSubPix(gl, cl, (11, 11), (-1, -1), crit))
            right.append(cv2.cornerSubPix(gr, cr, (11, 11), (-1, -1), crit))
    size = gl.shape[::-1]
    rms1, k1, d1, _, _ = cv2.calibrateCamera(objs, left, size, None, None)
    rms2, k2, d2, _, _ = cv2.calibrateCamera(objs, right, size, None, None)
    rms_s, *_, t, _e, _f = cv2.stereoCalibrate(objs, left, right, k1, d1, k2, d2, size)
    return {"n": len(objs), "left": rms1, "right": rms2, "stereo": rms_s, "baseline": float(np.linalg.norm(t))}


def _rotate_x(deg):
    rot, _ = cv2.Rodrigues(np.array([np.radians(deg), 0.0, 0.0]))
    return rot


# ---- corners -------------------------------------------------------------------------------
def test_pairs_found(pairs):
    assert [lp.stem for lp, _ in pairs] == [f"left{n}" for n in NAMES]
    assert [rp.stem for _, rp in pairs] == [f"right{n}" for n in NAMES]


def test_corners_found_in_every_real_image(corners):
    left, right = corners
    for c in left + right:
        assert c is not None and c.shape == (54, 1, 2)


def test_no_board_gives_none():
    assert find_corners(np.full((480, 640), 128, np.uint8)) is None


def test_colour_image_accepted(pairs):
    img = cv2.imread(str(pairs[0][0]), cv2.IMREAD_COLOR)
    assert find_corners(img).shape == (54, 1, 2)


# ---- calibration vs plain OpenCV -----------------------------------------------------------
def test_all_pairs_used(calib, plain_reference):
    assert plain_reference["n"] == 13
    assert [v.name for v in calib.per_view] == NAMES
    assert calib.skipped == {}
    assert calib.image_size == (640, 480)


def test_rms_within_10_percent_of_plain_opencv(calib, plain_reference):
    left, right = own_rms(calib)
    assert calib.names == ["left", "right"]
    assert left == pytest.approx(plain_reference["left"], rel=0.10)
    assert right == pytest.approx(plain_reference["right"], rel=0.10)
    assert calib.rms == pytest.approx(plain_reference["stereo"], rel=0.10)
    assert 0 < calib.rms < 1.0


def test_baseline_matches_plain_opencv_within_1_percent(calib, plain_reference):
    assert calib.baseline == pytest.approx(plain_reference["baseline"], rel=0.01)
    assert calib.unit == "squares"


def test_per_view_errors_agree_with_stereo_rms(calib):
    errs = np.array([[v.errors["left"], v.errors["right"]] for v in calib.per_view])
    assert np.sqrt(np.mean(errs**2)) == pytest.approx(calib.rms, rel=1e-6)


def test_real_outlier_view_02(calib):
    """Pair 02 is five times the median in the real set (see decision 0012); no other is flagged."""
    assert calib.outliers == ["02"]


def test_projection_matrices_triangulate_board(calib, corners):
    """Triangulating view 03's corners gives the board: neighbouring corners one square apart."""
    left, right = corners
    p1, p2 = calib.projection_matrices()
    assert p1.shape == p2.shape == (3, 4)
    ul = cv2.undistortPoints(left[2], calib.K1, calib.d1, P=calib.K1)
    ur = cv2.undistortPoints(right[2], calib.K2, calib.d2, P=calib.K2)
    hom = cv2.triangulatePoints(p1, p2, ul.reshape(-1, 2).T, ur.reshape(-1, 2).T)
    pts = (hom[:3] / hom[3]).T.reshape(6, 9, 3)
    steps = np.linalg.norm(np.diff(pts, axis=1), axis=2)
    assert np.median(steps) == pytest.approx(1.0, rel=0.02)


def test_square_in_mm_scales_translation(corners, calib):
    left, right = corners
    mm = calibrate_from_corners(left, right, (640, 480), names=NAMES, square=25.0, unit="mm")
    assert mm.baseline == pytest.approx(25.0 * calib.baseline, rel=1e-4)
    assert mm.rms == pytest.approx(calib.rms, rel=1e-4)
    assert compare_pair(mm, calib)["translation"] is None


def test_pairs_without_board_are_skipped(pairs):
    blank = np.full((480, 640), 128, np.uint8)
    imgs = [(cv2.imread(str(lp), 0), cv2.imread(str(rp), 0)) for lp, rp in pairs[:5]]
    imgs.append((imgs[0][0], blank))
    cal = calibrate_stereo(imgs)
    assert cal.skipped == {"pair06": "no 9x6 board found in the right image"}
    assert len(cal.per_view) == 5


def test_too_few_pairs_is_a_data_error(pairs):
    with pytest.raises(DataError, match="at least 3"):
        calibrate_stereo(pairs[:2])


def test_unreadable_image_is_a_data_error(tmp_path, pairs):
    bad = tmp_path / "left99.jpg"
    bad.write_bytes(b"not a jpeg")
    with pytest.raises(DataError, match="left99.jpg"):
        calibrate_stereo([(bad, pairs[0][1])])


# ---- outliers ------------------------------------------------------------------------------
def test_wrong_pairing_flagged(corners):
    """Right corners of pairs 03 and 13 swapped: exactly those two pairs are flagged."""
    left, right = corners
    right = list(right)
    right[2], right[11] = right[11], right[2]
    cal = calibrate_from_corners(left, right, (640, 480), names=NAMES)
    assert cal.outliers == ["03", "13"]


def test_shuffled_corners_flagged(corners):
    left, right = corners
    left = list(left)
    left[7] = np.random.default_rng(1).permutation(left[7])
    cal = calibrate_from_corners(left, right, (640, 480), names=NAMES)
    assert "08" in cal.outliers


# ---- save / load / compare -----------------------------------------------------------------
def test_save_load_round_trip(calib, tmp_path):
    path = calib.save(tmp_path / "calib.json")
    back = load_calibration(path)
    assert back == calib
    assert back.results_data() == calib.results_data()
    np.testing.assert_array_equal(back.R, calib.R)
    assert back.baseline == calib.baseline
    assert back.per_view == calib.per_view
    assert json.loads(path.read_text())["software"] == calib.software


def test_results_data_is_json_ready(calib):
    data = json.loads(json.dumps(calib.results_data()))
    assert data["outliers"] == ["02"]
    assert data["created"].endswith("+00:00")
    assert data["format"] == "vts-hw camera calibration" and data["n_cameras"] == 2
    assert len(data["cameras"][1]["K"]) == 3 and len(data["cameras"][1]["t"]) == 3
    assert len(data["pair_uncertainty"]["stereo_cov"]) == 6


def test_results_text(calib):
    text = calib.results()
    assert "baseline 3.3" in text and "OUTLIER" in text and "rotation between left and right 0.3" in text


def test_a_stereo_file_written_before_loads_as_two_cameras():
    """The file of tests/data as `vts calibrate stereo` wrote it before one record: two cameras
    cam1 (the frame) and cam2 with every figure, uncertainty and lens model it held."""
    data = json.loads(OLD_STEREO.read_text())
    old = load_calibration(OLD_STEREO)
    assert old.names == ["cam1", "cam2"] and old.reference == "cam1"
    np.testing.assert_array_equal(old.K1, data["K1"])
    np.testing.assert_array_equal(old.camera_fits[1].R, data["R"])
    np.testing.assert_array_equal(old.T, data["T"])
    assert [c.rms for c in old.camera_fits] == [data["rms_left"], data["rms_right"]]
    assert old.rms == data["rms_stereo"] and old.baseline == pytest.approx(data["baseline"], rel=1e-12)
    assert [v.errors for v in old.per_view] == [{"cam1": v["left"], "cam2": v["right"]} for v in data["per_view"]]
    assert old.outliers == data["outliers"] == ["02"]
    assert old.uncertainty["stereo"] == data["uncertainty"]["stereo"]
    assert old.uncertainty["camera2"] == data["uncertainty"]["camera2"]
    assert old.camera_fits[0].distortion_model == data["distortion_model"]["camera1"]
    assert compare_pair(old, old)["warnings"] == []


def test_a_stereo_file_written_before_equals_the_calibration_now(calib):
    """The same 13 pairs calibrated now give the figures the old file holds (OpenCV's, to the
    last digits its threads leave free)."""
    old = load_calibration(OLD_STEREO)
    np.testing.assert_allclose(calib.K2, old.K2, rtol=1e-9)
    np.testing.assert_allclose(calib.T, old.T, rtol=1e-8, atol=1e-9)
    assert calib.rms == pytest.approx(old.rms, rel=1e-9)
    assert own_rms(calib) == pytest.approx(own_rms(old), rel=1e-9)
    assert calib.uncertainty["stereo"]["baseline"] == pytest.approx(old.uncertainty["stereo"]["baseline"], rel=1e-6)


@pytest.mark.parametrize(
    ("change", "key"),
    [
        (lambda d: d.pop("R"), "'R'"),
        (lambda d: d.update(K1=[[1, 2], [3, 4]]), "'K1'"),
        (lambda d: d.update(T=[0, "x", 1]), "'T'"),
        (lambda d: d.update(unit="inch"), "'unit'"),
        (lambda d: d.update(rms_left=None), "'rms_left'"),
        (lambda d: d.update(image_size=[640]), "'image_size'"),
        (lambda d: d["per_view"][0].pop("left"), "'per_view[0].left'"),
        (lambda d: d.update(format="something else"), "'format'"),
        (lambda d: d["uncertainty"]["camera1"].update(fx="big"), "'uncertainty.camera1'"),
        (lambda d: d["uncertainty"].update(stereo_cov=[[1.0]]), "'uncertainty.stereo_cov'"),
        (lambda d: d.update(distortion_model=["k1"]), "'distortion_model'"),
    ],
)
def test_bad_stereo_file_names_file_and_key(tmp_path, change, key):
    """A stereo file of the old format with one key spoiled."""
    data = json.loads(OLD_STEREO.read_text())
    change(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(DataError) as err:
        load_calibration(path)
    assert str(path) in str(err.value) and key in str(err.value)


@pytest.mark.parametrize(
    ("change", "key"),
    [
        (lambda d: d["cameras"][1].pop("R"), "'cameras[1].R'"),
        (lambda d: d["cameras"][0].update(K=[[1, 2], [3, 4]]), "'cameras[0].K'"),
        (lambda d: d.update(unit="inch"), "'unit'"),
        (lambda d: d["pair_uncertainty"].update(stereo_cov=[[1.0]]), "'pair_uncertainty.stereo_cov'"),
        (lambda d: d["pair_uncertainty"]["stereo"].update(rx=-1), "'pair_uncertainty.stereo'"),
        (lambda d: d.update(format="something else"), "'format'"),
    ],
)
def test_bad_file_names_file_and_key(calib, tmp_path, change, key):
    data = calib.results_data()
    change(data)
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    with pytest.raises(DataError) as err:
        load_calibration(path)
    assert str(path) in str(err.value) and key in str(err.value)


def test_missing_and_non_json_files(tmp_path):
    with pytest.raises(DataError, match="nothere.json"):
        load_calibration(tmp_path / "nothere.json")
    junk = tmp_path / "junk.json"
    junk.write_text("{not json")
    with pytest.raises(DataError, match="junk.json"):
        load_calibration(junk)


def test_compare_reports_perturbation(calib):
    moved = _moved(calib, K1=(0, 0, 2.0), K2=(1, 2, -1.5))
    moved.camera_fits[1].R = _rotate_x(0.5) @ calib.R
    moved.camera_fits[1].t = calib.T + [0.0, 0.0, 0.1]
    moved.pair = None
    diff = compare_pair(moved, calib)
    assert diff["rotation_deg"] == pytest.approx(0.5, abs=1e-9)
    assert diff["translation"] == pytest.approx(0.1, abs=1e-12)
    assert diff["fx1"] == pytest.approx(2.0) and diff["cy2"] == pytest.approx(-1.5)
    assert diff["fy1"] == diff["cx1"] == diff["fx2"] == 0.0
    assert diff["unit"] == "squares"
    same = compare_pair(calib, calib)
    assert same["rotation_deg"] == 0.0 and same["translation"] == 0.0


def test_rotation_angle_small_angles():
    assert rotation_angle_deg(_rotate_x(0.01)) == pytest.approx(0.01, rel=1e-6)


def test_board_points_unit():
    pts = board_points(PATTERN, 2.0)
    assert pts.shape == (54, 3) and pts[1, 0] == 2.0 and pts[9, 1] == 2.0


# ---- lens model and uncertainty ------------------------------------------------------------
def test_real_pairs_keep_opencvs_five_terms(calib):
    """The wide real lens needs k2, k3 and the tangential terms: 'auto' keeps OpenCV's default."""
    for cam in calib.camera_fits:
        assert cam.distortion_model["fitted"] == ["k1", "k2", "p1", "p2", "k3"]
        assert "auto (BIC)" in cam.distortion_model["chosen_by"]


def test_uncertainty_of_intrinsics_is_opencvs(calib, pairs, corners):
    """Each camera's standard deviations are those cv2.calibrateCameraExtended reports."""
    obj = [board_points(PATTERN)] * len(pairs)
    for cam, side in (("camera1", corners[0]), ("camera2", corners[1])):
        sd = cv2.calibrateCameraExtended(obj, side, (640, 480), None, None)[5].ravel()
        ours = calib.uncertainty[cam]
        for i, name in enumerate(("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")):
            assert ours[name] == pytest.approx(sd[i], rel=1e-3), name
    st = calib.uncertainty["stereo"]
    assert 0.01 < max(st["rx"], st["ry"], st["rz"]) < 1.0  # degrees
    assert 0 < st["baseline"] < 0.01 * calib.baseline


def test_uncertainty_matches_the_spread_of_repeated_calibrations():
    """Corners with known noise (the simulated rig's exact corners + 0.1 px Gaussian): the
    spread of the estimates over repeated noise draws is the predicted standard deviation."""
    from vts_hw.sim_devices import checkerboard as cb
    from vts_hw.sim_devices.scene import Scene

    scene = Scene.reference(1, start_epoch=0.0)
    poses = cb.board_poses(scene, n=12, seed=1)
    exact = [[cb.truth_corners(scene, cam, pose) for pose in poses] for cam in ("cam1", "cam2")]
    rng = np.random.default_rng(0)
    est, predicted = [], []
    for _ in range(30):
        noisy = [[c + rng.normal(0, 0.1, c.shape) for c in side] for side in exact]
        cal = calibrate_from_corners(*noisy, (640, 480), square=cb.SQUARE_MM, unit="mm", distortion="k1")
        est.append([cal.K1[0, 2], cal.K2[0, 0], cal.d1[0], rotation_angle_deg(cal.R)])
        u = cal.uncertainty
        predicted.append([u["camera1"]["cx"], u["camera2"]["fx"], u["camera1"]["k1"], u["stereo"]["ry"]])
    spread = np.std(est, axis=0, ddof=1)
    ratio = spread / np.mean(predicted, axis=0)
    print("spread / predicted (cx1, fx2, k1 of 1, ry):", np.round(ratio, 2))
    assert np.all((ratio > 0.6) & (ratio < 1.6)), ratio


def test_old_file_without_uncertainty_still_loads_and_compares(calib, tmp_path):
    """A stereo file from before uncertainties (0024): no standard deviations, no lens model."""
    data = json.loads(OLD_STEREO.read_text())
    del data["uncertainty"], data["distortion_model"]
    path = tmp_path / "old.json"
    path.write_text(json.dumps(data))
    old = load_calibration(path)
    assert old.uncertainty is None and old.camera_fits[0].distortion_model == {}
    assert "±" not in old.results()
    diff = compare_pair(calib, old)
    assert diff["previous_has_uncertainty"] is False and diff["warnings"] == []
    cx1 = next(r for r in diff["judged"] if r["parameter"] == "cx1")
    assert cx1["sd"] == pytest.approx(np.sqrt(2) * calib.uncertainty["camera1"]["cx"])
    assert compare_pair(old, calib)["judged"] == []  # nothing to judge with: no warnings made up


def _moved(calib, **changes):
    """A copy of ``calib`` with K1/K2 entries moved: {"K1": (row, column, delta)}."""
    moved = copy.deepcopy(calib)
    for key, (i, j, delta) in changes.items():
        moved.camera_fits[int(key[1]) - 1].K[i, j] += delta
    return moved


def test_a_move_beyond_the_uncertainty_is_a_warning(calib):
    sd = calib.uncertainty["camera1"]["cx"]
    combined = np.sqrt(2) * sd
    small = compare_pair(_moved(calib, K1=(0, 2, 2.0 * combined)), calib)
    assert small["warnings"] == []
    big = compare_pair(_moved(calib, K1=(0, 2, 4.0 * combined)), calib)
    assert len(big["warnings"]) == 1
    w = big["warnings"][0]
    assert w.startswith("WARNING: cx1 moved by +") and "4.0 x its combined standard deviation" in w


def test_a_turned_camera_is_a_rotation_warning(calib):
    moved = _moved(calib)
    moved.camera_fits[1].R = _rotate_x(1.0) @ calib.R
    diff = compare_pair(moved, calib)
    assert diff["rotation_deg"] == pytest.approx(1.0)
    assert any(w.startswith("WARNING: rotation moved by +1 deg") for w in diff["warnings"]), diff["warnings"]
    assert not any("cx1" in w or "fx1" in w for w in diff["warnings"])


@pytest.mark.parametrize(
    "text, words",
    [
        ("[" * 5000 + "]" * 5000, "not a JSON calibration file (nested too deeply)."),
        ('{"format": ' + "9" * 5000 + "}", "not a JSON calibration file (Exceeds the limit (4300 digits)"),
    ],
)
def test_json_that_the_json_module_refuses_beyond_syntax(tmp_path, text, words):
    """RecursionError and the int-digits ValueError of json.loads: a DataError naming the file."""
    path = tmp_path / "calibration.json"
    path.write_text(text)
    with pytest.raises(DataError) as err:
        load_calibration(path)
    assert str(err.value).startswith(f"{path}: {words}")


@pytest.mark.parametrize("key", ["square", "K1", "cameras[0].K", "cameras[1].rms"])
def test_a_number_no_float_can_hold(calib, tmp_path, key):
    """A 401-digit JSON integer: json gives an int that float() overflows on (K1: a stereo file
    of the old format, the others today's)."""
    data = json.loads(OLD_STEREO.read_text()) if key == "K1" else calib.results_data()
    if key == "K1":
        data["K1"][0][0] = 10**400
    elif key == "cameras[0].K":
        data["cameras"][0]["K"][0][0] = 10**400
    elif key == "cameras[1].rms":
        data["cameras"][1]["rms"] = 10**400
    else:
        data[key] = 10**400
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(data))
    with pytest.raises(DataError) as err:
        load_calibration(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: key '{key}' must be") and len(msg) < len(str(path)) + 120
