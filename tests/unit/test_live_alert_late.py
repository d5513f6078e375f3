"""An alert raised long after the frame that raised it (the host behind its frames) says so, in
its line and in the manifest (issue 20: a late alert is reported as the computer's, never passed
off as the rule's); an alert raised on time says nothing of it."""

import time
from types import SimpleNamespace

import numpy as np

from vts_hw.procedures.scan_live import LATE_SAY_S, LiveMotion
from vts_hw.tracking.live.alerts import Alert
from vts_hw.tracking.live.estimator import LiveEstimate
from vts_hw.tracking.live.watch import BlindAlert


class _Session:
    def __init__(self):
        self.meta = {"live_motion": {"alerts": [], "blind_alerts": []}}

    def update_manifest(self, fn):
        fn(self.meta)


def _live():
    motion = SimpleNamespace(alert_mm=3.0, alert_deg=2.0, alert_command=None)
    said = []
    rig = SimpleNamespace(motion=motion, calibration=SimpleNamespace(cameras=None, mapping=None))
    lm = LiveMotion(rig, calibration=None, mapping=None, on_alert_text=said.append)
    return lm, said


def test_a_motion_alert_raised_late_says_how_late_and_why():
    lm, said = _live()
    session = _Session()
    est = LiveEstimate(phase="tracking", frame="vts", time=None, six_dof=tuple(np.zeros(6)))
    now = time.time()
    lm._motion_alert(session, Alert(now - 1.2, now - 3.0, 6.0, 1.0), est)  # its frame 1.2 s ago
    lm._motion_alert(session, Alert(time.time(), now - 2.0, 6.0, 1.0), est)  # on time
    late, on_time = session.meta["live_motion"]["alerts"]
    assert late["late_s"] >= 1.2 and "s after its frame: this computer is behind" in late["text"]
    assert "raised 1.2 s after" in said[0] or "raised 1.3 s after" in said[0]
    assert on_time["late_s"] < LATE_SAY_S and "behind" not in on_time["text"] and "behind" not in said[1]


def test_a_blind_alert_acted_on_late_says_so_too():
    lm, said = _live()
    session = _Session()
    now = time.time()
    lm._blind_alert(session, BlindAlert(now - 5.0, now - 0.8, "camera lost: cam2"))
    (ev,) = session.meta["live_motion"]["blind_alerts"]
    assert ev["late_s"] >= 0.8 and "this computer is behind" in ev["text"] and "camera lost: cam2" in said[0]
