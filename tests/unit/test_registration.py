"""Rigid registration: Kabsch, FRE / leave-one-out TRE, Euler angles, differences, JSON files."""

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import vts_hw
from vts_hw.errors import DataError
from vts_hw.sim_devices.scene import PHANTOM_LAYOUT
from vts_hw.vision.registration import RigidTransform, difference, fre, kabsch, loo_tre

PHANTOM = np.array(list(PHANTOM_LAYOUT.values()))


def random_transform(rng, shift=500.0) -> RigidTransform:
    return RigidTransform(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-shift, shift, 3))


# ---------------------------------------------------------------- Kabsch
def test_known_rotation_and_translation_are_recovered():
    rng = np.random.default_rng(0)
    for _ in range(20):
        T = random_transform(rng)
        A = rng.uniform(-100, 100, (7, 3))
        est = kabsch(A, T.apply(A))
        assert np.abs(est.R - T.R).max() < 1e-9
        assert np.abs(est.t - T.t).max() < 1e-9
        assert np.linalg.det(est.R) == pytest.approx(1.0, abs=1e-12)


def test_coplanar_points_give_a_rotation_not_a_reflection():
    """Planar sets are where the plain SVD solution can come out as a reflection."""
    rng = np.random.default_rng(1)
    A = np.column_stack([rng.uniform(-50, 50, (6, 2)), np.zeros(6)])
    for _ in range(20):
        T = random_transform(rng)
        est = kabsch(A, T.apply(A) + rng.normal(0, 0.01, (6, 3)))
        assert np.linalg.det(est.R) > 0
        assert np.degrees(np.linalg.norm(Rotation.from_matrix(est.R.T @ T.R).as_rotvec())) < 0.1


def test_mirrored_data_gives_the_best_proper_rotation():
    A = PHANTOM - PHANTOM.mean(axis=0)
    B = A * np.array([-1.0, 1.0, 1.0])  # a mirror image: no rotation maps A onto B
    est = kabsch(A, B)
    assert np.linalg.det(est.R) == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(est.R @ est.R.T, np.eye(3), atol=1e-12)
    # the naive SVD answer (no fix) is the reflection diag(-1, 1, 1) with zero residual
    U, _, Vt = np.linalg.svd(A.T @ B)
    naive = Vt.T @ U.T
    assert np.linalg.det(naive) < 0
    assert fre(A, B, est) > 10.0  # it cannot fit, and says so


def test_bad_inputs():
    with pytest.raises(ValueError):
        kabsch(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError):
        kabsch(np.zeros((4, 3)), np.zeros((5, 3)))
    line = np.outer(np.arange(5.0), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="collinear"):
        kabsch(line, line)


# ---------------------------------------------------------------- FRE and LOO-TRE
def test_fre_and_loo_tre_known_values_for_a_uniform_scaling():
    """B = s * A (A centred). The best rigid fit is the identity, so FRE is the RMS of
    (s - 1)|a_i|; leaving point i out shifts the others' centroid by -a_i/(N-1), which gives
    exactly TRE_i = (s - 1)|a_i| * N / (N - 1)."""
    A = PHANTOM - PHANTOM.mean(axis=0)
    s, n = 1.002, len(A)
    B = s * A
    T = kabsch(A, B)
    assert np.allclose(T.R, np.eye(3), atol=1e-12) and np.allclose(T.t, 0, atol=1e-12)
    r = np.linalg.norm(A, axis=1)
    assert fre(A, B, T) == pytest.approx((s - 1) * np.sqrt(np.mean(r**2)), rel=1e-9)
    tre = loo_tre(A, B)
    assert np.allclose(tre.per_point, (s - 1) * r * n / (n - 1), rtol=1e-9)
    assert tre.rms == pytest.approx((s - 1) * np.sqrt(np.mean(r**2)) * n / (n - 1), rel=1e-9)
    assert tre.max == pytest.approx(tre.per_point.max())


def test_fre_and_tre_on_noisy_points_follow_theory():
    """Isotropic localisation noise sigma per axis (FLE^2 = 3 sigma^2): the expected FRE^2 is
    (1 - 2/N) FLE^2 (Fitzpatrick et al. 1998), and the leave-one-out error is larger than FRE."""
    rng = np.random.default_rng(5)
    sigma, n = 0.2, len(PHANTOM)
    fre2, tre2, tre_ge_fre = [], [], 0
    for _ in range(400):
        T = random_transform(rng)
        A = PHANTOM + rng.normal(0, sigma, PHANTOM.shape)
        B = T.apply(PHANTOM) + rng.normal(0, sigma, PHANTOM.shape)
        f = fre(A, B, kabsch(A, B))
        t = loo_tre(A, B).rms
        fre2.append(f**2)
        tre2.append(t**2)
        tre_ge_fre += t >= f
    # noise on both sets: FLE^2 = 2 * 3 sigma^2
    expected = (1 - 2 / n) * 6 * sigma**2
    assert np.mean(fre2) == pytest.approx(expected, rel=0.1)
    assert tre_ge_fre == 400
    print(
        f"sigma {sigma} mm per axis per set: FRE {np.sqrt(np.mean(fre2)):.3f} mm "
        f"(theory {np.sqrt(expected):.3f}), LOO-TRE {np.sqrt(np.mean(tre2)):.3f} mm"
    )


def test_loo_tre_needs_four_points():
    with pytest.raises(ValueError):
        loo_tre(PHANTOM[:3], PHANTOM[:3])


# ---------------------------------------------------------------- transforms
def test_inverse_and_compose():
    rng = np.random.default_rng(2)
    T, U = random_transform(rng), random_transform(rng)
    X = rng.uniform(-100, 100, (5, 3))
    assert np.allclose(T.inverse().apply(T.apply(X)), X, atol=1e-9)
    assert np.allclose(T.compose(U).apply(X), T.apply(U.apply(X)), atol=1e-9)
    ident = T.compose(T.inverse())
    assert np.allclose(ident.R, np.eye(3), atol=1e-12) and np.allclose(ident.t, 0, atol=1e-9)
    assert T.apply(X[0]).shape == (3,)


def test_euler_round_trip_and_convention():
    rng = np.random.default_rng(3)
    for _ in range(50):
        angles = rng.uniform([-180, -89, -180], [180, 89, 180])
        T = RigidTransform.from_euler_xyz_deg(angles, (1.0, 2.0, 3.0))
        assert np.allclose(T.as_euler_xyz_deg(), angles, atol=1e-9)
    # extrinsic x-y-z: R = Rz @ Ry @ Rx
    a, b, c = np.radians([10.0, 20.0, 30.0])
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    Rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    assert np.allclose(RigidTransform.from_euler_xyz_deg([10, 20, 30]).R, Rz @ Ry @ Rx)


def test_rotation_angle_small_and_large():
    assert RigidTransform.from_rotvec([0, 0, 1e-7]).rotation_angle_deg == pytest.approx(np.degrees(1e-7), rel=1e-6)
    big = RigidTransform.from_euler_xyz_deg([0, 0, 179.0])
    assert big.rotation_angle_deg == pytest.approx(179.0)


def test_difference_of_a_known_half_degree_rotation():
    rng = np.random.default_rng(4)
    T1 = random_transform(rng)
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    delta = RigidTransform.from_rotvec(np.radians(0.5) * axis)
    T2 = RigidTransform(T1.R @ delta.R, T1.t + np.array([0.3, -0.4, 0.0]))
    d = difference(T1, T2)
    assert d.angle_deg == pytest.approx(0.5, abs=1e-9)
    assert d.translation_norm_mm == pytest.approx(0.5, abs=1e-12)
    assert np.allclose(d.translation_mm, [0.3, -0.4, 0.0])
    # per axis: about 0.5 deg * axis for so small a rotation
    assert np.allclose(d.axes_deg, 0.5 * axis, atol=1e-3)
    # a rotation about x alone shows up in the Euler differences on x alone
    U1 = RigidTransform.from_euler_xyz_deg([5.0, -3.0, 12.0])
    U2 = RigidTransform.from_euler_xyz_deg([5.5, -3.0, 12.0])
    assert np.allclose(difference(U1, U2).euler_diff_deg, [0.5, 0, 0], atol=1e-9)
    W1 = RigidTransform.from_euler_xyz_deg([0, 0, 179.8])
    W2 = RigidTransform.from_euler_xyz_deg([0, 0, -179.9])
    assert np.allclose(difference(W1, W2).euler_diff_deg, [0, 0, 0.3], atol=1e-9)


def test_save_load_round_trip(tmp_path):
    rng = np.random.default_rng(6)
    T = RigidTransform(random_transform(rng).R, [12.5, -3.0, 700.25], meta={"from": "vts"})
    path = T.save(tmp_path / "vts_to_spect.json")
    d = json.loads(path.read_text())
    assert d["vts_hw_version"] == vts_hw.__version__
    assert d["created"].endswith("+00:00")
    assert "x-y-z" in d["euler_convention"]
    back = RigidTransform.load(path)
    assert np.array_equal(back.R, T.R) and np.array_equal(back.t, T.t)
    assert back.meta == {"from": "vts"}
    assert not list(tmp_path.glob("*.tmp"))


def test_load_rejects_bad_files(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(DataError):
        RigidTransform.load(bad)
    d = RigidTransform.identity().to_dict()
    d["R"] = (2 * np.eye(3)).tolist()
    bad.write_text(json.dumps(d))
    with pytest.raises(DataError, match="rotation"):
        RigidTransform.load(bad)
    d["R"] = np.diag([-1.0, 1.0, 1.0]).tolist()  # a reflection
    bad.write_text(json.dumps(d))
    with pytest.raises(DataError):
        RigidTransform.load(bad)
    with pytest.raises(DataError):
        RigidTransform.load(tmp_path / "missing.json")


# ---------------------------------------------------------------- with the simulated rig
def test_phantom_motion_from_triangulated_spheres():
    """Initial -> final 6-DOF motion of the phantom from stereo 3D positions (0.02 px noise)
    against the scene's ground truth: the 7-sphere step procedure in miniature."""
    from vts_hw.sim_devices.scene import PHANTOM_PLACEMENT, Scene
    from vts_hw.vision.triangulate import match_epipolar, triangulate

    t0 = 1_700_000_000.0
    scene = Scene.reference(seed=0, start_epoch=t0)
    scene.add_phantom()
    rot = Rotation.from_euler("xyz", [2.0, -4.0, 6.0], degrees=True)
    shift = np.array([10.0, -75.0, 20.0])
    scene.set_phantom_pose(rot.as_rotvec(), shift, t0 + 10.0)
    rng = np.random.default_rng(8)
    ids = [f"S{k}" for k in range(1, 8)]

    def sphere_positions(t):
        cams = [scene.camera_at(c, t) for c in ("cam1", "cam2")]
        pts = []
        for c in ("cam1", "cam2"):
            seen = {m: (u, v) for m, u, v in scene.truth(c, t)}
            pts.append(np.array([seen[i] for i in ids]) + rng.normal(0, 0.02, (7, 2)))
        m = match_epipolar(cams[0], pts[0], cams[1], pts[1])
        assert m.pairs == [(i, i) for i in range(7)]
        return triangulate(cams, pts).points

    P0, P1 = sphere_positions(t0 + 1.0), sphere_positions(t0 + 11.0)
    measured = kabsch(P0, P1)
    truth = RigidTransform(rot.as_matrix(), shift - rot.as_matrix() @ np.array(PHANTOM_PLACEMENT))
    d = difference(truth, measured)
    print(
        f"phantom motion: rotation error {d.angle_deg:.4f} deg, translation error "
        f"{d.translation_norm_mm:.3f} mm, FRE {fre(P0, P1, measured):.3f} mm, "
        f"LOO-TRE {loo_tre(P0, P1).rms:.3f} mm"
    )
    assert d.angle_deg < 0.1
    assert d.translation_norm_mm < 0.3
    assert np.allclose(measured.as_euler_xyz_deg(), [2.0, -4.0, 6.0], atol=0.1)


@pytest.mark.parametrize(
    "text, words",
    [
        ("[" * 5000 + "]" * 5000, "nested too deeply"),
        ('{"R": ' + "9" * 5000 + "}", "Exceeds the limit (4300 digits) for integer string conversion"),
        ('{"R": [[1,0,0],[0,1,0],[0,0,1]], "t_mm": [0,0,0], "meta": 5}', "'meta' must be a JSON object, not int"),
        ('{"R": [[1,0,0],[0,1,0],[0,0,1]], "t_mm": [0,0,0], "meta": "ab"}', "'meta' must be a JSON object, not str"),
    ],
)
def test_load_of_json_beyond_syntax_and_a_bad_meta(tmp_path, text, words):
    path = tmp_path / "spect_mapping.json"
    path.write_text(text)
    with pytest.raises(DataError) as err:
        RigidTransform.load(path)
    assert str(path) in str(err.value) and words in str(err.value) and "\n" not in str(err.value)


def test_load_of_a_number_no_float_can_hold(tmp_path):
    path = tmp_path / "spect_mapping.json"
    path.write_text('{"R": [[1,0,0],[0,1,0],[0,0,1%s]], "t_mm": [0,0,0]}' % ("0" * 400))
    with pytest.raises(DataError, match="missing or malformed R/t_mm"):
        RigidTransform.load(path)
