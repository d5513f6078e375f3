"""The camera clock model (offset and skew from frames' camera and host times) against the
scene's true CameraClock."""

import numpy as np
import pytest
from scipy.optimize import linprog

from vts_hw.errors import DataError
from vts_hw.sim_devices.recording_sim import simulate_recording
from vts_hw.sim_devices.scene import CameraClock
from vts_hw.timing.camera_clock import ClockFit, fit_camera_clock, fit_recording_clocks, lower_envelope

START = 1_790_000_000.0
FLOOR = 0.004


def synthetic(clock: CameraClock, seconds: float, fps: float = 25.0, seed: int = 0, outlier_rate: float = 0.01):
    """Exposures on a host-time grid, truncated 10 ms stamps, receive times with a delay floor,
    exponential jitter, rare large outliers and head-of-line blocking (like the recorder)."""
    rng = np.random.default_rng(seed)
    t = START + 3.0 + np.arange(int(seconds * fps)) / fps
    stamps = np.floor(np.array([clock.camera_time(x) for x in t]) * 100.0 + 1e-6) / 100.0
    lat = FLOOR + rng.exponential(0.003, t.size)
    late = rng.random(t.size) < outlier_rate
    lat[late] += rng.uniform(0.05, 0.3, late.sum())
    recv = np.maximum.accumulate(t + lat)
    return t, stamps, recv, late


def test_envelope_is_the_linear_programme_solution():
    rng = np.random.default_rng(3)
    for n in (5, 40, 800):
        x = np.unique(np.round(rng.uniform(-60, 60, n), 2))
        y = 2e-5 * x + rng.exponential(0.004, x.size) + (rng.random(x.size) < 0.05) * 0.2
        a, k = lower_envelope(x, y)
        lp = linprog(
            c=[-x.size, -x.sum()],
            A_ub=np.column_stack([np.ones(x.size), x]),
            b_ub=y,
            bounds=[(None, None)] * 2,
            method="highs",
        )
        assert lp.success
        assert a == pytest.approx(lp.x[0], abs=1e-9) and k == pytest.approx(lp.x[1], abs=1e-10)
        assert (y - (a + k * x)).min() > -1e-12  # below every point


def test_twenty_minute_scan_maps_frames_to_exposure_times():
    clock = CameraClock(offset_s=2.37, skew_ppm=41.0, ref_epoch=START)
    t, stamps, recv, _ = synthetic(clock, 1200.0)
    fit = fit_camera_clock(stamps, recv, latency_s=FLOOR)
    assert fit.dequantised
    err = fit.frame_host_times() - t
    assert np.abs(err).max() < 0.0005
    assert fit.skew_ppm == pytest.approx(clock.skew_ppm, abs=1.0)
    # Against the true clock: camera time -> host time over the whole scan.
    c = np.linspace(stamps[0], stamps[-1], 50)
    truth = np.array([clock.host_time(v) for v in c])
    assert np.abs(fit.host_time(c) - truth).max() < 0.0005
    assert fit.camera_time(fit.host_time(c[7])) == pytest.approx(c[7], abs=1e-7)
    s = fit.summary()
    assert s["residual_max_s"] > 0.05 and s["late_frames"] > 50  # the outliers are reported
    assert np.nanmin(fit.residuals_s) == pytest.approx(0.0, abs=1e-9)
    assert 0 <= fit.uncertainty_s < 0.001
    # Without de-quantising, the stamps' phase sweeping the tick (41 ppm over 20 min) leaves
    # frames up to a tick early.
    raw = fit_camera_clock(stamps, recv, latency_s=FLOOR, dequantise_stamps=False)
    assert (raw.frame_host_times() - t).min() < -0.008


def test_irregular_frames_keep_their_stamps():
    clock = CameraClock(offset_s=0.8, skew_ppm=20.0, ref_epoch=START)
    t, stamps, recv, _ = synthetic(clock, 60.0)
    rng = np.random.default_rng(2)
    jitter = rng.uniform(0, 0.03, t.size)  # exposures up to 30 ms off the grid
    t2 = t + jitter
    stamps2 = np.floor(np.array([clock.camera_time(x) for x in t2]) * 100.0 + 1e-6) / 100.0
    fit = fit_camera_clock(stamps2, recv + jitter, latency_s=FLOOR)
    assert not fit.dequantised
    err = fit.frame_host_times() - t2
    assert err.min() > -0.0105 and err.max() < 0.001


def test_late_frames_do_not_move_the_fit():
    clock = CameraClock(offset_s=-1.2, skew_ppm=-25.0, ref_epoch=START)
    t, stamps, recv, _ = synthetic(clock, 120.0, seed=4, outlier_rate=0.0)
    clean = fit_camera_clock(stamps, recv)
    rng = np.random.default_rng(5)
    worse = recv.copy()
    hit = rng.random(recv.size) < 0.3  # 30 % of the frames up to a second late
    worse[hit] += rng.uniform(0.01, 1.0, hit.sum())
    fit = fit_camera_clock(stamps, worse)
    assert np.abs(fit.host_time(stamps) - clean.host_time(stamps)).max() < 0.001
    # an ordinary least-squares line would be pulled by about the mean extra delay
    assert (
        np.polyfit(stamps - stamps[0], worse - stamps, 1)[1] - np.polyfit(stamps - stamps[0], recv - stamps, 1)[1] > 0.1
    )


def test_simulated_recording_against_the_scene_clocks(tmp_path):
    sim = simulate_recording(tmp_path / "rec", duration_s=4.0, clock_offsets_s={"cam1": 1.5})
    fits = fit_recording_clocks(tmp_path / "rec", latency_s=FLOOR)
    assert set(fits) == {"cam1", "cam2"}
    for cam, fit in fits.items():
        clock = sim.scene.clocks[cam]
        err = fit.host_time(sim.camera_time[cam]) - sim.exposure[cam]
        assert np.abs(err).max() < 0.001, cam  # the tick's phase is fixed over 4 s
        # the offset is the camera clock's, up to the stamps' unknown phase within a tick
        true_offset = fit.ref_camera_time - clock.host_time(fit.ref_camera_time)
        assert fit.offset_s == pytest.approx(true_offset, abs=0.011)
        assert fit.n_used == fit.n_frames == len(sim.exposure[cam])
        assert fit.skew_resolution_ppm > 1000  # 10 ms over 4 s: the skew itself is not seen


def test_summary_round_trip_and_missing_stamps():
    clock = CameraClock(offset_s=0.5, skew_ppm=10.0, ref_epoch=START)
    t, stamps, recv, _ = synthetic(clock, 30.0)
    cams = stamps.astype(object)
    cams[::10] = None  # frames without a stamp are left out of the fit
    fit = fit_camera_clock(list(cams), recv)
    assert fit.n_used == fit.n_frames - len(range(0, len(t), 10))
    assert np.isnan(fit.residuals_s[0]) and np.isfinite(fit.residuals_s[1])
    back = ClockFit.from_summary(fit.summary())
    assert back.host_time(stamps[5]) == pytest.approx(fit.host_time(stamps[5]), abs=1e-9)
    assert back.skew_ppm == pytest.approx(fit.skew_ppm)


def test_too_few_frames_is_a_data_error():
    with pytest.raises(DataError):
        fit_camera_clock([1.0, None], [2.0, 3.0])


def test_frames_coming_later_and_later_do_not_bend_the_clock():
    """A host (or a simulator) falling behind and never catching up: each frame arrives later
    than the last, up to 8 s at the end of 22 s (seen in make test on a busy machine, where the
    free envelope made a 'skew' of -300 000 ppm and put a body move 3.3 s late). No clock runs
    that fast: the frames do not measure the rate, the fit says so and maps by the least
    delayed frames with the host's rate, within a plausible skew's error over the span."""
    clock = CameraClock(offset_s=1.37, skew_ppm=30.0, ref_epoch=START)
    t, stamps, recv, _ = synthetic(clock, 22.0, outlier_rate=0.0)
    behind = 8.0 * ((t - t[0]) / (t[-1] - t[0])) ** 1.5  # the lag grows to the end
    recv = np.maximum.accumulate(recv + behind)
    free_a, free_k = lower_envelope(stamps - np.median(stamps), recv - stamps)
    assert abs(free_k) > 0.01  # the free fit would bend
    fit = fit_camera_clock(stamps, recv, latency_s=FLOOR)
    assert fit.summary()["rate_measured"] is False and fit.skew_ppm == 0.0
    err = fit.frame_host_times() - t
    assert np.abs(err).max() < 0.003  # 30 ppm over 22 s, and the floor
    assert fit.uncertainty_s >= 1e-4 * (stamps[-1] - stamps[0]) - 1e-12
    # a clock that is truly skewed, with frames on time, is still measured
    ok = fit_camera_clock(
        *synthetic(CameraClock(offset_s=1.37, skew_ppm=400.0, ref_epoch=START), 120.0)[1:3], latency_s=FLOOR
    )
    assert ok.rate_measured and ok.skew_ppm == pytest.approx(400.0, abs=5.0)
