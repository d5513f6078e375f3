"""The simulated SPECT list-mode against its own truth, and the source marker in the scene.

Offline: a hand-made square wave (host time) and a scene with a source marker; the sim writes
a VTSLM file and its truth beside it. What is checked here is the file's content against the
truth (rates, positions, dead time, marks, frames, gating levels) and that the truth is kept
out of the file; the analysis is tested in tests/integration/test_sync_gating.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

from vts_hw.sim_devices.scene import Scene
from vts_hw.sim_devices.source_marker import add_source_marker, min_jerk, plan_moves, source_marker_from_json
from vts_hw.sim_devices.spect_listmode import (
    ListModeTruth,
    SimListModeSpect,
    SimSpectSettings,
    Source,
    TriggerEdges,
    edges_from_trigger_log,
    truth_path,
    write_sim_listmode,
)
from vts_hw.spect.listmode import read_listmode

T0 = 1_795_000_000.0


def square_wave(start: float, period: float, duty: float, n: int, high=5.0, low=0.0, pulse=True):
    rising = start + np.arange(n) * period
    return TriggerEdges(rising, rising + duty * period, start if pulse else None, high, low, "test")


@pytest.fixture(scope="module")
def sim60(tmp_path_factory):
    """One 60 s acquisition (3 moves) shared by the content checks."""
    tmp = tmp_path_factory.mktemp("sim60")
    scene = Scene.reference(seed=2, start_epoch=T0)
    fire = T0 + 3.0
    times, steps = plan_moves(fire, 60.0, n=3, seed=4)
    src = add_source_marker(scene, times, steps, position=(10.0, -20.0, 5.0), rate_cps=3000.0)
    settings = SimSpectSettings(gate_gain=0.5)
    truth = write_sim_listmode(tmp / "a.vtslm", scene, [src], square_wave(fire, 1.0, 0.5, 70), 60.0, settings, seed=11)
    return tmp / "a.vtslm", truth, src, read_listmode(tmp / "a.vtslm")


def test_the_truth_is_kept_apart_from_the_list_mode(sim60):
    path, truth, src, lm = sim60
    saved = ListModeTruth.load(truth_path(path))
    assert saved == truth and truth_path(path).name == "a.vtslm.truth.json"
    raw = path.read_bytes()
    header = json.dumps(lm.header)
    for word in ("delay", "offset", "skew", "truth", "move"):
        assert word not in header
    for value in (truth.start_delay_s, truth.clock_offset_s, truth.clock_skew_ppm):
        assert repr(value).encode() not in raw
    # what the header says is the SPECT's own view: its wall clock at its start
    assert lm.start_time == pytest.approx(truth.acquisition_start_host + truth.clock_offset_s, abs=1e-6)
    assert 0.05 <= truth.start_delay_s <= 0.4
    assert abs(truth.clock_offset_s) <= 3 and abs(truth.clock_skew_ppm) <= 50
    assert truth.n_events == lm.n_events


def test_event_rate_and_no_events_in_dead_time(sim60):
    _, truth, src, lm = sim60
    dead = np.array(truth.dead)
    assert dead.shape == (2, 2)  # rotations at ~20 s and ~42 s
    assert np.allclose(dead[:, 1] - dead[:, 0], 2.0, atol=0.2)
    assert dead[0, 0] == pytest.approx(20.0)
    live = 60.0 - np.sum(dead[:, 1] - dead[:, 0])
    expected = 3000.0 * live
    assert abs(lm.n_events - expected) < 5 * np.sqrt(expected)  # Poisson
    for d0, d1 in dead:
        assert not np.any((lm.t >= d0) & (lm.t < d1))
    assert np.allclose(lm.dead, dead, rtol=0, atol=1e-9)  # the file records them too (ns)
    assert lm.t.min() >= 0 and lm.t.max() < 60.0
    gaps = np.diff(lm.t[(lm.t > 1) & (lm.t < 19)])  # exponential inter-arrival times
    assert np.mean(gaps) == pytest.approx(1 / 3000, rel=0.03)
    assert set(np.unique(lm.head)) == {0, 1}


def test_detected_positions_are_the_source_plus_4_mm_blur(sim60):
    _, truth, src, lm = sim60
    host = truth.host_time(lm.t)
    z_true = src.z_at(host) + 0.0  # the table never moved
    still = np.ones(lm.t.size, bool)
    for m in src.moves:
        still &= (host < m.t_start - 0.01) | (host > m.t_end + 0.01)
    dz = lm.z[still] - z_true[still]
    assert abs(np.mean(dz)) < 0.05
    assert np.std(dz) == pytest.approx(4.0, rel=0.02)
    # transaxial: x cos(theta) + y sin(theta) for the head's angle (head 1 at 180 degrees)
    head0 = still & (lm.head == 0) & (lm.t < 19)
    head1 = still & (lm.head == 1) & (lm.t < 19)
    assert np.mean(lm.u[head0]) == pytest.approx(10.0, abs=0.1)
    assert np.mean(lm.u[head1]) == pytest.approx(-10.0, abs=0.1)


def test_timing_marks_frames_and_angles(sim60):
    _, truth, _, lm = sim60
    assert lm.timing_marks.size == 6000 and np.allclose(np.diff(lm.timing_marks), 0.01)
    assert lm.frame_starts.size == 600 and np.allclose(np.diff(lm.frame_starts), 0.1)
    stops = lm.frame_angles[(lm.frame_starts < 20.0)]
    assert np.all(stops == 0.0)
    after = lm.frame_angles[(lm.frame_starts >= truth.dead[0][1]) & (lm.frame_starts < truth.dead[1][0])]
    assert np.all(after == 6.0)
    rotating = lm.frame_angles[(lm.frame_starts > truth.dead[0][0]) & (lm.frame_starts < truth.dead[0][1])]
    assert np.all((rotating > 0) & (rotating < 6)) and np.all(np.diff(rotating) > 0)


def test_the_gating_voltage_is_the_wave_as_sent(sim60):
    _, truth, _, lm = sim60
    assert lm.gate_t.size == 120_000  # 2 kHz on the SPECT clock
    v = lm.gate_v
    high = v[v > 1.25]
    low = v[v <= 1.25]
    assert np.median(high) == pytest.approx(2.5, abs=0.01)  # 5 V sent, gain 0.5
    assert np.median(low) == pytest.approx(0.0, abs=0.01)
    mad = np.median(np.abs(low - np.median(low)))
    assert 1.4826 * mad == pytest.approx(0.02, rel=0.1)  # the noise
    # high exactly while the wave is high (away from the edges)
    host = truth.host_time(lm.gate_t)
    phase = (host - truth.start_pulse_host) % 1.0
    clear = (np.abs(phase - 0.0) > 0.002) & (np.abs(phase - 0.5) > 0.002) & (np.abs(phase - 1.0) > 0.002)
    assert np.all((v[clear] > 1.25) == (phase[clear] < 0.5))


def test_a_background_spreads_over_the_field_of_view(tmp_path):
    scene = Scene.reference(seed=0, start_epoch=T0)
    settings = SimSpectSettings(background_cps=2000.0, stop_s=100.0)
    truth = write_sim_listmode(tmp_path / "bg.vtslm", scene, [], square_wave(T0, 1.0, 0.5, 12), 10.0, settings, seed=1)
    lm = read_listmode(tmp_path / "bg.vtslm")
    assert abs(lm.n_events - 20000) < 5 * np.sqrt(20000)
    assert lm.z.min() >= -200 and lm.z.max() <= 200
    assert np.mean(lm.z) == pytest.approx(0.0, abs=3)
    assert truth.dead == []


def test_a_phantom_sphere_can_be_a_source(tmp_path):
    scene = Scene.reference(seed=0, start_epoch=T0)
    scene.add_phantom()
    scene.move_table(0.0, 40.0)  # the table moved 40 mm in Z
    truth = write_sim_listmode(
        tmp_path / "ph.vtslm",
        scene,
        [Source("phantom", "S3", 2000.0)],
        square_wave(T0, 1.0, 0.5, 8),
        5.0,
        SimSpectSettings(start_delay_s=0.1, clock_skew_ppm=0.0),
        seed=2,
    )
    lm = read_listmode(tmp_path / "ph.vtslm")
    s3_z = -71.0 + 40.0
    assert np.mean(lm.z) == pytest.approx(s3_z, abs=0.2)
    assert truth.start_delay_s == 0.1 and truth.clock_skew_ppm == 0.0
    # a source beyond the axial field of view gives no counts
    src = add_source_marker(scene, [], [], name="far", position=(0.0, 0.0, 260.0), rate_cps=2000.0)
    write_sim_listmode(tmp_path / "far.vtslm", scene, [src], square_wave(T0, 1.0, 0.5, 8), 5.0)
    assert read_listmode(tmp_path / "far.vtslm").n_events == 0
    with pytest.raises(ValueError, match="no marker 'S9'"):
        write_sim_listmode(
            tmp_path / "x.vtslm", scene, [Source("phantom", "S9", 10.0)], square_wave(T0, 1.0, 0.5, 8), 1.0
        )


def test_source_marker_moves_along_z_in_the_scene():
    scene = Scene.reference(seed=0, start_epoch=T0)
    src = add_source_marker(scene, [T0 + 2.0, T0 + 5.0], [20.0, -12.5], position=(0, 0, 3.0), move_s=0.3)
    assert [m.z_to for m in src.moves] == [23.0, 10.5]
    assert src.moves[0].t_mid == pytest.approx(T0 + 2.15)
    body = scene.bodies["source"]

    def z_scene(t):
        return body.markers_at(t, np.zeros(3))[0].center[2]

    assert z_scene(T0 + 1.9) == 3.0 and z_scene(T0 + 2.31) == 23.0 and z_scene(T0 + 6) == 10.5
    # the scheduled staircase follows the smooth truth to within a 5 ms step of a 0.3 s move
    ts = np.linspace(T0 + 1.95, T0 + 2.35, 200)
    diff = np.array([z_scene(t) for t in ts]) - src.z_at(ts)
    assert np.max(np.abs(diff)) < 20.0 * 1.9 * 0.005 / 0.3 + 1e-9  # max slope 1.875 * step/move_s
    assert src.z_at(T0 + 2.15) == pytest.approx(13.0, abs=1e-4)  # epoch floats: 0.2 us
    assert min_jerk(0.5) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="overlap"):
        add_source_marker(scene, [T0 + 1.0, T0 + 1.1], [10, 10], name="other")


def test_a_source_marker_rebuilt_from_its_truth_moves_the_same(tmp_path):
    scene = Scene.reference(seed=0, start_epoch=T0)
    src = add_source_marker(
        scene,
        [T0 + 2.0, T0 + 5.0],
        [20.0, -12.5],
        position=(5, -3, 1),
        move_s=0.25,
        rate_cps=1234.0,
        name="band",
        marker_id="B1",
    )
    data = json.loads(json.dumps(src.to_json()))  # as a truth file keeps it
    other = Scene.reference(seed=0, start_epoch=T0)
    again = source_marker_from_json(other, data)
    assert again == src
    for t in np.linspace(T0, T0 + 6, 97):
        a = scene.bodies["band"].markers_at(t, np.zeros(3))[0].center
        b = other.bodies["band"].markers_at(t, np.zeros(3))[0].center
        assert np.array_equal(a, b)


def test_plan_moves_are_spread_and_alternate():
    times, steps = plan_moves(T0, 60.0, n=4, seed=3)
    assert len(times) == 4 and all(b - a >= 2.0 for a, b in zip(times, times[1:]))
    assert T0 + 2.0 <= times[0] and times[-1] <= T0 + 58.0
    assert all(10 <= abs(s) <= 30 for s in steps)
    assert [np.sign(s) for s in steps] == [1, -1, 1, -1]


def test_edges_from_a_function_generator_log_stop_at_outp_0(tmp_path):
    log = tmp_path / "trigger.csv"
    log.write_text(
        "host_time,device_time_us,device,kind,text\n"
        f"{T0:.6f},,fgen,cmd,FUNC SQU\n"
        f"{T0 + 0.01:.6f},,fgen,cmd,FREQ 2\n"
        f"{T0 + 0.02:.6f},,fgen,cmd,FUNC:SQU:DCYC 25\n"
        f"{T0 + 0.03:.6f},,fgen,cmd,VOLT:HIGH 2.5\n"
        f"{T0 + 0.04:.6f},,fgen,cmd,VOLT:LOW 0\n"
        f"{T0 + 1.0:.6f},,fgen,cmd,OUTP 1\n"
        f"{T0 + 3.6:.6f},,fgen,cmd,OUTP 0\n"
    )
    e = edges_from_trigger_log(log)
    assert np.allclose(e.rising - T0, [1.0, 1.5, 2.0, 2.5, 3.0, 3.5])
    assert np.allclose(e.falling - T0, [1.125, 1.625, 2.125, 2.625, 3.125, 3.6])  # cut at OUTP 0
    assert (e.high_v, e.low_v, e.start_pulse) == (2.5, 0.0, None)
    # the SPECT then starts on the wave's first edge (no start pulse from a 33500)
    scene = Scene.reference(seed=0, start_epoch=T0)
    spect = SimListModeSpect(scene, [], SimSpectSettings(background_cps=100.0), seed=3)
    truth = spect.follow_trigger_log(log, tmp_path / "fg.vtslm", 2.0)
    assert truth.start_pulse_host is None
    assert truth.acquisition_start_host == pytest.approx(T0 + 1.0 + truth.start_delay_s)
    assert truth.start_delay_from_wave_s == pytest.approx(truth.start_delay_s)


def test_a_list_mode_that_does_not_fit_leaves_nothing_behind(small_disk):
    """A real full disk (a 128 kB tmpfs; 10 s of list-mode is ~0.5 MB): the write fails with
    ENOSPC and neither a half-written list-mode (a glob would pick it up) nor a truth is left."""
    disk = small_disk(128)
    scene = Scene.reference(seed=2, start_epoch=T0)
    src = add_source_marker(scene, [T0 + 5.0], [12.0], position=(10.0, -20.0, 5.0), rate_cps=3000.0)
    with pytest.raises(OSError) as e:
        write_sim_listmode(disk.path / "a.vtslm", scene, [src], square_wave(T0 + 1.0, 1.0, 0.5, 12), 10.0, seed=1)
    assert e.value.errno == 28  # ENOSPC
    assert disk.files() == {}
