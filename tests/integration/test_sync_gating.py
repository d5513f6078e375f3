"""The gating analysis against the simulated SPECT's truth: edges, start delay, the SPECT
clock's skew and offset, dead time, the axial centre of mass; offline, with the trigger-box
firmware in the loop, and following the pyvisa-sim function generator through its log."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from vts_hw.drivers.function_generator import SIM_RESOURCE, FunctionGenerator
from vts_hw.drivers.trigger import TriggerLog
from vts_hw.drivers.trigger_box import TriggerBox
from vts_hw.errors import DataError
from vts_hw.recording.trigger_wave import square_wave_edges, wave_from_trigger_log
from vts_hw.sim_devices.scene import Scene
from vts_hw.sim_devices.source_marker import add_source_marker
from vts_hw.sim_devices.spect_listmode import (
    SimListModeSpect,
    SimSpectSettings,
    TriggerEdges,
    edges_from_trigger_box,
    write_sim_listmode,
)
from vts_hw.sim_devices.trigger_box import F_CPU, SimTriggerBox
from vts_hw.spect.gating import (
    analyze_gating,
    axial_centre_of_mass,
    dead_time_from_events,
    find_gate_edges,
    fit_spect_clock,
)
from vts_hw.spect.listmode import GATE_TRANSITIONS, ListMode, base, read_listmode, register_reader

T0 = 1_795_000_000.0


def square_wave(start, period, duty, n, high=5.0, low=0.0, pulse=True):
    rising = start + np.arange(n) * period
    return TriggerEdges(rising, rising + duty * period, start if pulse else None, high, low, "test")


def simulate(
    tmp_path: Path, *, period=1.0, duty=0.5, duration=60.0, seed=0, moves=None, rate=2000.0, name="a.vtslm", **settings
):
    scene = Scene.reference(seed=seed, start_epoch=T0)
    fire = T0 + 2.0
    move_times, steps = moves if moves is not None else ([], [])
    src = add_source_marker(scene, [fire + m for m in move_times], steps, rate_cps=rate)
    wave = square_wave(fire, period, duty, int(duration / period) + 3)
    truth = write_sim_listmode(tmp_path / name, scene, [src], wave, duration, SimSpectSettings(**settings), seed=seed)
    return read_listmode(tmp_path / name), truth, wave, src


# ------------------------------------------------------------------- start delay and clock


@pytest.mark.parametrize(
    "period, duty, gain, delay, seed",
    [
        (1.0, 0.5, 1.0, None, 1),  # the default wave, random delay, offset and skew
        (0.5, 0.25, 0.5, None, 2),  # 0/2.5 V recorded
        (2.0, 0.1, 1.0, None, 3),
        (0.1, 0.5, 1.0, 0.07, 4),  # 10 Hz: a delay under one period (see the module docstring)
    ],
)
def test_start_delay_skew_and_offset_recovered(tmp_path, period, duty, gain, delay, seed):
    lm, truth, wave, _ = simulate(tmp_path, period=period, duty=duty, seed=seed, gate_gain=gain, start_delay_s=delay)
    r = analyze_gating(lm, period_s=period, fire_host=wave.start_pulse)
    assert abs(r.start_delay_s - truth.start_delay_s) < 1e-3  # measured: -0.17 +- 0.03 ms
    # the skew over 60 s: the edges' sub-sample timing (+-0.1 ms, depending on where they
    # fall between samples) allows a few ppm; what matters is the mapping over the run
    assert abs(r.clock.skew_ppm - truth.clock_skew_ppm) < 5  # measured: SD 0.9 ppm
    assert abs(float(r.clock.to_host(lm.duration_s)) - float(truth.host_time(lm.duration_s))) < 1e-3
    assert abs(r.clock_offset_s - truth.clock_offset_s) < 1e-3
    assert r.clock.residual_s < 0.1e-3  # sub-sample edges (whole samples: 0.14 ms RMS)
    assert r.clock.duty == pytest.approx(duty, abs=2e-3)
    assert r.edges.high_v == pytest.approx(5.0 * gain, abs=0.01) and abs(r.edges.low_v) < 0.01
    # every rising edge the SPECT saw, each mapped back to the host time it was sent
    assert r.edges.rising.size == truth.rising_edges_recorded
    sent = wave.rising[(wave.rising > truth.acquisition_start_host)][: r.edges.rising.size]
    assert np.max(np.abs(r.clock.to_host(r.edges.rising) - sent)) < 0.5e-3
    assert r.clock.max_residual_s < 0.5e-3 and r.problems == []


def test_a_20_minute_scan_needs_the_skew(tmp_path):
    lm, truth, wave, _ = simulate(
        tmp_path, duration=1200.0, rate=100.0, clock_skew_ppm=45.0, seed=5, gate_rate_hz=1000.0
    )
    r = analyze_gating(lm, period_s=1.0, fire_host=wave.start_pulse)
    assert abs(r.start_delay_s - truth.start_delay_s) < 1e-3
    assert r.clock.skew_ppm == pytest.approx(45.0, abs=0.5)
    t_end = lm.duration_s
    err = float(r.clock.to_host(t_end)) - float(truth.host_time(t_end))
    assert abs(err) < 1e-3
    # reading list-mode seconds as host seconds would be 54 ms off by the end
    naive = wave.start_pulse + t_end - r.clock.t_wave
    assert abs(naive - float(truth.host_time(t_end))) > 0.05
    assert len(r.dead) == len(truth.dead) == 54


def test_a_start_delay_longer_than_a_period_is_known_modulo_the_period(tmp_path):
    lm, truth, wave, _ = simulate(tmp_path, period=0.25, duration=20.0, start_delay_s=0.3, seed=6)
    r = analyze_gating(lm, period_s=0.25, fire_host=wave.start_pulse)
    assert r.start_delay_s == pytest.approx(0.3 - 0.25, abs=1e-3)  # the default assumption
    r2 = analyze_gating(lm, period_s=0.25, fire_host=wave.start_pulse, edges_before_start=2)
    assert r2.start_delay_s == pytest.approx(0.3, abs=1e-3)
    assert r2.clock_offset_s == pytest.approx(truth.clock_offset_s, abs=1e-3)


def test_a_wave_started_after_the_acquisition_gives_a_negative_delay(tmp_path):
    scene = Scene.reference(seed=0, start_epoch=T0)
    wave = square_wave(T0 + 3.0, 1.0, 0.5, 20)
    wave.start_pulse = T0  # the SPECT was started first
    truth = write_sim_listmode(
        tmp_path / "late.vtslm", scene, [], wave, 15.0, SimSpectSettings(background_cps=500.0), seed=3
    )
    lm = read_listmode(tmp_path / "late.vtslm")
    r = analyze_gating(lm, period_s=1.0, fire_host=T0 + 3.0)
    assert r.clock.first_index == 0 and "started" in r.problems[0]
    assert r.start_delay_s == pytest.approx(truth.start_delay_from_wave_s, abs=1e-3)
    assert r.start_delay_s < -2.5
    assert r.clock_offset_s == pytest.approx(truth.clock_offset_s, abs=1e-3)


def test_without_the_period_or_the_host_time_the_result_says_what_is_missing(tmp_path):
    lm, truth, wave, _ = simulate(tmp_path, duration=20.0, clock_skew_ppm=30.0, seed=7)
    r = analyze_gating(lm)
    assert abs(r.start_delay_s - truth.start_delay_s) < 1e-3  # 30 ppm of 1 s: 30 us
    assert r.clock.skew == 0.0 and r.clock_offset_s is None
    assert len(r.problems) == 2 and "skew is not measured" in r.problems[0]
    with pytest.raises(ValueError, match="fire_host"):
        r.clock.to_host(1.0)
    summary = json.loads(json.dumps(r.to_json(), allow_nan=False))  # strict JSON
    assert summary["start_delay_s"] == pytest.approx(r.start_delay_s)
    assert summary["period_s"] is None and summary["clock_offset_s"] is None


# ----------------------------------------------------------------------------- edges


def test_noise_makes_no_extra_edges(tmp_path):
    lm, truth, wave, _ = simulate(tmp_path, duration=20.0, gate_noise_v=0.4, seed=8)
    e = find_gate_edges(lm)
    assert e.rising.size == truth.rising_edges_recorded
    assert np.all(np.diff(e.rising) == pytest.approx(1.0, abs=5e-3))
    assert e.noise_v == pytest.approx(0.4, rel=0.1)
    r = analyze_gating(lm, period_s=1.0, fire_host=wave.start_pulse)
    assert abs(r.start_delay_s - truth.start_delay_s) < 1e-3


def test_no_square_wave_is_one_clear_error(tmp_path):
    scene = Scene.reference(seed=0, start_epoch=T0)
    wave = square_wave(T0 + 100.0, 1.0, 0.5, 3)  # starts after the acquisition
    wave.start_pulse = T0
    write_sim_listmode(tmp_path / "flat.vtslm", scene, [], wave, 5.0, SimSpectSettings(background_cps=100.0))
    lm = read_listmode(tmp_path / "flat.vtslm")
    with pytest.raises(DataError, match="no square wave in the gating signal") as e:
        analyze_gating(lm, period_s=1.0)
    assert str(e.value).startswith(str(tmp_path / "flat.vtslm")) and "\n" not in str(e.value)
    with pytest.raises(DataError, match="at least 2"):
        fit_spect_clock([1.0], where="x")
    with pytest.raises(DataError, match="not one steady square wave"):
        fit_spect_clock([1.0, 2.0, 3.0, 3.4, 5.0], period_s=1.0, where="x")


# ------------------------------------------------------------------------ dead time, COM


def test_dead_time_intervals_recovered_from_the_events(tmp_path):
    lm, truth, _, _ = simulate(tmp_path, duration=70.0, rate=3000.0, seed=9, record_dead_time=False)
    assert lm.dead is None  # the file does not say
    found = dead_time_from_events(lm)
    assert found.shape == (3, 2)
    assert np.max(np.abs(found - np.array(truth.dead))) < 10e-3  # measured: about 1 ms
    r = analyze_gating(lm, period_s=1.0)
    assert np.array_equal(r.dead, found) and r.dead_recorded is None


MOVES = ([6.3, 14.8, 27.4, 35.1, 50.6], [12.0, -25.0, 18.0, -10.0, 30.0])


def crossing(t, z, move, half=0.6):
    """When a trace crosses half-way between its levels before and after a move."""
    before = np.nanmedian(z[(t > move.t_start - 1.0) & (t < move.t_start - 0.1)])
    after = np.nanmedian(z[(t > move.t_end + 0.1) & (t < move.t_end + 1.0)])
    mid = 0.5 * (before + after)
    sel = np.flatnonzero((t > move.t_mid - half) & (t < move.t_mid + half))
    d = (z[sel] - mid) * np.sign(after - before)
    k = np.flatnonzero((d[:-1] < 0) & (d[1:] >= 0))
    assert k.size == 1, (move, d)
    i, j = sel[k[0]], sel[k[0]] + 1
    return t[i] + (mid - z[i]) / (z[j] - z[i]) * (t[j] - t[i]), before, after


def test_motion_in_the_axial_centre_of_mass_on_host_time(tmp_path):
    lm, truth, wave, src = simulate(tmp_path, moves=MOVES, rate=3000.0, seed=10)
    r = analyze_gating(lm, period_s=1.0, fire_host=wave.start_pulse)
    t, z = axial_centre_of_mass(lm, bin_s=0.1)
    assert t.size == 600 and np.allclose(np.diff(t), 0.1)
    host = r.clock.to_host(t)
    errors = []
    for m in src.moves:
        when, before, after = crossing(host, z, m)
        errors.append(when - m.t_mid)
        assert before == pytest.approx(m.z_from, abs=0.5)
        assert after == pytest.approx(m.z_to, abs=0.5)
    assert np.max(np.abs(errors)) < 20e-3  # measured: a few ms
    # nan while the heads rotate, numbers everywhere else
    dead = np.array(truth.dead)
    in_dead = np.zeros(t.size, bool)
    for d0, d1 in dead:
        in_dead |= (t >= d0) & (t < d1)
    assert np.all(np.isnan(z[in_dead])) and not np.any(np.isnan(z[~in_dead]))


# ----------------------------------------------------------------- another reader, same analysis


class ToyReader:
    """A 'vendor' format: a text header line and the gate as level transitions."""

    name = "toy"
    extensions = (".toylm",)

    @staticmethod
    def sniff(head: bytes) -> bool:
        return head.startswith(b"TOYLM")

    @staticmethod
    def read(path: Path) -> ListMode:
        lines = path.read_text().splitlines()
        start, duration = map(float, lines[0].split()[1:3])
        trans = np.array([[float(x) for x in ln.split()] for ln in lines[1:]])
        empty = np.empty(0)
        return ListMode(
            start_time=start,
            duration_s=duration,
            t=np.sort(np.random.default_rng(0).uniform(0, duration, 1000)),
            z=np.zeros(1000, np.float32),
            u=np.zeros(1000, np.float32),
            head=np.zeros(1000, np.uint8),
            timing_marks=empty,
            frame_starts=empty,
            frame_angles=empty,
            gate_t=trans[:, 0],
            gate_v=trans[:, 1].astype(np.float32),
            gate_kind=GATE_TRANSITIONS,
            source=path,
            format="toy",
        )


def test_a_vendor_reader_is_added_and_the_analysis_does_not_change(tmp_path, monkeypatch):
    monkeypatch.setattr(base._REGISTRY, "_readers", dict(base._REGISTRY._readers))
    register_reader(ToyReader())
    delay = 0.23
    lines = [f"TOYLM {T0 + 50:.3f} 10.0", "0.0 5.0"]  # high at the start (delay < duty*P)
    for k in range(10):  # falling, then rising, edges
        lines += [f"{k + 0.5 - delay:.6f} 0.0", f"{k + 1 - delay:.6f} 5.0"]
    (tmp_path / "scan.toylm").write_text("\n".join(lines) + "\n")
    lm = read_listmode(tmp_path / "scan.toylm")
    assert lm.format == "toy"
    r = analyze_gating(lm, period_s=1.0, fire_host=T0)
    assert r.start_delay_s == pytest.approx(delay, abs=1e-9)
    assert r.clock.duty == pytest.approx(0.5, abs=1e-9)


# ------------------------------------------------------------------ following real triggers


def test_firmware_in_the_loop_start_delay(tmp_path):
    """The real driver fires *TRG on the firmware in the emulator (real time); the simulated
    SPECT follows the pins the emulator logged; the analysis, given only the list-mode and
    the driver's trigger.csv, recovers the start delay and the clock."""
    log_path = tmp_path / "session" / "trigger.csv"
    with SimTriggerBox() as sim:
        box = TriggerBox(sim.port, log=TriggerLog(log_path), timeout=2.0)
        try:
            box.configure(2, 0.5)
            box.clock_mapping(samples=10, over_s=0.3)
            sent = time.time()
            box.fire()
            sim.wait_cycles(int(3.6 * F_CPU))  # the wave ends at 4.0 s, the SPECT by 3.4 s
            box.stop()
        finally:
            box.close()
        emitted = edges_from_trigger_box(sim)
        with pytest.raises(ValueError, match="let it run longer"):  # beyond the emulator's now
            SimListModeSpect(Scene.reference(seed=0, start_epoch=sent), []).follow_trigger_box(
                sim, tmp_path / "long.vtslm", 30.0
            )
        scene = Scene.reference(seed=0, start_epoch=sent)
        src = add_source_marker(scene, [sent + 1.2, sent + 2.2], [15.0, -20.0])
        truth = SimListModeSpect(scene, [src], seed=5).follow_trigger_box(sim, tmp_path / "scan.vtslm", 3.0)
    # the emulator's pins: *TRG closed CH2 and started OC1A together, after the command went
    assert abs(emitted.start_pulse - emitted.rising[0]) < 2e-6
    # (the pins' host times are the emulator's cycles mapped to host time, which on a busy
    # machine is off by up to a millisecond or two: an edge 0.16 ms "before" `sent` was seen)
    assert -2e-3 < emitted.rising[0] - sent < 0.05
    assert emitted.rising.size == 8 and np.allclose(np.diff(emitted.rising), 0.5, atol=1e-6)
    wave = wave_from_trigger_log(log_path)
    assert (wave.period_s, wave.duty, wave.n_rising, wave.start_pulse) == (0.5, 0.5, 8, True)
    assert wave.time_source == "device_clock_mapped" and "mapped from the device clock" in wave.how
    assert not wave.converted and 0 < wave.uncertainty_s < 3e-3  # from the neutral rows
    assert wave.drift_ppm is not None and wave.drift_se_ppm > 0  # from the driver's mapping
    assert abs(wave.start_host - emitted.rising[0]) < 3e-3  # driver vs emulator: 0.03-0.9 ms
    lm = read_listmode(tmp_path / "scan.vtslm")
    r = analyze_gating(lm, period_s=wave.period_s, fire_host=wave.start_host)
    assert abs(r.start_delay_s - truth.start_delay_s) < 10e-3  # measured: about 0.1 ms
    assert abs(r.clock_offset_s - truth.clock_offset_s) < 5e-3
    assert r.edges.rising.size == truth.rising_edges_recorded


def test_following_the_simulated_function_generator_through_its_log(tmp_path):
    log_path = tmp_path / "session" / "trigger.csv"
    fg = FunctionGenerator(SIM_RESOURCE, sim=True, log=TriggerLog(log_path))
    try:
        fg.configure(1.0, 0.3, high_v=2.5, low_v=0.0)
        before = time.time()
        fg.start()
    finally:
        fg.close()
    wave = wave_from_trigger_log(log_path)
    assert before <= wave.start_host <= time.time()
    assert (wave.period_s, wave.duty, wave.high_v, wave.low_v, wave.stop_host) == (1.0, 0.3, 2.5, 0.0, None)
    scene = Scene.reference(seed=3, start_epoch=before)
    src = add_source_marker(scene, [wave.start_host + 5.0], [20.0])
    truth = SimListModeSpect(scene, [src], seed=12).follow_trigger_log(
        log_path, tmp_path / "fg.vtslm", 20.0, until=wave.start_host + 30.0
    )
    assert truth.start_pulse_host is None and truth.wave_start_host == wave.start_host
    lm = read_listmode(tmp_path / "fg.vtslm")
    r = analyze_gating(lm, period_s=wave.period_s, fire_host=wave.start_host)
    assert abs(r.start_delay_s - truth.start_delay_s) < 1e-3
    assert abs(r.clock_offset_s - truth.clock_offset_s) < 1e-3
    assert r.edges.high_v == pytest.approx(2.5, abs=0.01) and r.clock.duty == pytest.approx(0.3, abs=2e-3)


def test_a_trigger_box_log_gives_the_wave_and_the_box_drift(tmp_path):
    rows = [
        (0.0, "cmd", "*IDN?"),
        (0.001, "reply", "VTS,TRIGGERBOX,0000,1.0.0"),
        (0.01, "cmd", "FREQ 2"),
        (0.011, "reply", "OK"),
        (0.02, "cmd", "DUTY 0.25"),
        (0.021, "reply", "OK"),
        (0.03, "cmd", "FREQ?"),
        (0.031, "reply", "2"),
        (
            0.5,
            "event",
            "clock mapping: host = 1.0 + (device_us - 5) * 1e-6 * (1 + 12.0e-6); "
            "drift +12.000 ± 0.500 ppm, residual 40.0 us, uncertainty 90.0 us",
        ),
        (1.0, "cmd", "*TRG"),
        (1.002, "reply", "OK"),
        (1.003, "cmd", "EDGES?"),
        (1.004, "reply", "1,100,100"),
        (1.0006, "edge", "first rising edge (1 of 1); host time mapped from the box clock"),
        (3.2, "cmd", "OUTP OFF"),
        (3.201, "reply", "OK"),
        (3.202, "cmd", "EDGES?"),
        (3.203, "reply", "4,100,1500100"),
    ]  # read before the last period ended
    p = tmp_path / "trigger.csv"
    p.write_text(
        "host_time,device_time_us,device,kind,text\n"
        + "".join(f'{T0 + h:.6f},,triggerbox,{k},"{text}"\n' for h, k, text in rows)
    )
    w = wave_from_trigger_log(p)  # written before the neutral rows: converted on read
    assert w.converted and w.time_source == "device_clock_mapped"
    assert w.start_host == pytest.approx(T0 + 1.0006, abs=1e-6) and "mapped" in w.how
    assert (w.period_s, w.duty, w.start_pulse, w.high_v, w.low_v) == (0.5, 0.25, True, 5.0, 0.0)
    assert w.n_rising == 5  # OFF at 2.2 s into the wave: it ends at 2.5 s
    assert w.stop_host == pytest.approx(T0 + 1.0006 + 2.5, abs=1e-6)
    assert (w.drift_ppm, w.drift_se_ppm) == (12.0, 0.5)
    assert w.host_period_s == pytest.approx(0.5 * (1 + 12e-6), rel=1e-12)
    rising, falling = square_wave_edges(w)
    assert np.allclose(rising - w.start_host, [0, 0.5, 1.0, 1.5, 2.0])
    assert np.allclose(falling - rising, 0.125)
    # a mapping too short to know the drift is not applied
    p.write_text(p.read_text().replace("± 0.500 ppm", "± 31.000 ppm"))
    assert wave_from_trigger_log(p).host_period_s == 0.5


def test_trigger_log_errors(tmp_path):
    with pytest.raises(DataError, match="no such file"):
        wave_from_trigger_log(tmp_path / "none.csv")
    p = tmp_path / "trigger.csv"
    p.write_text("host_time,device_time_us,device,kind,text\n1.0,,fgen,cmd,FREQ 2\n")
    with pytest.raises(DataError, match="no square wave was started"):
        wave_from_trigger_log(p)
    p.write_text("a,b\n1,2\n")
    with pytest.raises(DataError, match="not a trigger log"):
        wave_from_trigger_log(p)
