"""The live estimator on synthetic marker positions: the simulated patient's true markers
(``Patient.markers_at``, SPECT frame) with noise, plus wall markers that never move."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from vts_hw.sim_devices.patient import BodyMotion, BodyMove, Breathing, Patient
from vts_hw.tracking.live.breathing import breathing_rate
from vts_hw.tracking.live.estimator import LiveEstimator, LiveSettings

MOTION = SimpleNamespace(alert_mm=3.0, alert_deg=2.0, alert_after_s=1.0)
WALL = np.array([[-400.0, 900.0, 4000.0], [300.0, 1100.0, 4100.0], [0.0, 1500.0, 4050.0]])


def _patient(duration, moves=(), seed=1):
    return Patient(Breathing(0.0, duration, seed), BodyMotion(list(moves)), seed)


def _run(patient, duration, rate_hz=25.0, noise_mm=0.1, seed=0, settings=None):
    rng = np.random.default_rng(seed)
    est = LiveEstimator(MOTION, settings or LiveSettings(reference_s=10.0))
    alerts, errors = [], []
    for t in np.arange(0.0, duration, 1.0 / rate_hz):
        pts = np.array([m.center for m in patient.markers_at(float(t), np.zeros(3))])
        pts = np.vstack([pts, WALL]) + rng.normal(0, noise_mm, (len(pts) + len(WALL), 3))
        a = est.update(float(t), rng.permutation(pts))
        if a is not None:
            alerts.append(a)
        if est.phase == "tracking" and est.fit is not None:
            errors.append(np.abs(np.array(est.snapshot().six_dof) - patient.six_dof(float(t))))
    return est, alerts, np.array(errors)


@pytest.mark.timeout(600)  # 6000 estimates: minutes on a busy 2-core machine (a guard, not a figure)
def test_breathing_alone_never_alerts_and_the_pose_stays_put():
    """Ten minutes of breathing (deep breaths, pauses, a wandering baseline): no alert, and the
    body's 6-DOF stays within a fraction of the thresholds of the truth (which is still)."""
    p = _patient(600.0, seed=4)
    assert any(c.kind == "deep" for c in p.breathing.cycles)  # the hard cases are in
    est, alerts, err = _run(p, 600.0, rate_hz=10.0)
    assert est.phase == "tracking"
    assert alerts == []
    assert err[:, :3].max() < 0.25 * MOTION.alert_mm
    assert err[:, 3:].max() < 0.25 * MOTION.alert_deg
    snap = est.snapshot()
    assert snap.state == "still" and snap.alerts == 0


def test_bands_breathing_and_rate():
    """Two bands of four markers (the wall markers left out); each band's breathing follows
    the truth's b(t); the rate is that of the truth's cycles."""
    p = _patient(60.0, seed=2)
    est, _, _ = _run(p, 60.0)
    snap = est.snapshot()
    assert [b.markers for b in snap.bands] == [4, 4]
    assert all(b.seen == 4 for b in snap.bands)
    for _band, tr in zip(snap.bands, est.traces):
        t, v = tr.values()
        truth = p.breathing.value(t)
        assert np.corrcoef(v, truth)[0, 1] > 0.98
    cycles = [c for c in p.breathing.cycles if 30 <= c.t_start <= 60 and c.kind != "pause"]
    true_rate = 60.0 / np.mean([c.period_s for c in cycles])
    assert snap.bands[1].rate_per_min == pytest.approx(true_rate, rel=0.2)
    # the abdomen band (larger Z: the second) breathes more than the chest
    assert np.ptp(est.traces[1].values()[1]) > np.ptp(est.traces[0].values()[1])


def test_a_body_move_raises_one_alert_after_its_onset_and_the_pose_follows_the_truth():
    move = BodyMove(20.0, 20.8, (0.0, 1.0, 0.5), (5.0, 2.0, -3.0))
    p = _patient(40.0, [move], seed=3)
    est, alerts, err = _run(p, 40.0)
    assert len(alerts) == 1
    a = alerts[0]
    assert a.move_mm > MOTION.alert_mm
    assert a.time - a.onset > MOTION.alert_after_s
    assert abs(a.onset - move.t_start) <= 0.1  # the onset is the move's start (0088)
    assert a.time <= move.t_start + MOTION.alert_after_s + 0.1 + 0.04  # ... and the alert as the hold ends
    assert err[:, :3].max() < 1.0 and err[:, 3:].max() < 0.3  # the 6-DOF, breathing excluded
    final = np.array(est.snapshot().six_dof)
    assert np.allclose(final, p.six_dof(39.9), atol=[0.5, 0.5, 0.5, 0.15, 0.15, 0.15])


def test_a_short_twitch_does_not_alert():
    """A move that comes back within the alert time (out 0.3 s, back 0.3 s) never alerts."""
    out = BodyMove(20.0, 20.3, (0.0, 0.0, 0.0), (0.0, 6.0, 0.0))
    back = BodyMove(20.3, 20.6, (0.0, 0.0, 0.0), (0.0, -6.0, 0.0))
    est, alerts, _ = _run(_patient(30.0, [out, back]), 30.0)
    assert est.phase == "tracking" and alerts == []


def test_breathing_rate_of_a_known_signal():
    t = np.arange(0, 30, 0.04)
    assert breathing_rate(t, 3.0 * np.sin(2 * np.pi * t / 4.0)) == pytest.approx(15.0, rel=0.02)
    assert np.isnan(breathing_rate(t, 0.01 * np.sin(t)))


def test_the_live_view_prints_what_the_estimator_says():
    """The CLI's view: a rich table per band (sparkline of the trace, rate) and a plain line,
    both from one snapshot; before the reference, the phase and its progress."""
    from rich.console import Console

    from vts_hw.cli.live_view import live_line, live_table, sparkline

    p = _patient(30.0, seed=2)  # 20 s after the reference: the 3 breaths seen whole a rate needs
    est = LiveEstimator(MOTION, LiveSettings(reference_s=10.0))
    for t in np.arange(0.0, 5.0, 0.04):
        est.update(float(t), np.array([m.center for m in p.markers_at(float(t), np.zeros(3))]))
    assert "learning the reference: 5.0 of 10 s" in live_line(est.snapshot())
    est, _, _ = _run(p, 30.0)
    assert np.isfinite(est.snapshot().bands[1].rate_per_min)
    snap = est.snapshot({"sets": 500, "live_dropped": {"cam1": 2}, "latency_ms_p50": 1.5, "latency_ms_p95": 3.25})
    line = live_line(snap)
    assert f"band 2 4/4 markers {snap.bands[1].distance_mm:.1f} mm" in line
    assert f"{snap.bands[1].rate_per_min:.1f}/min" in line and "p95 3.2 ms" in line and "2 dropped" in line
    con = Console(record=True, width=160)
    con.print(live_table(snap))
    text = con.export_text()
    assert sparkline(snap.bands[0].trace) in text and "alerts 0" in text
    assert sparkline([0.0, 1.0, 2.0, 3.0]) == "▁▃▆█"


def test_a_move_during_the_reference_restarts_it_and_raises_no_alert():
    """The reference is the first *still* period: a 5 mm move 4 s into it restarts it, and
    the pose afterwards is measured from where the body settled (no alert for that move)."""
    move = BodyMove(4.0, 4.6, (0.0, 0.0, 0.0), (0.0, 5.0, 0.0))
    est, alerts, _ = _run(_patient(40.0, [move], seed=6), 40.0)
    assert est.phase == "tracking" and alerts == []
    assert abs(est.snapshot().six_dof[1]) < 0.5  # 0 from the settled pose, not 5 mm


def test_a_rate_only_bounded_is_shown_with_its_range_never_as_a_plain_figure():
    """The live rate is the offline figures of its window: when the breaths seen do not pin it
    to 0.5 /min it is bounded, and the view says between what (a plain number would claim more)."""
    from vts_hw.cli.live_view import live_line

    p = _patient(30.0, seed=2)
    est, _, _ = _run(p, 30.0)
    fig = est.traces[0].figures()
    snap = est.snapshot()
    b = snap.bands[0]
    if fig.status == "bounded":
        assert b.rate_range == tuple(fig.rate_range)
        assert f"/min ({b.rate_range[0]:.1f}-{b.rate_range[1]:.1f})" in live_line(snap)
    else:
        assert b.rate_range is None
    bounded = dataclasses.replace(
        snap, bands=tuple(dataclasses.replace(x, rate_range=(12.04, 16.31)) for x in snap.bands)
    )
    assert "/min (12.0-16.3)" in live_line(bounded)
