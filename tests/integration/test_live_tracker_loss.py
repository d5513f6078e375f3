"""The live tracker on frames rendered ahead of time (a simulated patient, 2 cameras, breathing,
one body move; ``simulate_recording``), with frames lost as a busy host or a camera loses them:

* fed on a made-up clock (every frame's recorded receive time; the watch ticked every 0.1 s):
  bursts of both cameras and a camera switched off for 4.5 s give NOT TRACKING stretches that
  match the time truly without frames, with their reasons, one NOT TRACKING alert for the long
  one, and the move still alerted; no real time, so nothing depends on this machine's speed;
* recorded for real (the ``replay`` camera kind, the recorder, the tracker's own threads)
  under a CPU load the test starts, with the live worker held up for a while: every frame is
  recorded, the live path drops its own oldest frames and counts them, and what a view reads
  meanwhile comes at once, with its age, as NOT TRACKING -- never a stale figure as current.
"""

from __future__ import annotations

import itertools
import multiprocessing as mp
import os
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from vts_hw.cli.live_view import live_line
from vts_hw.recording.folder import read_index
from vts_hw.sim_devices.patient import BodyMove
from vts_hw.sim_devices.recording_sim import received_frames, simulate_recording
from vts_hw.sim_devices.sync_truth import true_cameras
from vts_hw.tracking.live.estimator import LiveSettings
from vts_hw.tracking.live.tracker import PARTS, LiveTracker
from vts_hw.tracking.live.watch import NOT_TRACKING, TRACKING, Episode
from vts_hw.vision.registration import RigidTransform

SEED = 1
START = 1_790_000_000.0 + 1000.0 * SEED + 5.0  # simulate_recording's default start
DURATION = 16.0
MOVE = BodyMove(START + 13.0, START + 13.6, (0.0, 1.5, 0.0), (2.0, 6.0, 2.0))
MOTION = SimpleNamespace(alert_mm=3.0, alert_deg=2.0, alert_after_s=1.0, blind_alert_s=3.0)
MONO0 = 10_000.0  # the made-up monotonic clock at the recording's first receipt


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    folder = tmp_path_factory.mktemp("live-loss") / "rec"
    sim = simulate_recording(folder, duration_s=DURATION, seed=SEED, patient={"moves": [MOVE]})
    frames, offsets = received_frames(folder, sim.cameras)
    return sim, folder, frames, offsets


def _tracker(sim, offsets, **kw) -> LiveTracker:
    return LiveTracker(
        true_cameras(sim.scene, START),
        MOTION,
        mapping=RigidTransform.identity(),
        clock_offsets=offsets,
        settings=LiveSettings(reference_s=4.0),
        **kw,
    )


def _feed(tracker, frames, lost, after: float = -1.0, until: float | None = None):
    """Every frame (received after ``after`` up to ``until``, s from the first) that is not
    ``lost(camera, s from the first)`` put on the tap at its recorded receipt; the worker and
    the watch run at each frame and every 0.1 s in between."""
    t_first = frames[0][0]
    tick = max(0.0, round(np.ceil(after * 10) / 10, 6))
    for host, name, frame in frames:
        rel = host - t_first
        if rel <= after:
            continue
        if until is not None and rel > until:
            break
        while tick <= rel:
            tracker.step(0.0, now=MONO0 + tick)
            tracker.tick(MONO0 + tick)
            tick = round(tick + 0.1, 6)
        if not lost(name, rel):
            tracker.tap.put(name, frame, arrival=MONO0 + rel)
            tracker.step(0.0, now=MONO0 + rel)
    return t_first


BURST = (6.0, 7.04)  # both cameras, s after the first frame
CAM2_OFF = (8.0, 12.5)  # camera 2 switched off


def _lost(name, rel):
    return BURST[0] <= rel < BURST[1] or (name == "cam2" and CAM2_OFF[0] <= rel < CAM2_OFF[1])


def test_not_tracking_stretches_are_the_time_without_frames_with_their_reasons(rendered):
    sim, _, frames, offsets = rendered
    events, alerts = [], []
    tr = _tracker(sim, offsets, on_event=events.append, on_alert=lambda a, est: alerts.append(a))
    t_first = _feed(tr, frames, _lost, until=10.0)
    mid = tr.snapshot(now=MONO0 + 10.0)  # camera 2 off for 2 s
    _feed(tr, frames, _lost, after=10.0)
    end = MONO0 + frames[-1][0] - t_first
    tr.tick(end)
    events += tr.watch.finish(end)

    assert tr.estimator.phase == "tracking" and tr.facts.learned < MONO0 + 6.0, tr.estimator.note
    eps = [e for e in events if isinstance(e, Episode)]
    assert len(eps) == 2, [(e.start - MONO0, e.end - MONO0, e.reasons) for e in eps]
    burst, off = eps
    # from the last frame set before the gap to the first after it: the time truly without a pose
    assert BURST[0] - 0.08 <= burst.start - MONO0 <= BURST[0] and BURST[1] <= burst.end - MONO0 <= BURST[1] + 0.08
    assert burst.reasons[0].startswith("camera lost: no frames from any camera") and not burst.alerted
    assert (
        CAM2_OFF[0] - 0.08 <= off.start - MONO0 <= CAM2_OFF[0] and CAM2_OFF[1] <= off.end - MONO0 <= CAM2_OFF[1] + 0.08
    )
    assert off.reasons[0].startswith("camera lost: cam2 (no frame for") and off.alerted
    (blind,) = tr.blind_alerts
    assert 3.0 < blind.raised - blind.start <= 3.1 and "cam2" in blind.reason
    tot = tr.watch.totals()
    unobserved = (BURST[1] - BURST[0]) + (CAM2_OFF[1] - CAM2_OFF[0])
    assert tot["not_tracking_s"] == pytest.approx(unobserved, abs=0.2)
    assert tot["reference_s"] == pytest.approx(tr.facts.learned - MONO0, abs=0.1)
    # the view during the blind stretch: NOT TRACKING with its reason, the last pose with its age
    assert mid.status == NOT_TRACKING and "cam2" in mid.reason and mid.age_s == pytest.approx(2.0, abs=0.1)
    line = live_line(mid)
    assert "NOT TRACKING 2.0 s: camera lost: cam2" in line and "motion since then NOT KNOWN" in line
    assert "still" not in line
    # and the move after it is alerted as without loss
    (a,) = alerts
    assert MOVE.t_start - 0.1 <= a.onset <= MOVE.t_start + 0.5 and a.time < MOVE.t_end + 1.2
    assert tr.snapshot(now=end).status == TRACKING


def test_each_set_latency_is_told_in_its_parts(rendered):
    """The latency the live path reports (a set's last frame at the tap to its markers in the
    estimate) is the sum of its parts (tracker.PARTS: waiting for the worker, decode and
    detection, the set waiting for its cameras, matching, the estimator's update, publishing),
    every one measured for every set; on a clock that moves 1 ms at each reading (no real time)."""
    sim, _, frames, offsets = rendered
    ticks = itertools.count()

    def clock():
        return MONO0 + 0.001 * next(ticks)

    tr = _tracker(sim, offsets, clock=clock)
    for host, name, frame in frames:
        if host - frames[0][0] > 7.0:
            break
        tr.tap.put(name, frame, arrival=clock())
        tr.step(0.0)
    assert tr.estimator.phase == "tracking" and tr.sets > 100, tr.estimator.note
    lat, parts = np.array([x[0] for x in tr.latency]), np.array(tr.parts)
    assert parts.shape == (tr.sets, len(PARTS)) and np.isfinite(parts).all() and (parts > 0).all()
    assert np.allclose(parts.sum(axis=1), lat, rtol=0, atol=1e-9)
    figures = tr.latency_parts(None)
    assert list(figures) == list(PARTS) and all(0 < p50 <= p95 for p50, p95 in figures.values())
    assert tr.stats(None)["latency_ms_p95"] == pytest.approx(np.percentile(lat, 95) * 1e3, abs=1e-3)


def test_the_breathing_figures_are_worked_out_after_a_sets_latency_never_inside_it(rendered, monkeypatch):
    """Once a second of trace the breathing figures are worked out again (a few ms): after the
    set's markers are in the published estimate and its latency taken, never inside the
    published snapshot (which is within the latency); the next snapshot shows them."""
    from vts_hw.tracking.live import breathing

    sim, _, frames, offsets = rendered
    ticks = itertools.count()

    def clock():
        return MONO0 + 0.001 * next(ticks)

    tr = _tracker(sim, offsets, clock=clock)
    est, inside, calls = tr.estimator, [False], []
    figures_of, snapshot = breathing.figures_of, est.snapshot

    def counted(t, v):
        calls.append((inside[0], len(tr.latency), tr.sets))
        return figures_of(t, v)

    def published(*a, **kw):
        inside[0] = True
        try:
            return snapshot(*a, **kw)
        finally:
            inside[0] = False

    monkeypatch.setattr(breathing, "figures_of", counted)
    monkeypatch.setattr(est, "snapshot", published)
    for host, name, frame in frames:
        if host - frames[0][0] > 12.0:
            break
        tr.tap.put(name, frame, arrival=clock())
        tr.step(0.0)
    assert est.phase == "tracking" and len(calls) >= 4, (est.note, calls)
    assert not any(during for during, _, _ in calls), calls  # never within a published snapshot
    assert all(n == sets for _, n, sets in calls), calls  # each after its set's latency was taken
    fig = est.traces[est.lead].figures(fresh=False)  # the last worked out ...
    assert fig is not None and len(calls) == len({sets for _, _, sets in calls})
    shown = est.snapshot(fresh=False).bands[0].rate_per_min  # ... is what a snapshot shows
    known = fig.status in ("measured", "bounded") and fig.rate_per_min is not None
    assert shown == pytest.approx(fig.rate_per_min) if known else np.isnan(shown)


def _spin(stop):
    while not stop.is_set():
        pass


def test_under_cpu_load_the_live_path_drops_its_own_oldest_frames_never_a_recorded_one(rendered, tmp_path):
    from vts_hw.config import parse_rig
    from vts_hw.drivers.registry import open_cameras
    from vts_hw.recording.capture import FrameRecorder

    sim, folder, frames, offsets = rendered
    ctx = mp.get_context("spawn")
    stop = ctx.Event()
    hogs = [ctx.Process(target=_spin, args=(stop,), daemon=True) for _ in range(2 * (os.cpu_count() or 2))]
    for h in hogs:
        h.start()
    rig = parse_rig(
        {
            "rig": "load",
            "cameras": [
                {"name": n, "kind": "replay", "options": {"folder": str(folder), "camera": n, "speed": 1.0}}
                for n in sim.cameras
            ],
        },
        "test rig.yaml",
    )
    cams = open_cameras(rig.cameras)
    tr = _tracker(sim, offsets)
    hold, held = threading.Event(), threading.Event()
    update = tr.estimator.update

    def held_update(t, pts, *more):  # the worker held up inside an estimate (as a busy host would)
        if hold.is_set():
            held.set()
            while hold.is_set():
                time.sleep(0.01)
        return update(t, pts, *more)

    tr.estimator.update = held_update
    seen: list = []
    done = threading.Event()

    def view():  # a display reading the tracker as often as it likes
        while not done.is_set():
            seen.append((held.is_set() and hold.is_set(), tr.snapshot()))
            time.sleep(0.02)

    viewer = threading.Thread(target=view, daemon=True)
    rec = FrameRecorder(cams, tmp_path / "again", seconds=None, on_frame=tr.on_frame)
    try:
        tr.start()
        rec.start()
        viewer.start()
        deadline = time.monotonic() + 120  # failure guards only: never a figure asserted on time
        while tr.estimator.phase != "tracking" and time.monotonic() < deadline:
            time.sleep(0.05)
        hold.set()
        # held until frames were dropped, the view read it often, and longer than late_s (a fast
        # machine drops ten frames sooner than late_s: the view must then still say TRACKING)
        held_from = None
        while time.monotonic() < deadline:
            if held.is_set() and held_from is None:
                held_from = time.monotonic()
            if (
                sum(tr.tap.dropped.values()) >= 10
                and sum(1 for h, s in seen if h) >= 10
                and held_from is not None
                and time.monotonic() - held_from > 3 * tr.late_s
            ):
                break
            time.sleep(0.05)
        hold.clear()
        sets_at_release = tr.sets
        rec.wait()  # until the replay ends
        manifest = rec.finish()
        done.set()
        viewer.join(10)
        tr.stop()
    finally:
        stop.set()
        for h in hogs:
            h.join(10)
        for c in cams:
            c.close()
    # every frame recorded, whatever the live path did
    for name in sim.cameras:
        assert manifest["cameras"][name]["frames"] == len(read_index(folder / f"{name}.index.csv"))
    st = tr.stats()
    for name in sim.cameras:
        assert st["tapped"][name] == manifest["cameras"][name]["frames"]
        assert st["processed"][name] + st["live_dropped"][name] + st["queued"][name] == st["tapped"][name]
    assert sum(st["live_dropped"].values()) >= 10 and rec.on_frame_errors == 0
    assert tr.sets > sets_at_release  # it went on after being held up
    # what the view read while the worker was held: at once, ever older, never TRACKING on old figures
    during = [s for h, s in seen if h]
    assert len(during) >= 10
    ages = [s.age_s for s in during]
    assert all(b >= a for a, b in zip(ages, ages[1:]))
    assert during[-1].status == NOT_TRACKING and during[-1].reason.startswith("frames too late")
    for _, s in seen:
        assert s.status != TRACKING or s.age_s <= tr.late_s + tr.publish_s
