"""Commissioning's warm-up (issue 24 §3): the simulated cameras' pictures drift after they start
(sim_devices/warmup.py) and the step measures that they have settled (procedures/warmup.py): the
wall markers' mean position sampled, the rate fitted in px/min, judged by its window, the uptime
still counting. A freshly started camera is "not settled, about N min" with --no-wait; an old one
is settled; waiting, the step says each sample and stops waiting only once the picture has truly
slowed below the limit. Real simulated cameras over HTTP; a virtual clock so that minutes of
warming take a second (or nothing, when the step's own sleep moves it)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from inprocess_cli import vts
from vts_hw.config import dump_rig, parse_rig
from vts_hw.errors import ConfigError
from vts_hw.procedures import commission_steps as steps
from vts_hw.procedures.commission import Context, Inputs
from vts_hw.sim_devices.clock import VirtualClock
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore
from vts_hw.store.commission import load_state

LIMIT = 0.05  # px/min, the default window


def _truth_shift(rig, cam: str, t: float) -> np.ndarray:
    return np.array([(u, v) for _, u, v in rig.scene.truth(cam, t)])


def test_a_declared_warmup_drift_moves_a_fresh_camera_and_decays_and_changes_nothing_else():
    clock = VirtualClock(rate=1e-9)
    plain = SimRig(n_cameras=2, seed=3, clock=clock)
    warm = SimRig(n_cameras=2, seed=3, clock=clock, warmup_drift=True)
    t = clock.now()
    for cam in ("cam1", "cam2"):  # started a day ago: settled, as a rig without a warm-up drift
        assert np.allclose(_truth_shift(plain, cam, t), _truth_shift(warm, cam, t), atol=1e-9)
    warm.servers["cam1"].reboot()
    d = warm.scene.warmups["cam1"]
    assert 2.0 <= d.amplitude_px <= 4.0 and 8 * 60 <= d.tau_s <= 15 * 60
    base = _truth_shift(plain, "cam1", t)
    now = _truth_shift(warm, "cam1", t) - base
    later = _truth_shift(warm, "cam1", t + d.tau_s) - base
    # every wall marker moved by the same offset, amplitude_px along its direction, then 1/e of it
    assert np.allclose(now, now.mean(axis=0), atol=0.02) and math.isclose(
        np.hypot(*now.mean(axis=0)), d.amplitude_px, rel_tol=0.02
    )
    assert math.isclose(np.hypot(*later.mean(axis=0)), d.amplitude_px / math.e, rel_tol=0.03)
    assert np.allclose(_truth_shift(plain, "cam2", t), _truth_shift(warm, "cam2", t), atol=1e-9)
    other = SimRig(n_cameras=2, seed=4, clock=clock, warmup_drift=True).scene.warmups["cam1"]
    assert other.amplitude_px != d.amplitude_px  # seeded per rig and camera
    with pytest.raises(ValueError, match="cam9: the scene has no such camera"):
        SimRig(n_cameras=2, seed=3, clock=clock, warmup_drift={"cam9": {}})


def _config(rig, tmp_path, warmup_min=None, **settings):
    data = rig.config(rig_name="room3", results_url=f"sqlite:///{tmp_path / 'r.sqlite'}").model_dump(
        mode="json", exclude_none=True, exclude_defaults=True
    )
    data["warmup"] = settings
    if warmup_min is not None:
        for c in data["cameras"]:
            c["warmup_min"] = warmup_min
    return parse_rig(data, "test rig")


def test_no_wait_stops_at_once_for_a_young_camera_and_measures_one_window_for_an_old_one(tmp_path, capsys):
    """Through `vts commission --no-wait`, the simulated world 60 times faster than real time:
    half a second between samples is half a simulated minute. A camera started less than its
    warmup_min ago cannot pass: no sample is taken, the step stops at once with the rest of its
    warm-up time as the least wait. With no warm-up time left, one window is measured (a rate
    takes that long) and the step stops with the wait its fitted rate gives."""
    rig = SimRig(
        n_cameras=2,
        seed=5,
        clock=VirtualClock(rate=60.0),
        warmup_drift={"cam1": {"amplitude_px": 3.0, "tau_min": 10.0}},
    ).start()
    try:
        with rig.env():
            y = tmp_path / "rig.yaml"
            y.write_text(dump_rig(_config(rig, tmp_path, interval_s=0.5, samples=4, frames=2)))
            rig.servers["cam1"].reboot()
            code, out, err = vts(
                capsys, "commission", "--config", y, "-o", tmp_path / "c", "--from", "warmup", "--no-wait"
            )
            assert code == 10, err
            assert "sample 1" not in err and "watching the wall markers" not in err  # no window waited for
            young = re.search(
                r"commissioning stopped at warm-up: cam1 started (\d+) min ago, less than its 30 min "
                r"warm-up time: wait at least (\d+) min \(until \d\d:\d\d\), its picture's rate is "
                r"measured then; then `vts commission --resume`",
                out,
            )
            assert young and int(young.group(1)) + int(young.group(2)) in (29, 30, 31), out
            assert "cam2" not in out  # started a day ago
            with ResultsStore(f"sqlite:///{tmp_path / 'r.sqlite'}") as store:
                s = load_state(store, "room3").steps["warmup"]
                assert not s.passed and s.status == "TOLERANCE"
                ms = {(m.subject, m.metric): m for m in store.measurements(run_id=s.run_id)}
                assert ms[("cam1", "warming_up")].value == 1.0 and ms[("cam2", "warming_up")].value == 0.0
                assert ms[("cam1", "warmup_rate_px_min")].value is None  # not measured, said so

            y.write_text(dump_rig(_config(rig, tmp_path, warmup_min=0, interval_s=0.5, samples=4, frames=2)))
            code, out, err = vts(
                capsys, "commission", "--config", y, "-o", tmp_path / "c", "--from", "warmup", "--no-wait"
            )
    finally:
        rig.stop()
    assert code == 10, err
    assert "sample 1 of 4" in err and "sample 4 of 4: rate now cam1 0." in err and "sample 5" not in err
    m = re.search(
        r"commissioning stopped at warm-up: cam1 not settled \((.*?)\): (wait (?:about|at least) \d+ min "
        r"\(until \d\d:\d\d\)|wait and run it again); then `vts commission --resume`",
        out,
    )
    assert m, out
    assert "the rate" in m.group(1)
    assert re.search(
        r"cam1: 0\.\d\d\d ± 0\.\d+ px/min over [\d.]+ min \(OK ≤ 0\.05 px/min\), running \d+ min "
        r"\(warm-up 0 min\): NOT settled",
        err,
    ), err
    assert re.search(r"cam2: 0\.0[0-2]\d ± .* running 14\d\d min \(warm-up 0 min\): settled", err), err
    with ResultsStore(f"sqlite:///{tmp_path / 'r.sqlite'}") as store:
        s = load_state(store, "room3").steps["warmup"]
        assert not s.passed and s.status == "TOLERANCE"
        ms = {(m.subject, m.metric): m for m in store.measurements(run_id=s.run_id)}
        windows = store.windows(m.tolerance_id for m in ms.values())
        for cam, state in (("cam1", "TOLERANCE"), ("cam2", "OK")):
            rate = ms[(cam, "warmup_rate_px_min")]
            assert str(rate.status) == state and rate.unit == "px/min"
            assert windows[rate.tolerance_id].describe() == "OK ≤ 0.05 px/min"  # the window, stored with it


@pytest.fixture(scope="module")
def frozen():
    """Simulated time that moves only when the step sleeps (a minute between samples costs nothing)."""
    clock = VirtualClock(rate=1e-9)
    rig = SimRig(
        n_cameras=2, seed=6, clock=clock, warmup_drift={"cam1": {"amplitude_px": 3.0, "tau_min": 10.0}, "cam2": {}}
    ).start()
    try:
        with rig.env():
            yield rig, clock
    finally:
        rig.stop()


def _run(rig, clock, tmp_path, wait, **kw):
    said: list[str] = []
    ctx = Context(
        _config(rig, tmp_path, **kw),
        Inputs(out=tmp_path / "c", wait=wait),
        say=said.append,
        clock=clock.now,
        sleep=clock.advance,
    )
    return steps.warmup(ctx), said


def test_the_wait_comes_from_the_fitted_decay_and_an_old_camera_is_settled(frozen, tmp_path):
    rig, clock = frozen
    rig.servers["cam1"].reboot()
    out, said = _run(rig, clock, tmp_path, False, warmup_min=0, interval_s=60, samples=6, frames=2)
    truth = rig.scene.warmups["cam1"]
    age_end = clock.now() - rig.servers["cam1"].booted_at
    true_wait = (truth.settled_after_s(LIMIT) - age_end) / 60  # 17.9 - 5 = 12.9 min
    assert not out.passed and out.state == "TOLERANCE"
    m = re.search(
        r"cam1 not settled \(the rate slowing with a time constant of (\d+) min: (\d+) min to 0.05 "
        r"px/min\): wait about (\d+) min",
        out.advice,
    )
    assert m, out.advice
    assert 7 <= int(m.group(1)) <= 14  # tau 10 min
    assert abs(int(m.group(3)) - true_wait) <= 0.3 * true_wait, (m.group(3), true_wait)
    assert "cam2" not in out.advice  # declared a warm-up, but started a day ago
    data = out.result.data["warmup"]
    assert data["cam2"]["rate_px_min"] < 0.01 and len(data["cam1"]["samples_taken"]) == 6


def test_waiting_says_each_sample_and_stops_once_the_picture_has_slowed(frozen, tmp_path):
    rig, clock = frozen
    rig.servers["cam1"].reboot()
    out, said = _run(rig, clock, tmp_path, True, warmup_min=3, interval_s=60, samples=4, frames=1)
    # passed; TOLERANCE for the clocks: 4 readings of 1 ms cannot tell their rates' change (warmup_clock.py)
    assert out.passed and out.state == "TOLERANCE", said
    assert "cam1: clock's change not known: " in out.result.results(), out.result.results()
    assert said[1:3] == ["  sample 1 of 4", "  sample 2 of 4"] and said[3].startswith("  sample 3 of 4: rate now cam1 ")
    waits = [s for s in said if s.startswith("  not settled: cam1 (")]
    assert len(waits) >= 5 and all(s.endswith("; waiting") for s in waits)
    assert re.search(r"sample \d+ \(the last 4\): rate now cam1 0\.0[0-4]\d px/min", said[-1]), said[-1]
    truth = rig.scene.warmups["cam1"]
    age = clock.now() - rig.servers["cam1"].booted_at
    assert truth.rate_px_min(age) < LIMIT  # never settled while the picture still moves faster
    assert age <= truth.settled_after_s(LIMIT) + 5 * 60  # ... and waited no more than a window longer
    assert "cam1: 0.0" in out.result.results() and "settled" in out.result.results()


def test_a_camera_without_wall_markers_is_not_known_and_never_waited_for(frozen, tmp_path):
    rig, clock = frozen
    rig.sources["cam2"].set_optics(yaw_deg=40.0)  # the wall out of its picture
    try:
        t0 = clock.now()
        out, said = _run(rig, clock, tmp_path, True, warmup_min=0, interval_s=60, samples=3, frames=1)
    finally:
        rig.sources["cam2"].set_optics(yaw_deg=0.0)
    assert not out.passed and out.state == "ACTION"  # a rate not measured is never settled
    assert clock.now() - t0 < 3 * 60  # one window, no waiting: waiting would not help
    assert (
        "cam2: no wall markers seen with the LED on: the rate is not known (check its LED ring and aim)" in out.advice
    )
    assert out.result.data["warmup"]["cam2"]["rate_px_min"] is None


@pytest.mark.parametrize(
    "section, says",
    [
        ("warmup: {samples: 2}", "warmup.samples input should be greater than or equal to 3 (got 2)"),
        ("warmup: {interval_s: 0}", "warmup.interval_s input should be greater than 0 (got 0)"),
        ("warmup: {every: 5}", "warmup.every is not a known key"),
        (
            "tolerances: {warmup_rate_px_min: {tolerance_high: 0.1, action_high: 0.05}}",
            "tolerances.warmup_rate_px_min expected action_low <= tolerance_low <= tolerance_high <= action_high",
        ),
    ],
)
def test_a_bad_warmup_setting_or_limit_is_one_sentence_naming_its_key(tmp_path, capsys, section, says):
    y = tmp_path / "rig.yaml"
    y.write_text(f"rig: r\ncameras: [{{name: cam1, host: 127.0.0.1}}]\n{section}\n")
    code, out, err = vts(capsys, "commission", "--config", y, "--no-wait")
    assert code == 2 and err.strip() == f"vts: {y}: {says}", err


@pytest.mark.parametrize("metric", ["warmup_rate_px_min", "warmup_clock_change_ppm_min"])
def test_a_warmup_window_with_no_upper_limit_is_refused_naming_its_key_before_a_camera_is_opened(tmp_path, metric):
    """A warm-up window judges how fast a picture or a clock still changes: with neither
    tolerance_high nor action_high it has nothing to judge against (it passed None on, a
    TypeError later, or a pass when every camera settled at once): one sentence naming the key,
    before any camera is opened."""
    rig = parse_rig(
        {
            "rig": "r",
            "cameras": [{"name": "cam1", "host": "127.0.0.1"}],
            "tolerances": {metric: {"tolerance_low": 0.0}},
        },
        "rig.yaml",
    )
    opened = []
    ctx = Context(rig=rig, inputs=Inputs(out=tmp_path), camera=lambda cfg: opened.append(cfg) or pytest.fail("opened"))
    with pytest.raises(ConfigError, match=rf"tolerances: {metric} has no upper limit"):
        steps.warmup(ctx)
    assert opened == []
