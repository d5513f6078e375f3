"""VTS → SPECT mapping on the simulated phantom: a SimSpect volume at a known pose gives the
SPECT centroids; the VTS points are the same true centres in a made-up VTS frame (known rigid
transform) plus 0.1 mm Gaussian noise, in shuffled order."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vts_hw import __version__
from vts_hw.errors import DataError
from vts_hw.procedures.spect_mapping import FRE_LIMIT_MM, SpectMapping, correspond, correspondence
from vts_hw.sim_devices.spect import SimSpect, phantom_centres
from vts_hw.spect import find_spheres, read_volume
from vts_hw.vision.registration import RigidTransform, difference

POSE_T = (5.0, -3.0, 12.0)  # phantom pose in the SPECT frame (mm)
POSE_RVEC = (0.05, -0.1, 0.2)  # rad
# SPECT → made-up VTS frame: the VTS frame sits ~3.7 m from the FOV centre, like the cameras.
SPECT_TO_VTS_FAR = RigidTransform.from_euler_xyz_deg((20.0, -35.0, 110.0), (300.0, -1200.0, 2500.0))
# A VTS frame whose origin is near the phantom: the transform's translation is then not
# magnified by the lever arm of a rotation error, so it can be compared directly.
SPECT_TO_VTS_NEAR = RigidTransform.from_euler_xyz_deg((10.0, -20.0, 30.0), (40.0, 55.0, -60.0))
NOISE_MM = 0.1


@pytest.fixture(scope="module")
def phantom(tmp_path_factory):
    """(true centres S1..S7, volume path, SPECT centroids in S1..S7 order)."""
    truth = phantom_centres(POSE_T, POSE_RVEC)
    path = SimSpect(seed=3).write(tmp_path_factory.mktemp("spect") / "phantom.npz", truth)
    found = find_spheres(read_volume(path), n_expected=7, reference=truth)
    assert found.ok
    return truth, path, found.centroids


def vts_points(truth, known, seed):
    """The true centres in the VTS frame with 0.1 mm noise, shuffled: (points, perm) with
    ``points[i]`` = sphere ``perm[i]``."""
    rng = np.random.default_rng(seed)
    perm = rng.permutation(len(truth))
    pts = known.apply(truth) + rng.normal(0.0, NOISE_MM, truth.shape)
    return pts[perm], perm


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_known_transform_far_frame(phantom, seed):
    truth, _, spect = phantom
    vts, perm = vts_points(truth, SPECT_TO_VTS_FAR, seed)
    m = SpectMapping(vts, spect).analyze()
    expected = SPECT_TO_VTS_FAR.inverse()  # VTS → SPECT
    d = difference(expected, m.transform)
    assert d.angle_deg < 0.15  # 60 seeded cases: mean 0.059°, max 0.104° at 0.1 mm noise
    # With the VTS origin ~2.8 m away, the raw translation carries the lever arm of the
    # (tiny) rotation error; what matters is where the phantom lands: within 0.3 mm.
    at_phantom = np.linalg.norm(m.transform.apply(vts) - expected.apply(vts), axis=1)
    assert at_phantom.max() < 0.3
    assert 0.0 < m.fre_mm < 0.5
    assert m.tre.rms < 0.6 and m.tre.max < 1.0
    assert m.tre.rms >= m.fre_mm
    assert m.correspondence == [int(k) for k in perm]  # spect is in S1..S7 order


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_recovers_known_transform_near_frame(phantom, seed):
    truth, _, spect = phantom
    vts, _ = vts_points(truth, SPECT_TO_VTS_NEAR, seed)
    m = SpectMapping(vts, spect).analyze()
    d = difference(SPECT_TO_VTS_NEAR.inverse(), m.transform)
    assert d.angle_deg < 0.15  # 60 seeded cases: mean 0.059°, max 0.104° at 0.1 mm noise
    assert d.translation_norm_mm < 0.3
    assert m.fre_mm < 0.5 and m.tre.rms >= m.fre_mm


def test_correspondence_despite_shuffling_both_sides(phantom):
    truth, _, spect = phantom
    vts, perm = vts_points(truth, SPECT_TO_VTS_FAR, seed=7)
    q = np.random.default_rng(8).permutation(7)
    spect_shuffled = spect[q]  # spect_shuffled[j] = sphere q[j]
    order = correspond(vts, spect_shuffled)
    assert isinstance(order, list) and all(isinstance(k, int) for k in order)
    # VTS point i is sphere perm[i], found in spect_shuffled at the j with q[j] == perm[i].
    assert order == [int(np.argsort(q)[p]) for p in perm]
    np.testing.assert_allclose(np.sort(np.linalg.norm(spect_shuffled[order] - spect[perm], axis=1)), 0.0)


def test_from_volume(phantom):
    truth, path, _ = phantom
    vts, perm = vts_points(truth, SPECT_TO_VTS_FAR, seed=4)
    m = SpectMapping.from_volume(vts, path).analyze()
    assert difference(SPECT_TO_VTS_FAR.inverse(), m.transform).angle_deg < 0.15
    found = m.spect_points[m.correspondence]
    assert np.linalg.norm(found - truth[perm], axis=1).max() < 0.3


def test_near_symmetric_phantom_is_resolved_by_kabsch():
    # Two-fold symmetric about the y axis (signatures pair up), broken by 3 mm at one sphere.
    a = np.array(
        [[60, 0, 20], [-60, 0, -20], [30, 50, -70], [-30, 50, 70], [10, 120, 40], [-10, 120, -40], [0, 80, 0]], float
    )
    a[4] += (0.0, 0.0, 3.0)
    rng = np.random.default_rng(1)
    T = RigidTransform.from_euler_xyz_deg((10, 20, 30), (5, 6, 7))
    for _ in range(5):
        p = rng.permutation(7)
        b = T.apply(a)[p] + rng.normal(0.0, NOISE_MM, a.shape)
        c = correspondence(a, b)
        assert c.order == [int(np.flatnonzero(p == i)[0]) for i in range(7)]
        assert c.tried > 1  # the near-identical signatures made it try other orders
        assert c.runner_up_fre_mm > 3 * c.fre_mm


def test_exactly_symmetric_phantom_is_flagged_ambiguous():
    a = np.array(
        [[60, 0, 20], [-60, 0, -20], [30, 50, -70], [-30, 50, 70], [10, 120, 40], [-10, 120, -40], [0, 80, 0]], float
    )
    m = SpectMapping(a, RigidTransform.from_euler_xyz_deg((0, 45, 0), (1, 2, 3)).apply(a)).analyze()
    assert m.fre_mm < 1e-6
    assert m.results_data()["ambiguous"] is True
    assert "WARNING" in m.results()


def test_mismatched_counts(phantom):
    truth, _, spect = phantom
    vts, _ = vts_points(truth, SPECT_TO_VTS_FAR, seed=0)
    with pytest.raises(DataError, match="7 points to 6 points"):
        correspond(vts, spect[:6])
    with pytest.raises(DataError, match="VTS sees 6 spheres but the SPECT volume gives 7"):
        SpectMapping(vts[:6], spect).analyze()


def test_non_rigid_set_is_refused(phantom):
    truth, _, spect = phantom
    vts, _ = vts_points(truth, SPECT_TO_VTS_FAR, seed=0)
    vts[3] += (20.0, 0.0, 0.0)  # one sphere 20 mm off: not the same rigid body
    with pytest.raises(
        DataError,
        match=r"no consistent correspondence.*FRE of [\d.]+ mm "
        rf"\(limit {FRE_LIMIT_MM:.1f} mm",
    ):
        SpectMapping(vts, spect).analyze()


def test_mirror_image_is_refused(phantom):
    _, _, spect = phantom
    mirrored = spect * np.array([-1.0, 1.0, 1.0])  # same distances, not a proper rigid motion
    with pytest.raises(DataError, match="no consistent correspondence"):
        correspond(spect, mirrored)


def test_too_few_or_malformed_points():
    pts = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0]], float)
    with pytest.raises(DataError, match="at least 4 spheres"):
        SpectMapping(pts, pts).analyze()
    with pytest.raises(DataError, match="N×3"):
        correspond(np.zeros((4, 2)), np.zeros((4, 2)))


def test_results_and_save_load_round_trip(phantom, tmp_path):
    truth, _, spect = phantom
    vts, _ = vts_points(truth, SPECT_TO_VTS_FAR, seed=5)
    m = SpectMapping(vts, spect).analyze()

    data = json.loads(json.dumps(m.results_data()))
    assert data["vts_hw_version"] == __version__
    assert data["date"].startswith("20")
    assert data["fre_mm"] == pytest.approx(m.fre_mm)
    assert len(data["tre_per_sphere_mm"]) == 7
    assert data["tre_max_mm"] == pytest.approx(max(data["tre_per_sphere_mm"]))
    text = m.results()
    assert "FRE" in text and "TRE" in text and "WARNING" not in text

    path = m.save(tmp_path / "vts_to_spect.json")
    raw = json.loads(path.read_text())
    assert raw["vts_hw_version"] == __version__ and raw["created"]
    back = RigidTransform.load(path)
    np.testing.assert_allclose(back.R, m.transform.R, atol=1e-12)
    np.testing.assert_allclose(back.t, m.transform.t, atol=1e-9)
    assert back.meta["from_frame"] == "VTS" and back.meta["to_frame"] == "SPECT"
    assert back.meta["fre_mm"] == pytest.approx(m.fre_mm)
    assert back.meta["tre_rms_mm"] == pytest.approx(m.tre.rms)
    assert back.meta["tre_per_sphere_mm"] == pytest.approx(m.tre.per_point.tolist())
    assert back.meta["correspondence"] == m.correspondence


def test_results_before_analyze_raises():
    with pytest.raises(RuntimeError, match="analyze"):
        SpectMapping(np.eye(4, 3), np.eye(4, 3)).results()
