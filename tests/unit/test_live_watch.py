"""Whether the patient is watched (vts_hw/tracking/live/watch.py): TRACKING, REFERENCE or NOT TRACKING with
its reason, stretches timed from the last instant observed to the first observed again, and a
NOT TRACKING alert once a stretch lasts longer than blind_alert_s. Driven with what the live
worker publishes (Facts) on a made-up clock: no thread, no waiting."""

from __future__ import annotations

import numpy as np
import pytest

from vts_hw.tracking.live.watch import NOT_TRACKING, REFERENCE, TRACKING, BlindAlert, Change, Episode, Facts, Watch

CAMS = ("cam1", "cam2")
LATE = 0.5


class Run:
    """A made-up live path: frame sets every ``period`` s, each observing the patient or not,
    cameras silent or not; the watch ticked at each."""

    def __init__(self, **kw):
        self.w = Watch(CAMS, late_s=LATE, blind_alert_s=3.0, reference_deadline_s=kw.pop("deadline", 20.0))
        self.f = Facts(phase="tracking", started=0.0, learned=0.0)
        self.last = {c: 0.0 for c in CAMS}
        self.events: list = []
        self.t = 0.0

    def go(self, until: float, *, cams=CAMS, sets=True, observed=True, why="", period=0.04, phase=None):
        """Until ``until``: frames from ``cams``; frame sets estimated (``sets``) that observed
        the patient (``observed``)."""
        f = self.f
        while self.t < until - 1e-9:
            self.t = round(self.t + period, 6)
            for c in cams:
                self.last[c] = self.t
            if sets:
                seen, resumed = f.seen, f.resumed
                if observed:
                    if seen is None or self.t - seen > LATE:
                        resumed = self.t
                    seen = self.t
                f = Facts(phase or f.phase, 0.0, seen, resumed, self.t, "" if observed else why, f.learned)
            self.f = f  # the watch ticks at each step
            self.events += self.w.tick(self.t, f, {c: self.t - v for c, v in self.last.items()})
        self.f = f
        return self

    def of(self, kind):
        return [e for e in self.events if isinstance(e, kind)]


def test_a_gap_of_both_cameras_is_one_stretch_from_the_last_pose_to_the_next_with_one_alert():
    r = Run().go(10.0).go(14.52, cams=(), sets=False).go(20.0)  # nothing from 10.04 to 14.52
    (ep,) = r.of(Episode)
    assert ep.start == pytest.approx(10.0) and ep.end == pytest.approx(14.56)  # the time without a pose
    assert ep.reasons[0].startswith("camera lost: no frames from any camera")
    (alert,) = r.of(BlindAlert)  # once, after 3 s
    assert alert.start == pytest.approx(10.0) and 13.0 < alert.raised <= 13.04
    assert "PATIENT NOT TRACKED for 3.0 s: camera lost" in alert.text()
    assert [c.status for c in r.of(Change)] == [TRACKING, NOT_TRACKING, TRACKING]
    r.w.finish(20.0)
    tot = r.w.totals()
    assert tot["not_tracking_s"] == pytest.approx(4.56) and tot["tracking_s"] == pytest.approx(20.0 - 4.56)
    assert tot["not_tracking_share"] == pytest.approx(4.56 / 20.0)


def test_gaps_shorter_than_late_s_stay_tracking_and_short_stretches_raise_no_alert():
    r = Run()
    for k in range(6):  # a frame set lost now and then, and 1 s bursts every 3 s (the host)
        r.go(3.0 * k + 1.0).go(3.0 * k + 1.4, sets=False).go(3.0 * k + 2.0).go(3.0 * k + 3.04, cams=(), sets=False)
    r.go(20.0)
    eps = r.of(Episode)
    assert len(eps) == 6 and r.of(BlindAlert) == []
    assert all(e.duration(0) == pytest.approx(1.08) for e in eps)  # 1.04 s without frames + a frame
    assert all(e.reasons[0].startswith("camera lost") for e in eps)


def test_one_camera_lost_names_it():
    r = Run().go(5.0).go(9.0, cams=("cam1",), sets=False)
    status, reason = r.w.classify(9.0, r.f, {"cam1": 0.0, "cam2": 4.0})
    assert status == NOT_TRACKING and reason == "camera lost: cam2 (no frame for 4.0 s)"
    (alert,) = r.of(BlindAlert)
    assert "cam2" in alert.reason


def test_frames_arriving_but_estimates_behind_are_frames_too_late():
    r = Run().go(5.0).go(8.0, sets=False)  # both cameras deliver, the live path is stuck
    status, reason = r.w.classify(8.0, r.f, {"cam1": 0.0, "cam2": 0.0})
    assert status == NOT_TRACKING and reason == "frames too late: the newest frame set estimated is 3.0 s old"
    assert r.w.episodes[-1].start == pytest.approx(5.0)


def test_frame_sets_without_the_patient_are_too_few_markers():
    r = Run().go(5.0).go(9.0, observed=False, why="2 of 8 markers seen").go(12.0)
    (ep,) = r.of(Episode)
    assert ep.reasons == ["too few markers: 2 of 8 markers seen"]
    assert ep.start == pytest.approx(5.0) and ep.end == pytest.approx(9.04)
    assert len(r.of(BlindAlert)) == 1


def test_a_reference_never_learned_is_not_tracking_after_the_deadline():
    r = Run(deadline=8.0)
    r.f = Facts(phase="reference", started=0.0)
    r.go(15.0, why="reference restarted: the body moved")
    assert [c.status for c in r.of(Change)] == [REFERENCE, NOT_TRACKING]
    (ep,) = r.w.episodes
    assert ep.start == pytest.approx(8.0) and ep.reasons[0].startswith("no reference: none learned in 8 s")
    (alert,) = r.of(BlindAlert)
    assert 11.0 < alert.raised <= 11.04
    # learned at last: TRACKING from the instant it was learned
    r.f = Facts("tracking", 0.0, r.f.seen, r.f.resumed, r.f.estimate, "", learned=15.0)
    r.go(17.0)
    assert r.w.status == TRACKING and r.w.episodes[0].end == pytest.approx(15.0)
    r.w.finish(17.0)
    tot = r.w.totals()
    assert tot["reference_s"] == pytest.approx(8.0) and tot["not_tracking_s"] == pytest.approx(7.0)


def test_the_status_is_never_tracking_on_old_figures():
    """Whatever the facts, TRACKING only within late_s of the last instant observed."""
    rng = np.random.default_rng(0)
    w = Watch(CAMS, late_s=LATE)
    for _ in range(2000):
        seen = rng.uniform(0, 10)
        f = Facts("tracking", 0.0, seen, seen, seen + rng.uniform(0, 1), "", 0.0)
        now = seen + rng.uniform(0, 3)
        status, reason = w.classify(now, f, {c: rng.uniform(0, 2) for c in CAMS})
        assert (status == TRACKING) == (now - seen <= LATE)
        assert status == TRACKING or reason.split(":")[0] in ("camera lost", "frames too late", "too few markers")


def test_a_camera_that_sent_nothing_since_the_last_pose_is_lost_even_before_late_s():
    """Frames reach the host 0.1 s after capture: 0.55 s after the last pose the cameras have
    been quiet only 0.45 s, yet they sent nothing since that pose's frames: camera lost, not
    frames too late (which is for frames that come, but late)."""
    w = Watch(CAMS, late_s=LATE)
    f = Facts("tracking", 0.0, seen=10.0, resumed=0.0, estimate=10.0, learned=0.0, seen_arrival=10.1)
    assert (
        w.classify(10.55, f, {"cam1": 0.46, "cam2": 0.46})[1]
        == "camera lost: no frames from any camera since the last pose"
    )
    assert w.classify(10.55, f, {"cam1": 0.01, "cam2": 0.46})[1] == "camera lost: cam2 (no frame since the last pose)"
    assert w.classify(10.65, f, {"cam1": 0.01, "cam2": 0.56})[1] == "camera lost: cam2 (no frame for 0.6 s)"
    assert w.classify(10.55, f, {"cam1": 0.01, "cam2": 0.02})[1].startswith("frames too late")


def test_a_break_shorter_than_the_watch_could_see_is_a_stretch_all_the_same():
    """Poses at 5.0 s and next at 5.55 s, the watch looking every 0.1 s: it never saw NOT
    TRACKING (at 5.5 s the pose was 0.5 s old), yet 0.55 s passed without a pose: a stretch."""
    w = Watch(CAMS, late_s=LATE)
    alive = {c: 0.01 for c in CAMS}
    w.tick(4.9, Facts("tracking", 0.0, 4.9, 0.0, 4.9, "", 0.0), alive)
    w.tick(5.0, Facts("tracking", 0.0, 5.0, 0.0, 5.0, "", 0.0), alive)
    assert w.tick(5.5, Facts("tracking", 0.0, 5.0, 0.0, 5.0, "", 0.0), alive) == []
    (ep,) = w.tick(5.6, Facts("tracking", 0.0, 5.55, 5.55, 5.55, "", 0.0, broke=5.0), alive)
    assert (ep.start, ep.end) == (5.0, 5.55) and ep.reasons[0].startswith("no pose: 0.55 s without one")
    assert w.tick(5.7, Facts("tracking", 0.0, 5.65, 5.55, 5.65, "", 0.0, broke=5.0), alive) == []  # once
    w.finish(6.0)
    assert w.totals()["not_tracking_s"] == pytest.approx(0.55) and w.totals()["tracking_s"] == pytest.approx(5.45)


def test_frames_late_not_lost_make_a_stretch_until_the_view_is_current_again():
    """Poses every 0.04 s of capture, but from 5.0 s they reach the live path late: nothing
    until 5.8 s (then the set captured at 5.2 s), the view current again at 6.0 s. No pose was
    lost, yet nobody could see the patient from 5.5 s to 6.0 s: the stretch runs from the last
    pose seen in time (5.0) to 6.0, not to 5.2 (the capture of the late frames)."""
    w = Watch(CAMS, late_s=LATE)
    alive = {c: 0.01 for c in CAMS}
    w.tick(5.0, Facts("tracking", 0.0, 5.0, 0.0, 5.0, "", 0.0, seen_arrival=5.0), alive)
    w.tick(5.6, Facts("tracking", 0.0, 5.0, 0.0, 5.0, "", 0.0, seen_arrival=5.0), alive)
    assert w.status == NOT_TRACKING and w.reason.startswith("frames too late")
    w.tick(5.8, Facts("tracking", 0.0, 5.2, 0.0, 5.2, "", 0.0, seen_arrival=5.8), alive)
    (ep,) = [
        e
        for e in w.tick(6.0, Facts("tracking", 0.0, 5.6, 0.0, 5.6, "", 0.0, seen_arrival=6.0), alive)
        if isinstance(e, Episode)
    ]
    assert (ep.start, ep.end) == (5.0, 6.0) and w.status == TRACKING
