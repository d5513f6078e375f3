"""The simulated patient's model (sim_devices/patient.py): breathing, body moves, creep, the
torso as an occluder, the 6-DOF truth and its files. Pure computation, no server."""

import csv
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vts_hw.sim_devices.patient import (
    BAND_MARKERS,
    PLACEMENT,
    TORSO_HALF_DEPTH,
    BodyMotion,
    BodyMove,
    Breathing,
    Patient,
    add_patient,
    write_truth,
)
from vts_hw.sim_devices.scene import Marker, RigidBody, Scene

T0 = 1_700_000_000.0
LONG_S = 1800.0  # half an hour of breathing: deep breaths and pauses occur


@pytest.fixture(scope="module")
def long_breathing():
    return [Breathing(T0, LONG_S, seed) for seed in range(3)]


def _scene(n_cameras=2):
    s = Scene.reference(seed=0, n_cameras=n_cameras, start_epoch=T0)
    for cam in s.cameras:
        s.set_led(cam, True, T0)
    return s


def _no_breath_patient(moves, creep_mm=0.0):
    return add_patient(_scene(), T0, 120.0, seed=1, breathing=False, moves=moves, creep_mm=creep_mm)


# ------------------------------------------------------------------------------ breathing


def test_breathing_period_is_3_to_6_s_and_varies_cycle_to_cycle(long_breathing):
    for b in long_breathing:
        normal = [c for c in b.cycles if c.kind == "normal"]
        periods = np.array([c.period_s for c in normal])
        assert periods.min() >= 3.0 and periods.max() <= 6.0
        assert periods.std() > 0.15 and np.mean(np.abs(np.diff(periods))) > 0.1
        # the signal itself: each breath peaks at 40 % of its cycle, by its amplitude
        for c in normal[:40]:
            t = np.arange(c.t_start, c.t_start + c.period_s, 0.01)
            v = b.value(t)
            assert t[np.argmax(v)] == pytest.approx(c.t_start + 0.4 * c.period_s, abs=0.15)  # the baseline tilts it
            assert v.max() - v[0] == pytest.approx(c.amplitude, abs=0.06)
            assert 60.0 / b.rate_per_min(c.t_start + 1.0) == pytest.approx(c.period_s)


def test_deep_breaths_and_pauses_occur_over_long_runs(long_breathing):
    for b in long_breathing:
        normal = np.median([c.amplitude for c in b.cycles if c.kind == "normal"])
        deep = [c for c in b.cycles if c.kind == "deep"]
        pauses = [c for c in b.cycles if c.kind == "pause"]
        assert deep and pauses
        for c in deep:
            t = np.arange(c.t_start, c.t_start + c.period_s, 0.01)
            assert np.ptp(b.value(t)) > 1.5 * normal
        for c in pauses:
            assert 2.0 <= c.period_s <= 5.0
            t = np.arange(c.t_start + 0.02, c.t_start + c.period_s - 0.02, 0.01)
            assert np.ptp(b.value(t)) < 0.03 * c.period_s  # held: only the baseline drifts
            assert np.all(b.phase(t) == 0.0)


def test_the_baseline_wanders_but_stays_bounded(long_breathing):
    for b in long_breathing:
        ends = b.value([c.t_start for c in b.cycles if T0 <= c.t_start <= T0 + LONG_S])
        assert np.abs(ends).max() <= b.wander + 1e-9
        assert np.ptp(ends) > 0.03


def test_breathing_off_is_flat():
    b = Breathing(T0, 60.0, 0, enabled=False)
    assert not b.cycles and not np.any(b.value(np.linspace(T0, T0 + 60, 500)))


def test_breathing_amplitudes_per_band():
    """Chest 2-5 mm and abdomen 5-15 mm anterior-posterior (the band's largest), a smaller
    head-foot part; markers move by b(t) times their direction."""
    chest, abd = [], []
    for seed in range(12):
        p = Patient(Breathing(T0, 30.0, seed), BodyMotion(), seed)
        chest.append(p.breath_mm["chest"])
        abd.append(p.breath_mm["abdomen"])
        for band, ids in BAND_MARKERS.items():
            d = np.array([p.breath_dir[i] for i in ids])
            assert d[:, 1].max() == pytest.approx(p.breath_mm[band])
            assert np.all(d[:, 1] > 0.3 * p.breath_mm[band])  # the flanks move too, less
            assert np.all(0 < np.abs(d[:, 2])) and np.all(np.abs(d[:, 2]) < 0.5 * d[:, 1].max())
        c = next(c for c in p.breathing.cycles if c.kind == "normal" and c.t_start > T0)
        t_a, t_b = c.t_start, c.t_start + 0.4 * c.period_s
        a, b = p.marker_truth(t_a), p.marker_truth(t_b)
        db = float(p.breathing.value(t_b) - p.breathing.value(t_a))
        for i in a:
            assert b[i] - a[i] == pytest.approx(db * p.breath_dir[i], abs=1e-9)
    assert 2.0 <= min(chest) and max(chest) <= 5.0 and np.ptp(chest) > 1.0
    assert 5.0 <= min(abd) and max(abd) <= 15.0 and np.ptp(abd) > 3.0


# ------------------------------------------------------------------------------ body motion


def test_a_pure_translation_is_the_six_dof_change():
    p = _no_breath_patient([BodyMove(T0 + 20, T0 + 21, (0.0, 0.0, 0.0), (4.0, -3.0, 12.0))])
    assert np.allclose(p.six_dof(T0 + 19.99), 0.0)
    assert np.allclose(p.six_dof(T0 + 20.5), [2.0, -1.5, 6.0, 0, 0, 0])  # min-jerk: half at the middle
    assert np.allclose(p.six_dof(T0 + 30), [4.0, -3.0, 12.0, 0, 0, 0])


def test_a_rotation_turns_about_the_body_origin_and_moves_compose():
    rot = (1.0, -2.5, 3.0)
    p = _no_breath_patient(
        [
            BodyMove(T0 + 20, T0 + 21, rot, (0.0, 0.0, 0.0)),
            BodyMove(T0 + 30, T0 + 31, (0.0, 0.0, 0.0), (10.0, 0.0, 0.0)),
            BodyMove(T0 + 40, T0 + 41, (0.0, 4.0, 0.0), (0.0, 0.0, -5.0)),
        ]
    )
    origin = np.array(PLACEMENT)
    R, t = p.body_transform(T0 + 25)
    assert np.allclose(R @ origin + t, origin)  # the origin stays where it was
    six = p.six_dof(T0 + 25)
    assert np.allclose(Rotation.from_euler("xyz", six[3:], degrees=True).as_rotvec(), np.deg2rad(rot))
    R, t = p.body_transform(T0 + 50)
    assert np.allclose(R @ origin + t, origin + [10.0, 0.0, -5.0])  # turns never swing earlier shifts
    expect = Rotation.from_rotvec(np.deg2rad([0, 4.0, 0])) * Rotation.from_rotvec(np.deg2rad(rot))
    assert np.allclose(R, expect.as_matrix())


def test_creep_is_slow_and_mostly_along_the_table():
    s = _scene()
    p = add_patient(s, T0, 300.0, seed=2, n_moves=0, creep_mm=6.0, still_s=15.0, breathing=False)
    (c,) = p.motion.creeps
    assert (c.t_start, c.t_end) == (T0 + 15.0, T0 + 300.0)
    assert np.allclose(p.six_dof(T0 + 10), 0.0)
    mid, end = p.six_dof((c.t_start + c.t_end) / 2)[:3], p.six_dof(T0 + 300)[:3]
    assert np.linalg.norm(end) == pytest.approx(6.0) and np.allclose(mid, end / 2)
    assert abs(end[2]) > 0.8 * 6.0
    assert np.allclose(p.six_dof(T0 + 300)[3:], 0.0)


def test_planned_moves_follow_the_still_period_and_their_ranges():
    for seed in range(5):
        m = BodyMotion.plan(T0, 600.0, seed, n_moves=3, still_s=15.0)
        starts = np.array([x.t_start for x in m.moves])
        assert starts.min() >= T0 + 15.0 and np.all(np.diff(starts) >= 8.0) and starts.max() < T0 + 600
        for x in m.moves:
            assert 2.0 <= np.linalg.norm(x.translation_mm) <= 20.0 + 1e-9
            assert 1.0 <= np.linalg.norm(x.rotation_deg) <= 5.0 + 1e-9
            assert 0.4 <= x.t_end - x.t_start <= 1.5
    with pytest.raises(ValueError, match="too short"):
        BodyMotion.plan(T0, 30.0, 0, n_moves=2, still_s=15.0)


def test_body_transform_takes_the_rest_markers_to_where_they_are():
    s = _scene()
    p = add_patient(s, T0, 120.0, seed=4, n_moves=2, creep_mm=3.0, breathing=False, still_s=10.0)
    rest = p.marker_truth(T0)
    for t in (T0 + 5, p.motion.moves[0].t_start + 0.3, p.motion.moves[1].t_end + 1, T0 + 119):
        R, tr = p.body_transform(t)
        now = p.marker_truth(t)
        moved = {i: R @ x + tr for i, x in rest.items()}
        assert all(np.allclose(moved[i], now[i]) for i in rest)
        assert not np.allclose(R, np.eye(3)) or t < p.motion.moves[0].t_start


# ------------------------------------------------------------------------------ the torso


def test_the_torso_hides_a_marker_behind_it_and_not_one_on_top():
    s = _scene()
    p = add_patient(
        s, T0, 120.0, seed=0, breathing=False, moves=[BodyMove(T0 + 20, T0 + 21, (0, 0, 0), (450.0, 0.0, 0.0))]
    )
    below = np.array(PLACEMENT) + [0.0, -TORSO_HALF_DEPTH - 40.0, 0.0]
    s.add_body(RigidBody("under", [Marker("U", below, np.array([0, 1.0, 0]), 15.0, "sphere")]))
    for cam in s.cameras:
        seen = {m for m, _, _ in s.truth(cam, T0 + 1)}
        assert "U" not in seen and set(BAND_MARKERS["chest"]) <= seen, cam
        eye = s.camera_at(cam, T0 + 1).center
        assert p.hides(eye, below[None], T0 + 1)[0]
        on_top = np.array([p.marker_truth(T0 + 1)["C2"]])
        assert not p.hides(eye, on_top, T0 + 1, grow_mm=7.5)[0]
    # the torso moves with the body: shifted aside, it no longer hides the marker below
    assert "U" in {m for m, _, _ in s.truth("cam1", T0 + 30)}


def test_no_two_band_markers_share_an_epipolar_line_at_rest():
    """The bands go round askew: in each stereo pair of the reference rig every marker is well
    off the epipolar plane of every other (else a pair of cameras cannot tell them apart)."""
    s = _scene(4)
    p = add_patient(s, T0, 60.0, seed=0, breathing=False)
    pts = p.marker_truth(T0)
    for a, b in (("cam1", "cam2"), ("cam3", "cam4")):
        c1, c2 = s.cameras[a].center, s.cameras[b].center
        for i, x in pts.items():
            n = np.cross(c2 - c1, x - c1)
            n /= np.linalg.norm(n)
            for j, y in pts.items():
                if i != j:
                    assert abs(np.dot(y - c1, n)) > 5.0, (a, b, i, j)


# ------------------------------------------------------------------------------ truth files


def test_truth_files_are_readable_and_agree_with_the_model(tmp_path):
    s = _scene()
    p = add_patient(s, T0, 60.0, seed=5, n_moves=2, still_s=10.0)
    js, path = write_truth(p, tmp_path / "truth", T0, T0 + 20.0, rate_hz=25.0)
    meta = json.loads(js.read_text())
    assert meta["bands"] == {k: list(v) for k, v in BAND_MARKERS.items()}
    assert [m["t_start"] for m in meta["moves"]] == [m.t_start for m in p.motion.moves]
    assert meta["breath_mm"] == p.breath_mm
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 500
    for row in rows[::37]:
        t = float(row["t"])
        six = p.six_dof(t)
        assert [float(row[k]) for k in ("tx_mm", "ty_mm", "tz_mm", "rx_deg", "ry_deg", "rz_deg")] == pytest.approx(
            six, abs=1e-4
        )
        assert float(row["breath"]) == pytest.approx(float(p.breathing.value(t)), abs=1e-4)
        truth = p.marker_truth(t)
        assert [float(row[f"A3_{a}"]) for a in "xyz"] == pytest.approx(truth["A3"], abs=1e-4)


def test_every_camera_sees_all_eight_apart_from_each_other_and_the_wall():
    for seed in range(3):
        s = _scene(4) if seed == 0 else Scene.reference(seed=seed, n_cameras=4, start_epoch=T0)
        add_patient(s, T0, 60.0, seed=seed, breathing=False)
        for cam in s.cameras:
            seen = {m: np.array((u, v)) for m, u, v in s.truth(cam, T0 + 1)}
            assert set(BAND_MARKERS["chest"] + BAND_MARKERS["abdomen"]) <= set(seen), (seed, cam)
            for m, uv in seen.items():
                if m[0] in "CA":
                    gaps = [np.linalg.norm(uv - other) for k, other in seen.items() if k != m]
                    assert min(gaps) > 30.0, (seed, cam, m)
