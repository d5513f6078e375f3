"""The breathing rate against the truth over many simulated patients (issue 20, decision 0059).

The simulator's breathing (`sim_devices.patient.Breathing`: 10 % breath-to-breath spread, deep
breaths, pauses) sampled at 25 frames/s with 0.03 mm noise, whole or with bursts of 0.7-1.3 s
lost as a busy machine lost them. Over a population, a rate said `measured` must be within
0.5 /min of the truth (the median of the true breaths lying whole in the scan) and a `bounded`
range must hold it, but for the few a 99 % range misses. Before 0059 the rate said `measured`
with no loss and was more than 0.5 /min off for 11 % of patients (the median of every landmark
period is not the median of the breaths); this test failed then. Decision 0089: one estimator
for the live trace and the recording, and each breath across a short gap measured from what is
seen on both sides of it.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim_devices.patient import Breathing
from vts_hw.motion.cycles import breathing_figures, find_breaths, signal_noise
from vts_hw.tracking.live.breathing import BreathingTrace

FPS = 25.0
PERIOD = 1.0 / FPS


def scan(seed: int, duration: float, loss: float, mean_period_s: float = 4.2):
    br = Breathing(0.0, duration + 5.0, seed=seed, mean_period_s=mean_period_s)
    t = np.arange(0.0, duration, PERIOD)
    rng = np.random.default_rng(seed)
    a = 8.0 * br.value(t) + rng.normal(0.0, 0.03, len(t))
    valid = np.ones(len(t), bool)
    gaps = []
    if loss > 0:
        mean_gap = 1.0 / loss
        x = 0.5 + rng.uniform(0.2, 1.0) * (mean_gap - 1.0)
        while True:
            length = rng.uniform(0.7, 1.3)
            if x + length > duration - 1.0:
                break
            valid &= ~((t >= x) & (t < x + length))
            gaps.append((x, x + length))
            x += length + (mean_gap - 1.0) * rng.uniform(0.6, 1.4)
    true = [c for c in br.cycles if c.t_start >= 0 and c.t_start + c.period_s <= t[-1] and c.kind != "pause"]
    return t, np.where(valid, a, np.nan), valid, float(np.median([60.0 / c.period_s for c in true])), br, gaps


def figures(t, a, valid, duration):
    b = find_breaths(t, a, valid, PERIOD)
    return b, breathing_figures(b, PERIOD, duration, signal_noise(a, valid))


def outside(f, truth) -> bool:
    if f.status == "measured":
        return abs(f.rate_per_min - truth) > 0.5
    if f.status == "bounded":
        return not (f.rate_range[0] <= truth <= f.rate_range[1])
    return f.rate_per_min is not None  # unknown carries no number


@pytest.mark.parametrize("loss", [0.0, 0.05, 0.2])
def test_over_sixty_patients_a_rate_is_within_its_claim(loss):
    statuses, missed = [], []
    for seed in range(60):
        t, a, valid, truth, _, _ = scan(seed, 60.0, loss)
        _, f = figures(t, a, valid, 60.0)
        statuses.append(f.status)
        if outside(f, truth):
            missed.append((seed, f.status, f.rate_per_min, f.rate_range, round(truth, 2)))
    assert len(missed) <= 3, missed  # a 99 % range, and the breaths' own landmarks
    if loss == 0.0:
        assert statuses.count("measured") >= 25, statuses  # with no loss most patients are measured
    if loss == 0.2:
        # each breath across a short gap measured from its landmarks on both sides (0089): most
        # patients have a rate (0059's rule: 44 of 60, none measured), some to within 0.5 /min (no
        # chain through a body move: a held-out scan with four moves read a wrong range: 0089)
        assert statuses.count("bounded") + statuses.count("measured") >= 48, statuses
        assert statuses.count("measured") >= 6, statuses


def test_a_breath_across_a_short_gap_is_one_breath_and_a_long_gap_is_never_spanned():
    t, a, valid, _, br, _ = scan(3, 60.0, 0.0)
    cyc = [c for c in br.cycles if 8.0 < c.t_start and c.t_start + c.period_s < 50.0 and c.kind == "normal"]
    c = cyc[2]
    # a 0.6 s gap over the middle of one breath's exhalation: its up-crossings are both seen
    short = valid & ~((t >= c.t_start + 0.55 * c.period_s) & (t < c.t_start + 0.55 * c.period_s + 0.6))
    b = find_breaths(t, np.where(short, a, np.nan), short, PERIOD)
    assert 0.0 < 0.6 < b.span_s
    ups = [(x, y) for x, y in b.periods if x < c.t_start + 0.55 * c.period_s < y]
    assert len(ups) == 1 and abs((ups[0][1] - ups[0][0]) - c.period_s) < 0.15 * c.period_s, (ups, c)
    # a gap longer than a whole breath: no period of any kind spans it
    x0 = c.t_start + 0.3 * c.period_s
    long = valid & ~((t >= x0) & (t < x0 + 1.2 * c.period_s))
    b = find_breaths(t, np.where(long, a, np.nan), long, PERIOD)
    assert not [p for p in b.periods if p[0] < x0 and p[1] > x0 + 1.2 * c.period_s], b.periods


def test_the_live_trace_rate_is_the_recordings_on_the_same_signal():
    """The live path's trace (host times a few ms off the frame grid, frame sets lost in bursts)
    and the offline analysis of the same samples on the recording's frame grid give one rate and
    one status: the same estimator (0089). Before, the live trace counted crossings of its median
    across the gaps: 16.01 /min here, the recording's rules 15.93."""
    t, a, valid, truth, _, _ = scan(5, 60.0, 0.2)
    offline = figures(t, a, valid, 60.0)[1]
    trace = BreathingTrace(window_s=120.0)
    jitter = np.random.default_rng(1).uniform(-0.004, 0.004, len(t))
    for k in np.flatnonzero(valid):
        trace.add(float(t[k] + jitter[k]), float(a[k]))
    assert abs(trace.rate_per_min() - offline.rate_per_min) < 0.02, (trace.rate_per_min(), offline)
    live = trace.figures()
    assert live.status == offline.status and offline.status in ("measured", "bounded"), (live, offline)
    assert live.rate_range == pytest.approx(offline.rate_range, abs=0.03)


def test_no_breath_is_chained_across_a_gap_through_a_body_move():
    """While the body moves the fitted signal takes up part of the move: a breath seen whole in
    one stretch stands, but no period or fitted breath crosses a gap through moving frames
    (0089: a held-out scan with four moves read a wrong range through them)."""
    t, a, valid, truth, _, gaps = scan(3, 60.0, 0.2)
    free = find_breaths(t, a, valid, PERIOD)
    assert free.periods and len(free.breaths) > len(free.cycles)  # breaths measured across gaps
    moving = np.zeros(len(t), bool)
    for g0, g1 in gaps:  # the body moving around every gap
        moving |= (t >= g0 - 0.5) & (t < g1 + 0.5)
    held = find_breaths(t, a, valid, PERIOD, moving=moving)
    assert [c.t_start for c in held.cycles] == [c.t_start for c in free.cycles]  # the whole ones stand
    assert not held.periods  # none across a gap
    assert all(any(abs(b[0] - c.t_start) < 0.5 for c in held.cycles) for b in held.breaths)
