"""When the body has moved: the alert rule, on the breathing-separated pose.

A *deviation* is measured from the alert reference pose (the reference, and after an alert
the pose the body settled in): the translation of the markers' centre (mm) and the angle of
the turn (deg). An *excursion* starts at its **onset**, the last instant the deviation was
within the onset levels (``onset_mm``, ``onset_deg``: 15 % of the thresholds, or four times
the still pose's noise measured over the reference period when that is more). The alert is raised at the first estimate where

* the deviation exceeds ``alert_mm`` or ``alert_deg``, and
* the excursion has lasted longer than ``after_s`` since its onset.

So "longer than ``after_s``" counts the whole move, from when the body started to leave its
pose, not from when it crossed the threshold; a cough or a twitch that comes back within
``after_s`` never alerts, and breathing (taken out of the pose) does not either. After an
alert the reference follows the body for ``settle_s`` (the rest of the move) and then stays:
a further move of the thresholds' size alerts again. See docs/decisions/0036-live-motion.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["AlertRule", "Alert"]

NOISE_FACTOR = 4.0   # onset levels at least this many times the still pose's RMS noise


@dataclass(frozen=True)
class Alert:
    time: float          # host s of the estimate that raised it
    onset: float         # host s the excursion started (the body left its pose)
    move_mm: float
    turn_deg: float
    onset_known_s: float = 0.0   # the move started between onset and onset + this (the next estimate: a gap)

    def text(self, alert_mm: float, alert_deg: float) -> str:
        gap = (f"; it started during {self.onset_known_s:.1f} s without a pose" if self.onset_known_s > 0.25 else "")
        return (f"PATIENT MOVED: {self.move_mm:.1f} mm, {self.turn_deg:.1f} deg (limits {alert_mm:g} mm, "
                f"{alert_deg:g} deg) for {self.time - self.onset:.1f} s, breathing excluded{gap}")


class AlertRule:
    def __init__(self, alert_mm: float, alert_deg: float, after_s: float, onset_fraction: float = 0.15,
                 settle_s: float = 2.0, noise_mm: float = 0.0, noise_deg: float = 0.0):
        self.alert_mm, self.alert_deg, self.after_s = alert_mm, alert_deg, after_s
        # the onset levels: a fraction of the thresholds, but clear of the still pose's noise
        self.onset_mm = max(onset_fraction * alert_mm, NOISE_FACTOR * noise_mm)
        self.onset_deg = max(onset_fraction * alert_deg, NOISE_FACTOR * noise_deg)
        self.settle_s = settle_s
        self.R_ref = np.eye(3)
        self.c_ref: np.ndarray | None = None
        self.onset: float | None = None      # last time within the onset levels
        self.left: float | None = None       # the first estimate after it (the start lies between)
        self.alerted_at: float | None = None
        self.alerts: list[Alert] = []
        self.move_mm = 0.0
        self.turn_deg = 0.0

    @property
    def state(self) -> str:
        if self.alerted_at is not None:
            return "ALERT"
        if self.move_mm > self.alert_mm or self.turn_deg > self.alert_deg:
            return "moving"
        return "still" if self.move_mm <= self.onset_mm and self.turn_deg <= self.onset_deg else "off pose"

    def update(self, t: float, R: np.ndarray, T: np.ndarray, centre: np.ndarray) -> Alert | None:
        """One estimate: the body's pose ``x -> R x + T`` from the reference, at host ``t``;
        ``centre`` the markers' reference centre. Returns the alert raised, if any."""
        c = R @ centre + T
        if self.c_ref is None:
            self.c_ref = centre.copy()
        self.move_mm = float(np.linalg.norm(c - self.c_ref))
        self.turn_deg = float(np.degrees(np.linalg.norm(Rotation.from_matrix(R @ self.R_ref.T).as_rotvec())))
        if self.alerted_at is not None:
            if t - self.alerted_at <= self.settle_s:      # the rest of the move that alerted
                self.R_ref, self.c_ref = R.copy(), c.copy()
                self.move_mm = self.turn_deg = 0.0
                self.onset, self.left = t, None
                return None
            self.alerted_at = None
        if self.move_mm <= self.onset_mm and self.turn_deg <= self.onset_deg or self.onset is None:
            self.onset, self.left = t, None
            return None
        if self.left is None:
            self.left = t
        if (self.move_mm > self.alert_mm or self.turn_deg > self.alert_deg) and t - self.onset > self.after_s:
            a = Alert(t, self.onset, self.move_mm, self.turn_deg, self.left - self.onset)
            self.alerts.append(a)
            self.alerted_at = t
            return a
        return None
