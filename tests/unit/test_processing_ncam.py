"""Processing a 4-camera recording of the room with the SPECT heads turning, end to end:
every point from the cameras that see it, nothing invented, more located than with 2 cameras."""

import numpy as np
import pytest

from vts_hw.recording.frames import load_camera_frames
from vts_hw.sim_devices.recording_sim import BreathingBand, simulate_recording
from vts_hw.sim_devices.scene import Scene
from vts_hw.sim_devices.sync_truth import write_true_cameras
from vts_hw.tracking.frame_sets import FrameGrouper, Pending, group_frames, mapped_times
from vts_hw.tracking.identities import MarkerTracks
from vts_hw.tracking.live.tracker import GROUP_WAIT_S
from vts_hw.tracking.processing import process_recording
from vts_hw.tracking.tracks import Tracks

PLACEMENT = (-30.0, 130.0, 20.0)  # the chest, where the heads pass close (bench/n_cameras.py)


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ncam")
    scene = Scene.reference(seed=0, n_cameras=4, start_epoch=1_790_000_000.0, gantry=True)
    start = scene.start_epoch + 5.0
    scene.gantry.step_and_shoot(start, 3.0, 20, 0.4, 0.2, start_deg=0.0, radius_mm=230.0)
    sim = simulate_recording(
        tmp / "rec",
        duration_s=5.0,
        seed=0,
        scene=scene,
        start=start,
        band=BreathingBand(start, placement=PLACEMENT),
        gaps={"cam3": [(1.0, 1.6)]},
    )
    cams = write_true_cameras(scene, tmp, start, frame="world")  # the N-camera calibration file
    four = process_recording(sim.folder, cams_from(cams), workers=2)
    two = process_recording(sim.folder, {k: v for k, v in cams_from(cams).items() if k in ("cam1", "cam2")}, workers=2)
    return sim, four, two, cams


def cams_from(path):
    from vts_hw.vision.camera_set import load_cameras

    return load_cameras(path)


def per_set(sim, tracks):
    """Per frame set: exposure per camera, the true positions, and which cameras see which marker."""
    names = tracks.camera_names
    exp = np.column_stack(
        [
            np.where(tracks.camera_frame[:, c] >= 0, sim.exposure[n][np.maximum(tracks.camera_frame[:, c], 0)], np.nan)
            for c, n in enumerate(names)
        ]
    )
    ids, truth = sim.marker_positions(np.nanmean(exp, axis=1))
    seen = np.array(
        [
            [
                sim.seen_by(n, exp[f, c]) if np.isfinite(exp[f, c]) else np.zeros(len(ids), bool)
                for c, n in enumerate(names)
            ]
            for f in range(len(exp))
        ]
    )  # (F, C, M)
    return ids, truth, seen


def located(sim, tracks):
    ids, truth, seen = per_set(sim, tracks)
    err = np.linalg.norm(truth[tracks.point_frame] - tracks.xyz[:, None, :], axis=2)
    nearest, d = err.argmin(axis=1), err.min(axis=1)
    n_seen = seen.sum(axis=1)  # (F, M) cameras seeing each marker
    got = np.zeros_like(n_seen, bool)
    got[tracks.point_frame[d < 2.0], nearest[d < 2.0]] = True
    return got, n_seen, nearest, d, seen


def test_four_cameras_around_the_turning_heads(recorded):
    sim, four, two, _ = recorded
    assert four.camera_names == ["cam1", "cam2", "cam3", "cam4"]
    got, n_seen, nearest, d, seen = located(sim, four)
    eligible = n_seen >= 2
    share = got[eligible].mean()
    assert share >= 0.99  # measured 99.8 % (bench/n_cameras.py, 20 s: 99.9 %)
    assert float(np.sqrt(np.mean(d**2))) < 0.12 and d.max() < 1.0
    assert (n_seen == 1).any() and (n_seen >= 2).any() and (n_seen < 4).any()  # the heads do hide
    # nothing invented: each point only from cameras that see its marker, never fewer than two
    pc = four.point_cameras
    assert pc.sum(axis=1).min() >= 2
    assert not (pc & ~seen[four.point_frame, :, nearest]).any()
    assert set(four.meta["points_by_cameras_seen"]) == {"2", "3", "4"}
    assert all(v > 0 for v in four.meta["points_by_cameras_seen"].values())
    # a marker seen by one camera only is reported as such, per frame set and camera
    assert four.n_single.sum() > 0 and sum(four.meta["single_camera_detections"].values()) == four.n_single.sum()
    # the head pair alone locates fewer
    got2, n_seen2, *_ = located(sim, two)
    assert got.sum() > 1.2 * got2.sum()


def test_a_camera_that_drops_out_leaves_the_others_tracking(recorded):
    sim, four, _, _ = recorded
    n = len(sim.exposure["cam1"])
    # cam4's frames come 39 ms after cam1's: its last one may find no set (reported, not lost)
    assert all(v <= 1 for v in four.meta["unpaired_frames"].values())
    assert sum(four.meta["unpaired_frames"].values()) + int((four.camera_frame >= 0).sum()) == sum(
        len(v) for v in sim.exposure.values()
    )
    missing = four.camera_frame[:, 2] < 0
    assert 10 <= missing.sum() <= 16  # 0.6 s of cam3 lost: 15 frames
    assert (four.camera_frame[:, 0] >= 0).sum() == n  # every frame of cam1 in a set
    assert (four.n_blobs[missing, 2] == -1).all()
    assert not four.point_cameras[np.isin(four.point_frame, np.flatnonzero(missing)), 2].any()


def test_four_camera_tracks_file_round_trip(recorded, tmp_path):
    _, four, _, _ = recorded
    csv, _ = four.save(tmp_path / "tracks")
    header = csv.read_text().splitlines()[0].split(",")
    assert header[:10] == [
        "frame",
        "host_time",
        "cam1_frame",
        "cam1_time",
        "cam2_frame",
        "cam2_time",
        "cam3_frame",
        "cam3_time",
        "cam4_frame",
        "cam4_time",
    ]
    assert header[-8:] == [f"cam{k}_{a}" for k in range(1, 5) for a in "uv"]
    back = Tracks.load(tmp_path / "tracks")
    assert back.camera_names == four.camera_names
    assert np.array_equal(back.camera_frame, four.camera_frame)
    assert np.array_equal(back.point_cameras, four.point_cameras)
    assert np.allclose(back.uv, four.uv, atol=1e-4, equal_nan=True)
    assert np.array_equal(back.n_single, four.n_single) and np.array_equal(back.n_blobs, four.n_blobs)


def test_one_worker_gives_the_same_four_camera_tracks(recorded):
    sim, four, _, cams = recorded
    serial = process_recording(sim.folder, cams_from(cams), workers=1)
    assert np.array_equal(serial.marker, four.marker)
    assert np.allclose(serial.xyz, four.xyz, atol=1e-9)


def test_group_frames_of_three_cameras():
    t = np.arange(10) * 0.04
    sets = group_frames([t, t + 0.013, np.delete(t + 0.026, [3, 4])], 0.02)
    # 26 ms after the first frame, but 19.5 ms from the set's mean time: the third joins
    assert sets.shape == (10, 3) and (sets[:, 0] == np.arange(10)).all()
    assert list(sets[3:5, 2]) == [-1, -1] and (sets[:, 1] == np.arange(10)).all()
    # two cameras: each frame of the second joins the first camera's frame 1 ms before it
    two = group_frames([t, t[::2] + 0.001], 0.02)
    assert two.tolist() == [[2 * k, k] for k in range(5)]
    # a set needs two cameras: a frame alone is left out
    lone = group_frames([t[:5], t[:5] + 0.01, np.array([5.0])], 0.02)
    assert len(lone) == 5 and (lone[:, 2] == -1).all()


def live_sets(folder, names, tolerance_s):
    """The live path's frame sets of a recording: its frames fed to the grouper as the live
    tracker builds it, one at a time in the order they were received (a frame's receipt its
    arrival), asking for the sets ready after each; then time passes. The frames' times are the
    processing's (how each path maps a camera's clock is not the grouper's). Per set, each
    camera's frame number (-1: none)."""
    frames = [load_camera_frames(folder, n) for n in names]
    times = [mapped_times(cf, 0.0)[0] for cf in frames]
    grouper = FrameGrouper(len(names), tolerance_s, max(1.5 * 0.04, GROUP_WAIT_S))
    arrivals = sorted((cf.host_time[i], c, i) for c, cf in enumerate(frames) for i in range(len(cf.frame)))
    sets = []
    for arrival, c, i in arrivals:
        grouper.add(Pending(c, float(times[c][i]), float(arrival), np.zeros((0, 2)), index=i))
        sets += grouper.ready(float(arrival))
    sets += grouper.ready(arrivals[-1][0] + 10.0)
    return np.array(
        [[-1 if i < 0 else int(frames[c].frame[i]) for c, i in enumerate(fs.index)] for fs in sets]
    ).reshape(-1, len(names))


def test_the_live_path_groups_and_names_as_the_processing_does(recorded):
    """One grouper and one identity tracker on both paths (decision 0090): the recording's
    frames, fed one by one to the live path's grouper in the order they arrived -- cam3 lost
    0.6 s of frames, and a frame now and then arrived 50-300 ms late -- make exactly the frame
    sets the processing made, with four cameras and with two; and the live path's identity
    tracker, given those sets' points in order, names every point as the processing did."""
    sim, four, two, _ = recorded
    for tracks in (four, two):
        live = live_sets(sim.folder, tracks.camera_names, tracks.meta["pair_tolerance_s"])
        assert np.array_equal(live, tracks.camera_frame)
    assert (four.camera_frame[:, 2] < 0).sum() >= 10  # the loss is in it
    assert (four.camera_frame >= 0).sum(axis=1).min() == 2 and (four.camera_frame >= 0).all(axis=1).any()
    ids = MarkerTracks(four.meta["settings"]["gate_mm"], four.meta["settings"]["max_gap_s"])
    live_ids = np.concatenate(
        [ids.update(four.host_time[f], four.xyz[four.point_frame == f]) for f in range(len(four))]
    )
    assert np.array_equal(live_ids, four.marker) and four.marker.max() > 5
