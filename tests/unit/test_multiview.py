"""Matching and triangulation across N views against the simulated scene's truth: every pair's
epipolar constraint, ambiguities reported (and settled by a further view), markers seen by one
camera reported as such, each point with its cameras and reprojection error."""

import json

import numpy as np
import pytest

from vts_hw.errors import DataError
from vts_hw.sim_devices.scene import Scene
from vts_hw.sim_devices.sync_truth import true_stereo_calibration, write_true_cameras
from vts_hw.vision.camera_set import load_cameras, named_cameras
from vts_hw.vision.multiview import ViewGeometry, match_views
from vts_hw.vision.triangulate import triangulate

T0 = 1_700_000_000.0


@pytest.fixture(scope="module")
def room():
    s = Scene.reference(seed=0, n_cameras=4, start_epoch=T0)
    s.add_phantom()
    names = s.camera_names
    return s, names, ViewGeometry([s.camera_at(c, T0) for c in names], names)


def observe(scene, names, sigma, seed):
    """Each camera's detections (shuffled) with noise, and the marker id of each."""
    rng = np.random.default_rng(seed)
    pts, ids = [], []
    for c in names:
        truth = scene.truth(c, T0)
        order = rng.permutation(len(truth))
        pts.append(np.array([truth[i][1:] for i in order]) + rng.normal(0, sigma, (len(order), 2)))
        ids.append([truth[i][0] for i in order])
    return pts, ids


def test_every_marker_from_every_camera_that_sees_it(room):
    scene, names, geo = room
    pts, ids = observe(scene, names, 0.02, seed=1)
    truth = {m.id: m.center for m in scene.markers_world(T0)}
    m = match_views(geo, pts)
    assert m.ambiguous == [] and all(v == [] for v in m.single.values())
    got = {}
    for p in m.points:
        seen = {ids[c][d] for c, d in enumerate(p.detections) if d >= 0}
        assert len(seen) == 1, seen  # one marker's detections, never mixed
        got[seen.pop()] = p
    # the phantom from all four cameras; each wall only from the pair at its end
    assert sorted(got) == sorted(truth)
    for k in range(1, 8):
        assert got[f"S{k}"].cameras == ("cam1", "cam2", "cam3", "cam4")
    for k in range(1, 11):
        assert got[f"W{k}"].cameras == (("cam1", "cam2") if k <= 5 else ("cam3", "cam4"))
    for p in m.points:
        assert p.rms_px < 0.1 and np.nanmax(p.residual_px) < 0.15
        used = [c for c, d in enumerate(p.detections) if d >= 0]
        assert np.isnan(np.array(p.residual_px)[[c for c in range(4) if c not in used]]).all()
    # four cameras at both ends beat the head pair alone on the phantom (measured: ~3x)
    sph = [f"S{k}" for k in range(1, 8)]
    err4 = np.array([np.linalg.norm(got[s].xyz - truth[s]) for s in sph])
    pair = triangulate(
        [geo.cams[0], geo.cams[1]], [np.array([pts[c][ids[c].index(s)] for s in sph]) for c in (0, 1)]
    ).points
    err2 = np.linalg.norm(pair - np.array([truth[s] for s in sph]), axis=1)
    assert np.sqrt(np.mean(err4**2)) < 0.06 and np.sqrt(np.mean(err4**2)) < np.sqrt(np.mean(err2**2))


def test_noise_free_points_are_exact(room):
    scene, names, geo = room
    pts, ids = observe(scene, names, 0.0, seed=2)
    truth = {m.id: m.center for m in scene.markers_world(T0)}
    for p in match_views(geo, pts).points:
        marker = next(ids[c][d] for c, d in enumerate(p.detections) if d >= 0)
        assert np.linalg.norm(p.xyz - truth[marker]) < 1e-6


def test_a_marker_seen_by_one_camera_only_is_reported_not_invented(room):
    scene, names, geo = room
    pts, ids = observe(scene, names, 0.02, seed=3)
    # S3 hidden from every camera but cam3 (the heads, say), and a reflection in cam2 alone
    for c in (0, 1, 3):
        keep = [i for i, m in enumerate(ids[c]) if m != "S3"]
        pts[c], ids[c] = pts[c][keep], [ids[c][i] for i in keep]
    pts[1] = np.vstack([pts[1], [600.0, 20.0]])
    ids[1].append("stray")
    m = match_views(geo, pts)
    assert m.single == {"cam1": [], "cam2": [len(ids[1]) - 1], "cam3": [ids[2].index("S3")], "cam4": []}
    assert len(m.points) == 16 and m.ambiguous == []
    assert all("S3" not in {ids[c][d] for c, d in enumerate(p.detections) if d >= 0} for p in m.points)


def two_on_one_epipolar_plane(scene):
    """Two points in one epipolar plane of cam1 and cam2 (ambiguous for that pair alone)."""
    ca, cb = scene.camera_at("cam1", T0).center, scene.camera_at("cam2", T0).center
    p = np.array([30.0, 60.0, 120.0])
    return np.vstack([p, p + 0.02 * (p - ca) + 0.03 * (cb - ca)])


def test_an_ambiguity_is_reported_never_guessed_and_a_further_view_settles_it(room):
    """Two markers in one epipolar plane of the head pair, seen by that pair alone: every
    pairing of their detections fits as well as any other (a noise-aware ``min_sep_px`` of 5 sigma, as
    decision 0013 advises), so all are withheld and reported; once the foot pair sees them
    too, the four views match them with no ambiguity."""
    scene, names, geo = room
    X = two_on_one_epipolar_plane(scene)
    rng = np.random.default_rng(5)
    pts, ids = observe(scene, names, 0.02, seed=4)
    n = [len(p) for p in pts]
    extra = [scene.camera_at(c, T0).project(X) + rng.normal(0, 0.02, (2, 2)) for c in names]
    seen_by_pair = [np.vstack([pts[c], extra[c]]) if c < 2 else pts[c] for c in range(4)]
    m = match_views(geo, seen_by_pair, min_sep_px=0.1)
    assert len(m.ambiguous) == 1 and len(m.ambiguous[0].groups) >= 2
    withheld = {(c, d) for g in m.ambiguous[0].groups for c, d in enumerate(g) if d >= 0}
    new = {(0, n[0]), (0, n[0] + 1), (1, n[1]), (1, n[1] + 1)}
    assert withheld == new
    used = {(c, d) for p in m.points for c, d in enumerate(p.detections) if d >= 0}
    assert not used & new and len(m.points) == 17  # everything else still matched
    assert all(v == [] for v in m.single.values())  # withheld, not "seen by one camera"
    # the foot pair sees them too: four views settle what two could not
    m4 = match_views(geo, [np.vstack([pts[c], extra[c]]) for c in range(4)], min_sep_px=0.1)
    assert m4.ambiguous == [] and len(m4.points) == 19
    found = [p for p in m4.points if p.detections[0] >= n[0]]
    assert len(found) == 2 and all(p.n_cameras == 4 for p in found)
    for p in found:
        k = p.detections[0] - n[0]
        assert all(p.detections[c] - n[c] == k for c in range(4))
        assert np.linalg.norm(p.xyz - X[k]) < 0.2


def test_n_cameras_from_any_calibration_form(room, tmp_path):
    scene, names, _ = room
    path = write_true_cameras(scene, tmp_path, frame="world")
    cams = load_cameras(path)
    assert list(cams) == names
    assert np.allclose(cams["cam3"].R, scene.camera_at("cam3", T0).R)
    stereo = named_cameras(true_stereo_calibration(scene), ["cam1", "cam2"])
    assert list(stereo) == ["cam1", "cam2"] and np.allclose(stereo["cam1"].R, np.eye(3))
    assert list(named_cameras([scene.cameras[n] for n in names])) == names
    # the rig's file is in camera 1's frame, as calibration.json; the sync analysis reads either
    from vts_hw.vision.calibration_io import read_calibration as load_calibration

    rig_file = write_true_cameras(scene, tmp_path / "rig", frame="cam1")
    by_cam1 = load_calibration(rig_file)
    assert list(by_cam1) == names and np.allclose(by_cam1["cam1"].R, np.eye(3), atol=1e-12)
    assert np.allclose(by_cam1["cam4"].R, stereo_of(scene, "cam4"), atol=1e-12)
    two = load_calibration(true_stereo_calibration(scene).save(tmp_path / "s.json"))
    assert type(two).__name__ == "CameraCalibration" and two.names == ["cam1", "cam2"]
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"cameras": [{"name": "a", "K": [1, 2]}, {"name": "b"}]}))
    with pytest.raises(DataError, match="camera 1 is not whole"):
        load_cameras(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(DataError, match="not a calibration"):
        load_cameras(bad)


def stereo_of(scene, name):
    """Camera ``name``'s rotation relative to camera 1 (what a calibration in cam1's frame holds)."""
    return scene.camera_at(name, T0).R @ scene.camera_at("cam1", T0).R.T
