"""Processing a recording (decode, detect, match, triangulate, pair, identities) against the
simulated scene's truth; gaps, torn tails, clocks seconds apart; the trajectory files."""

import json

import numpy as np
import pytest

from vts_hw.errors import DataError
from vts_hw.sim_devices.recording_sim import BAND_LAYOUT, simulate_recording
from vts_hw.tracking.processing import (
    ProcessSettings,
    Tracks,
    group_frames,
    process_recording,
    track_identities,
    triangulate_fast,
)
from vts_hw.vision.registration import RigidTransform
from vts_hw.vision.triangulate import as_camera, triangulate

FLOOR = 0.004  # the simulated receive delay's floor (recording_sim default)


def true_cameras(sim):
    """The scene's camera models as the calibration (drift over seconds is negligible)."""
    return {c: sim.scene.camera_at(c, sim.scene.start_epoch + 5.0) for c in sim.cameras}


def errors_against_truth(sim, tracks):
    """Per point: distance (mm) to the nearest true marker at the point's time, and its id."""
    ids, truth = sim.marker_positions(tracks.point_time)
    d = np.linalg.norm(truth - tracks.xyz[:, None, :], axis=2)
    j = d.argmin(axis=1)
    return d[np.arange(len(j)), j], np.array(ids)[j]


@pytest.fixture(scope="module")
def processed(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rec") / "session"
    sim = simulate_recording(folder, duration_s=8.0, seed=1)
    calls = []
    tracks = process_recording(
        folder, true_cameras(sim), workers=2, progress=lambda done, total: calls.append((done, total))
    )
    return sim, tracks, calls


def test_tracks_against_the_scene_truth(processed):
    sim, tracks, calls = processed
    n = len(sim.exposure["cam1"])
    assert len(tracks) == n and tracks.meta["unpaired_frames"] == {"cam1": 0, "cam2": 0}
    err, which = errors_against_truth(sim, tracks)
    rms = float(np.sqrt(np.mean(err**2)))
    assert rms < 0.5 and err.max() < 1.5  # measured: RMS 0.08 mm, max 0.4 mm
    band = np.isin(which, list(BAND_LAYOUT))
    assert float(np.sqrt(np.mean(err[band] ** 2))) < 0.5
    # 9 markers in every frame, each true marker with exactly one identity and vice versa
    assert len(tracks.xyz) == 9 * n
    assert tracks.meta["markers"] == 9 and tracks.meta["ambiguous_points"] == 0
    for name in set(which.tolist()):
        assert len(set(tracks.marker[which == name].tolist())) == 1, name
    # the band really moved: a 10 mm step in Z at 6 s and breathing in Y
    bid = int(tracks.marker[which == "B2"][0])
    _, xyz = tracks.trajectory(bid)
    assert np.ptp(xyz[:, 2]) > 9.0 and np.ptp(xyz[:, 1]) > 8.0
    summary = {d["marker"]: d for d in tracks.marker_summary()}
    assert summary[bid]["points"] == n and summary[bid]["range_mm"][2] > 9.0
    wall = int(tracks.marker[which == "W1"][0])
    assert max(summary[wall]["range_mm"]) < 1.5  # a wall marker stays put
    # host time of each pair: the mean of the two exposures plus the delay floor
    expo = 0.5 * (sim.exposure["cam1"][tracks.camera_frame[:, 0]] + sim.exposure["cam2"][tracks.camera_frame[:, 1]])
    assert np.abs(tracks.host_time - expo - FLOOR).max() < 0.001
    assert calls and calls[-1] == (n, n) and len(calls) >= 2


def test_one_worker_gives_the_same_tracks(processed):
    sim, tracks, _ = processed
    serial = process_recording(sim.folder, true_cameras(sim), workers=1)
    assert np.array_equal(serial.marker, tracks.marker)
    assert np.allclose(serial.xyz, tracks.xyz, atol=1e-9)
    assert np.array_equal(serial.host_time, tracks.host_time)


def test_fast_triangulation_agrees_with_the_reference(processed):
    sim, _, _ = processed
    cams = [as_camera(c) for c in true_cameras(sim).values()]
    rng = np.random.default_rng(0)
    X = rng.uniform(-200, 200, (40, 3))
    pa = cams[0].project(X) + rng.normal(0, 0.1, (40, 2))
    pb = cams[1].project(X) + rng.normal(0, 0.1, (40, 2))
    fast, rms = triangulate_fast(cams[0], cams[1], pa, pb)
    ref = triangulate(cams, [pa, pb])
    assert np.abs(fast - ref.points).max() < 1e-5
    assert np.allclose(rms, ref.rms_px, atol=1e-8)
    assert np.abs(fast - X).max() > 0.01  # the noise is there: not a trivially exact case


def test_gap_and_torn_tail_still_process(tmp_path):
    folder = tmp_path / "gap"
    sim = simulate_recording(folder, duration_s=5.0, seed=2, gaps={"cam2": [(2.0, 2.6)]}, torn_tail=("cam1",))
    # and an index line whose frame is cut short in the .mjpeg (bytes lost at a power cut)
    mj = folder / "cam2.mjpeg"
    with open(mj, "r+b") as f:
        f.truncate(mj.stat().st_size - 100)
    # and a frame whose bytes were damaged (not a JPEG any more)
    from vts_hw.recording.folder import read_index

    row = read_index(folder / "cam1.index.csv")[10]
    with open(folder / "cam1.mjpeg", "r+b") as f:
        f.seek(row.offset)
        f.write(b"\x00" * 64)
    tracks = process_recording(folder, true_cameras(sim), workers=2)
    assert tracks.meta["undecodable_frames"] == {"cam1": 1, "cam2": 0}
    bad = int(np.flatnonzero(tracks.camera_frame[:, 0] == 10)[0])
    assert tracks.n_blobs[bad, 0] == 0 and not (tracks.point_frame == bad).any()
    n1, n2 = len(sim.exposure["cam1"]), len(sim.exposure["cam2"])
    assert n1 - n2 == 15  # 0.6 s of cam2 lost, and the manifest says so
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["cameras"]["cam2"]["dropped_frames"] == 15
    assert manifest["cameras"]["cam1"]["gaps"] == []
    assert tracks.meta["frames_beyond_end_of_mjpeg"] == {"cam1": 0, "cam2": 1}
    # every cam1 frame in the gap, and the one whose partner was cut, is left unpaired
    assert tracks.meta["unpaired_frames"]["cam1"] == 16
    assert tracks.meta["unpaired_frames"]["cam2"] == 0
    assert len(tracks) == n2 - 1
    gap_t = sim.band.start + np.array([2.0, 2.6])
    assert not ((tracks.host_time > gap_t[0] + 0.02) & (tracks.host_time < gap_t[1] - 0.02)).any()
    err, which = errors_against_truth(sim, tracks)
    assert float(np.sqrt(np.mean(err**2))) < 0.5
    assert len(tracks.xyz) == 9 * (len(tracks) - 1)
    # a 0.6 s gap is shorter than max_gap_s: every marker keeps its identity across it
    assert tracks.meta["markers"] == 9
    # with a shorter max_gap_s, identities end at the gap and new ones start after it
    short = process_recording(folder, true_cameras(sim), workers=1, settings=ProcessSettings(max_gap_s=0.3))
    assert short.meta["markers"] == 18


def test_pairing_when_camera_clocks_differ_by_seconds(tmp_path):
    folder = tmp_path / "clocks"
    sim = simulate_recording(
        folder, duration_s=4.0, seed=3, clock_offsets_s={"cam1": -2.7, "cam2": 1.9}, phases_s={"cam2": 0.017}
    )
    stamps = {c: sim.camera_time[c] for c in sim.cameras}
    assert abs((stamps["cam2"][0] - stamps["cam1"][0]) - 4.6) < 0.05  # 4.6 s apart
    tracks = process_recording(folder, true_cameras(sim), workers=2)
    n = len(sim.exposure["cam1"])
    assert len(tracks) == n
    dt = sim.exposure["cam1"][tracks.camera_frame[:, 0]] - sim.exposure["cam2"][tracks.camera_frame[:, 1]]
    assert np.abs(dt + 0.017).max() < 1e-6  # each frame with the frame exposed 17 ms later
    assert np.array_equal(tracks.camera_frame[:, 0], tracks.camera_frame[:, 1])
    err, _ = errors_against_truth(sim, tracks)
    assert float(np.sqrt(np.mean(err**2))) < 0.5


def test_two_cameras_frames_join_in_time_order_within_the_tolerance():
    ta = np.array([0.00, 0.038, 0.05, 0.08, 0.30, np.nan])
    tb = np.array([0.001, 0.045, 0.081, 0.20])
    # the oldest frame opens a set and the other camera's next frame joins within 20 ms:
    # 0.038 opens before 0.05 and takes 0.045 (the rule is the live path's: a set is decided
    # from the frames in time order); 0.30 is 100 ms from its nearest (too far); NaN never joins
    assert group_frames([ta, tb], 0.02).tolist() == [[0, 0], [1, 1], [3, 2]]
    assert group_frames([np.array([0.0, 0.041, 0.052]), tb[:2]], 0.02).tolist() == [[0, 0], [1, 1]]
    assert group_frames([np.array([1.0]), tb], 0.02).shape == (0, 2)


def test_identities_gate_and_new_markers():
    # marker A still, marker B moving 2 mm per frame, marker C appears at frame 3
    frames, pts = [], []
    for f in range(6):
        row = [(0.0, 0.0, 0.0), (100.0 + 2 * f, 0.0, 0.0)]
        if f >= 3:
            row.append((50.0, 50.0, 0.0))
        frames += [f] * len(row)
        pts += row
    ids = track_identities(np.array(frames), np.arange(6) * 0.04, np.array(pts), gate_mm=5.0)
    ids_by = {tuple(p): i for p, i in zip(map(tuple, pts), ids.tolist())}
    assert set(ids[np.array(pts)[:, 0] == 0.0].tolist()) == {1}
    assert set(ids[(np.array(pts)[:, 0] >= 100)].tolist()) == {2}
    assert ids_by[(50.0, 50.0, 0.0)] == 3
    # a jump beyond the gate is a new marker
    ids = track_identities(np.array([0, 1]), np.array([0.0, 0.04]), np.array([(0.0, 0, 0), (20.0, 0, 0)]), gate_mm=5.0)
    assert ids.tolist() == [1, 2]


def test_trajectory_files_round_trip_with_spect_columns(processed, tmp_path):
    sim, tracks, _ = processed
    T = RigidTransform.from_euler_xyz_deg((1.0, -2.0, 0.5), (10.0, -5.0, 3.0))
    spect = tracks.with_spect(T, lambda h: h - 1_790_000_000.0 + 0.0123)
    csv_path, json_path = spect.save(tmp_path / "traj")
    header = csv_path.read_text().splitlines()[0].split(",")
    assert header == [
        "frame",
        "host_time",
        "cam1_frame",
        "cam1_time",
        "cam2_frame",
        "cam2_time",
        "spect_time",
        "marker",
        "x_mm",
        "y_mm",
        "z_mm",
        "reproj_px",
        "cam1_u",
        "cam1_v",
        "cam2_u",
        "cam2_v",
        "x_spect_mm",
        "y_spect_mm",
        "z_spect_mm",
    ]
    back = Tracks.load(csv_path)
    assert np.allclose(back.xyz, spect.xyz, atol=1e-4)
    assert np.allclose(back.xyz_spect, T.apply(tracks.xyz), atol=1e-4)
    assert np.allclose(back.host_time, spect.host_time, atol=1e-6)
    assert np.allclose(back.spect_time, spect.host_time - 1_790_000_000.0 + 0.0123, atol=1e-6)
    assert np.allclose(back.camera_time, spect.camera_time, atol=1e-6)
    assert np.array_equal(back.marker, spect.marker)
    assert np.array_equal(back.point_frame, spect.point_frame)
    assert np.array_equal(back.camera_frame, spect.camera_frame)
    assert back.meta["clock_fits"]["cam1"]["frames"] == len(sim.exposure["cam1"])
    doc = json.loads(json_path.read_text())
    assert doc["format"] == "vts-trajectory/1" and doc["csv"] == "traj.csv"
    # plain VTS tracks have no SPECT columns
    plain_csv, _ = tracks.save(tmp_path / "plain.csv")
    assert "x_spect_mm" not in plain_csv.read_text().splitlines()[0]
    assert Tracks.load(tmp_path / "plain").xyz_spect is None


def test_bad_inputs_are_data_errors(tmp_path, processed):
    sim, _, _ = processed
    with pytest.raises(DataError):
        process_recording(tmp_path / "nowhere", true_cameras(sim))
    cams = true_cameras(sim)
    with pytest.raises(DataError):
        process_recording(sim.folder, {"camA": cams["cam1"], "camB": cams["cam2"]})
    (tmp_path / "x.json").write_text("{}")
    with pytest.raises(DataError):
        Tracks.load(tmp_path / "x.csv")


def test_reindexed_and_recovered_recordings(tmp_path):
    from vts_hw.recording.reindex import reindex

    folder = tmp_path / "killed"
    sim = simulate_recording(
        folder, duration_s=3.0, seed=4, torn_tail=("cam2",), clock_offsets_s={"cam1": 0.0, "cam2": 5.0}
    )
    before = process_recording(folder, true_cameras(sim), workers=1)
    report = reindex(folder)  # what `vts recording reindex` does after a kill -9
    assert report["cam2"].torn == 1 and report["cam2"].host_times_kept == 75 and report["cam2"].replaced
    after = process_recording(folder, true_cameras(sim), workers=1)
    assert np.array_equal(after.xyz, before.xyz) and after.meta["warnings"] == []
    # an index lost entirely: no receive times for cam2, so no way to host time but its own
    # clock -- said in a warning; with the clocks 5 s apart nothing pairs, and nothing breaks
    (folder / "cam2.index.csv").unlink()
    reindex(folder)
    lost = process_recording(folder, true_cameras(sim), workers=2)
    assert any("cam2" in w and "own clock" in w for w in lost.meta["warnings"])
    assert lost.meta["clock_fits"]["cam2"] is None
    assert len(lost) == 0 and lost.meta["unpaired_frames"]["cam1"] == 75
    assert lost.meta["paired_frames"] == 0 and len(lost.xyz) == 0


def test_chunk_matching_follows_match_epipolar(processed):
    """The chunk-wide matcher gives match_epipolar's answer frame by frame, including frames
    with ambiguous points (two markers level along the baseline) and missing points."""
    from vts_hw.tracking.chunks import _ideal, _match_chunk
    from vts_hw.vision.triangulate import fundamental_matrix, match_epipolar

    sim, _, _ = processed
    cams = [as_camera(c) for c in true_cameras(sim).values()]
    rng = np.random.default_rng(7)
    frames_a, frames_b = [], []
    for k in range(12):
        X = rng.uniform(-150, 150, (5, 3))
        if k % 3 == 0:  # a second marker in the same epipolar plane (same Y, Z)
            X[1] = X[0] + (90.0, 0.0, 0.0)
        pa = cams[0].project(X) + rng.normal(0, 0.05, (5, 2))
        pb = cams[1].project(X) + rng.normal(0, 0.05, (5, 2))
        pb = pb[rng.permutation(5)][: 5 - (k % 2)]  # shuffled; every other frame loses one
        frames_a.append(pa if k != 4 else pa[:0])  # and one frame sees nothing in camera a
        frames_b.append(pb)
    flat = []
    for cam, fr in zip(cams, (frames_a, frames_b)):
        allp = np.concatenate(fr)
        norm, ideal = _ideal(cam, allp)
        starts = np.concatenate([[0], np.cumsum([len(f) for f in fr])]).astype(int)
        flat.append((allp, norm, ideal, starts))
    ia, ib, fk, amb = _match_chunk(fundamental_matrix(*cams), ProcessSettings(), cams, flat, 12)
    assert amb.sum() > 0  # the ambiguous frames did take the slow path
    for k in range(12):
        m = match_epipolar(cams[0], frames_a[k], cams[1], frames_b[k])
        got = [(a - flat[0][3][k], b - flat[1][3][k]) for a, b in zip(ia[fk == k], ib[fk == k])]
        assert sorted(got) == sorted(m.pairs), k
        assert amb[k] == len(m.ambiguous), k


def test_stereo_calibration_and_export_in_the_spect_frame(processed):
    """With a stereo calibration the VTS frame is camera 1's; the VTS -> SPECT transform
    (here the true one) brings the tracks back onto the scene's truth, on SPECT time."""
    from vts_hw.vision.calibration_io import CameraCalibration, CameraFit

    sim, tracks, _ = processed
    c1, c2 = (as_camera(c) for c in true_cameras(sim).values())
    R = c2.R @ c1.R.T
    # a two-camera calibration in camera 1's frame, its cameras named after its images
    calib = CameraCalibration(
        [
            CameraFit("left", c1.K, c1.dist, np.eye(3), np.zeros(3), (640, 480)),
            CameraFit("right", c2.K, c2.dist, R, c2.t - R @ c1.t, (640, 480)),
        ],
        (9, 6),
        1.0,
        "mm",
        0.0,
        [],
        "",
    )
    to_spect = RigidTransform(c1.R.T, -c1.R.T @ c1.t)  # camera 1's frame -> world (SPECT)
    spect_start = sim.band.start - 1.0
    out = process_recording(sim.folder, calib, workers=2, mapping=to_spect, host_to_spect=lambda h: h - spect_start)
    assert np.abs(out.xyz_spect - tracks.xyz).max() < 1e-6  # the same points, back in SPECT
    assert np.abs(out.xyz - tracks.xyz).max() > 100.0  # ... from camera 1's frame
    assert np.allclose(out.spect_time, out.host_time - spect_start)
    assert out.meta["spect_mapping"]["meta"] == {} and out.meta["cameras"] == ["cam1", "cam2"]


@pytest.mark.parametrize(
    "doc",
    [
        "[]",
        '{"format": "vts-trajectory/1"}',
        '{"format": "vts-trajectory/1", "cameras": [1, 2], "frames": {}}',
        "[" * 5000,
    ],
)
def test_a_trajectory_file_of_the_wrong_shape_is_a_data_error(tmp_path, doc):
    (tmp_path / "t.json").write_text(doc)
    (tmp_path / "t.csv").write_text("frame,marker,x_mm,y_mm,z_mm\n")
    with pytest.raises(DataError, match="t.json"):
        Tracks.load(tmp_path / "t.csv")


def test_a_trajectory_point_on_a_frame_the_json_lacks_is_a_data_error(tmp_path):
    # found by bench/fuzz.py (tracks): the point of frame 5 of a 1-frame table made trajectory() an IndexError
    (tmp_path / "t.json").write_text(
        '{"format": "vts-trajectory/1", "cameras": ["cam1", "cam2"], "frames": '
        '{"host_time": [1.0], "cam1_time": [1.0], "cam2_time": [1.0], "cam1_frame": [0], '
        '"cam2_frame": [0], "cam1_blobs": [1], "cam2_blobs": [1]}}'
    )
    (tmp_path / "t.csv").write_text(
        "frame,marker,x_mm,y_mm,z_mm,reproj_px,cam1_u,cam1_v,cam2_u,cam2_v\n5,1,0,0,0,0,1,1,1,1\n"
    )
    with pytest.raises(DataError, match="not one of the 1 frames"):
        Tracks.load(tmp_path / "t.csv")
