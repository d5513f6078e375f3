"""When the body has moved: the alert rule, on the breathing-separated pose.

A *deviation* is measured from the alert reference pose (the reference, and after an alert
the pose the body settled in): the translation of the markers' centre (mm) and the angle of
the turn (deg). An *excursion* begins when the deviation leaves the onset levels
(``onset_mm``, ``onset_deg``: 15 % of the thresholds, or four times the still pose's noise
measured over the reference period when that is more). Its **onset** is the instant the body
started to leave its pose, found by looking back over the recent poses (:func:`find_onset`):
the first part of the rise, projected on the move's direction and fitted with the pose
before it, extrapolated back to where it left that pose. The alert is raised at the first
estimate where

* the deviation exceeds ``alert_mm`` or ``alert_deg``, and
* the excursion has lasted longer than ``after_s`` since its onset.

So "longer than ``after_s``" counts the whole move, from when the body started to leave its
pose, not from when it crossed the threshold; a cough or a twitch that comes back within
``after_s`` never alerts, and breathing (taken out of the pose) does not either. The onset is
at most ``BACK_S`` before the last instant within the onset levels and never after the first
estimate beyond them; when no pose was seen around it (lost frames) it is the last pose
before that stretch and ``onset_known_s`` its length: the move started between the two.
After an alert the reference of the rule follows the body for ``settle_s`` (the rest of the
move) and then stays: a further move of the thresholds' size alerts again. See
docs/decisions/0036-live-motion.md and 0088-alert-onset-looked-back.md.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

__all__ = ["Alert", "AlertRule", "find_onset"]

NOISE_FACTOR = 4.0  # onset levels at least this many times the still pose's RMS noise
# the onset looked back for (decision 0088)
BASELINE_S = 0.6  # the pose before the move: the poses over this long ...
BACK_S = 0.4  # ... ending this long before the last instant within the onset levels; the
#                      onset found at most this long before that instant
RISE_SHARE = 0.15  # the first part of the rise fitted: up to this share of the deviation now
RISE_MAX_S = 2.0  # ... and at most this long after the last instant within the onset levels
RISE_MIN_POSES = 5  # ... and at least this many poses beyond the onset levels (a slow ramp
#                      reaches them in a few poses: fewer let the noise tilt it) ...
RISE_CAP = 0.5  # ... unless the deviation passed this share of now before them (a sudden
#                      move: past its half the rise bends over, and the fit would find it late)
POWERS = (1.0, 2.0)  # its shapes: a ramp, a steady acceleration (a start smoother than that is
#                      found late rather than early: an early onset would shorten a twitch's hold)
STEP_S = 0.005  # the onsets tried
GAP_S = 0.25  # poses further apart than this: a stretch without a pose


@dataclass(frozen=True)
class Alert:
    time: float  # host s of the estimate that raised it
    onset: float  # host s the move started: the body left its pose (found looking back)
    move_mm: float
    turn_deg: float
    onset_known_s: float = 0.0  # the poses around the onset this far apart (the frame period when none
    #                              was lost); longer than GAP_S: no pose in that stretch, the onset the last
    #                              before it, and the move started between onset and onset + this

    def text(self, alert_mm: float, alert_deg: float) -> str:
        gap = f"; it started during {self.onset_known_s:.1f} s without a pose" if self.onset_known_s > GAP_S else ""
        return (
            f"PATIENT MOVED: {self.move_mm:.1f} mm, {self.turn_deg:.1f} deg (limits {alert_mm:g} mm, "
            f"{alert_deg:g} deg) for {self.time - self.onset:.1f} s, breathing excluded{gap}"
        )


def _turn_deg(M: np.ndarray) -> float:
    """The angle of the rotation ``M`` (deg)."""
    return float(np.degrees(np.arccos(np.clip((np.trace(M) - 1.0) / 2.0, -1.0, 1.0))))


def _turns_deg(M: np.ndarray) -> np.ndarray:
    """The rotation vectors (deg) of the rotations ``M`` (N, 3, 3), turns of less than 90 deg."""
    w = 0.5 * np.stack([M[:, 2, 1] - M[:, 1, 2], M[:, 0, 2] - M[:, 2, 0], M[:, 1, 0] - M[:, 0, 1]], axis=1)
    s = np.linalg.norm(w, axis=1, keepdims=True)  # sin of the angle
    angle = np.arcsin(np.clip(s, 0.0, 1.0))
    return np.degrees(w * np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 1.0))


def _bracket(ts: np.ndarray, t0: float) -> tuple[float, float]:
    """The onset ``t0`` as reported: ``(onset, onset_known_s)``: inside a stretch without a pose
    longer than GAP_S, the pose before it and the stretch's length."""
    j = int(np.clip(np.searchsorted(ts, t0), 1, len(ts) - 1))
    gap = float(ts[j] - ts[j - 1])
    if gap > GAP_S and t0 > ts[j - 1]:
        return float(ts[j - 1]), gap
    return float(t0), gap


def find_onset(
    ts, centres, rotations, still_until: float, left: float, alert_mm: float, alert_deg: float, powers=POWERS
) -> tuple[float, float] | None:
    """When the body started to leave its pose, from the poses ``(ts, centres (N, 3),
    rotations (N, 3, 3))`` in time order: ``still_until`` the last estimate within the onset
    levels, ``left`` the first beyond them. Returns ``(onset, onset_known_s)``, or None when
    the poses do not hold the pose before the move (then the caller keeps ``still_until``).

    The deviation, in units of the thresholds (mm / alert_mm, deg / alert_deg, six values),
    is taken from the mean pose over BASELINE_S ending BACK_S before ``still_until`` and
    projected on the direction the body has gone since; the poses from that baseline to the
    first at RISE_SHARE of the deviation now (RISE_MIN_POSES beyond ``left`` at least, short of
    RISE_CAP of it) are fitted with ``b + a (t - t0)^p`` for each
    trial onset ``t0`` (every STEP_S from BACK_S before ``still_until`` to just before ``left``) and each
    shape ``p`` of POWERS; the onset is the ``t0`` of the least squares."""
    ts = np.asarray(ts, float)
    i_left = int(np.searchsorted(ts, left))
    if i_left == 0 or i_left >= len(ts):
        return None
    if ts[i_left] - ts[i_left - 1] > GAP_S:  # it left its pose unseen: bounded by the stretch
        return float(ts[i_left - 1]), float(ts[i_left] - ts[i_left - 1])
    base = np.flatnonzero((ts >= still_until - BACK_S - BASELINE_S) & (ts <= still_until - BACK_S))
    if len(base) < 3:
        return None
    C, Rs = np.asarray(centres, float), np.asarray(rotations, float)
    v = np.hstack([(C - C[base[0]]) / alert_mm, _turns_deg(Rs @ Rs[base[0]].T) / alert_deg])
    d = v[-1] - v[base].mean(axis=0)
    size = float(np.linalg.norm(d))
    if not np.isfinite(size) or size == 0.0:
        return None
    r = (v - v[base].mean(axis=0)) @ (d / size)
    beyond = np.flatnonzero((r > RISE_SHARE * r[-1]) & (ts >= left))
    end = min(int(beyond[0]) if len(beyond) else len(ts), int(np.searchsorted(ts, still_until + RISE_MAX_S)))
    half = np.flatnonzero((r > RISE_CAP * r[-1]) & (ts >= left))  # a few poses beyond the levels at least,
    end = max(end, min(i_left + RISE_MIN_POSES, int(half[0]) if len(half) else len(ts)))  # not past half
    tt, rr = ts[base[0] : end], r[base[0] : end]
    trial = np.arange(still_until - BACK_S, ts[i_left] - STEP_S / 2, STEP_S)  # before it was seen gone
    best, onset = np.inf, None
    n, sy = len(tt), rr.sum()
    for p in powers:
        X = np.maximum(0.0, tt[None, :] - trial[:, None]) ** p  # (trials, poses)
        sx, sxx, sxy = X.sum(axis=1), (X * X).sum(axis=1), X @ rr
        den = n * sxx - sx * sx
        ok = den > 1e-12
        a = np.where(ok, (n * sxy - sx * sy) / np.where(ok, den, 1.0), 0.0)
        b = (sy - a * sx) / n
        sse = ((rr[None, :] - b[:, None] - a[:, None] * X) ** 2).sum(axis=1)
        sse = np.where(ok & (a > 0), sse, np.inf)
        k = int(np.argmin(sse))
        if sse[k] < best:
            best, onset = float(sse[k]), float(trial[k])
    if onset is None:
        return None
    return _bracket(ts, onset)


class AlertRule:
    def __init__(
        self,
        alert_mm: float,
        alert_deg: float,
        after_s: float,
        onset_fraction: float = 0.15,
        settle_s: float = 2.0,
        noise_mm: float = 0.0,
        noise_deg: float = 0.0,
    ):
        self.alert_mm, self.alert_deg, self.after_s = alert_mm, alert_deg, after_s
        # the onset levels: a fraction of the thresholds, but clear of the still pose's noise
        self.onset_mm = max(onset_fraction * alert_mm, NOISE_FACTOR * noise_mm)
        self.onset_deg = max(onset_fraction * alert_deg, NOISE_FACTOR * noise_deg)
        self.settle_s = settle_s
        self.R_ref = np.eye(3)
        self.c_ref: np.ndarray | None = None
        self.still_until: float | None = None  # last time within the onset levels
        self.left: float | None = None  # the first estimate after it
        self.onset: float | None = None  # the excursion's onset, once looked back for
        self.onset_known_s = 0.0
        self.alerted_at: float | None = None
        self.alerts: list[Alert] = []
        self.move_mm = 0.0
        self.turn_deg = 0.0
        # the recent poses (time, centre, rotation): what the onset is looked back for in
        self._poses: deque[tuple[float, np.ndarray, np.ndarray]] = deque()
        self._keep_s = after_s + BACK_S + BASELINE_S + RISE_MAX_S

    @property
    def state(self) -> str:
        if self.alerted_at is not None:
            return "ALERT"
        if self.move_mm > self.alert_mm or self.turn_deg > self.alert_deg:
            return "moving"
        return "still" if self.move_mm <= self.onset_mm and self.turn_deg <= self.onset_deg else "off pose"

    def _look_back(self, still_until: float, left: float) -> float:
        """The excursion's onset (kept in ``onset``, with ``onset_known_s``)."""
        since = still_until - BACK_S - BASELINE_S
        ts, cs, rs = zip(*(p for p in self._poses if p[0] >= since))
        found = find_onset(ts, cs, rs, still_until, left, self.alert_mm, self.alert_deg)
        self.onset, self.onset_known_s = found or (still_until, left - still_until)
        return self.onset

    def update(self, t: float, R: np.ndarray, T: np.ndarray, centre: np.ndarray) -> Alert | None:
        """One estimate: the body's pose ``x -> R x + T`` from the reference, at host ``t``;
        ``centre`` the markers' reference centre. Returns the alert raised, if any."""
        c = R @ centre + T
        if self.c_ref is None:
            self.c_ref = centre.copy()
        self._poses.append((t, c, R.copy()))
        while self._poses[0][0] < t - self._keep_s:
            self._poses.popleft()
        self.move_mm = float(np.linalg.norm(c - self.c_ref))
        self.turn_deg = _turn_deg(R @ self.R_ref.T)
        if self.alerted_at is not None:
            if t - self.alerted_at <= self.settle_s:  # the rest of the move that alerted
                self.R_ref, self.c_ref = R.copy(), c.copy()
                self.move_mm = self.turn_deg = 0.0
                self.still_until, self.left, self.onset = t, None, None
                return None
            self.alerted_at = None
        if self.move_mm <= self.onset_mm and self.turn_deg <= self.onset_deg or self.still_until is None:
            self.still_until, self.left, self.onset = t, None, None
            return None
        if self.left is None:
            self.left = t
        if not (self.move_mm > self.alert_mm or self.turn_deg > self.alert_deg):
            return None
        # beyond the thresholds: the onset matters once the excursion may have lasted after_s
        if t - (self.still_until - BACK_S) <= self.after_s:
            return None
        onset = self._look_back(self.still_until, self.left)  # (at each estimate until it alerts:
        if t - onset > self.after_s:  # the move seen further)
            a = Alert(t, onset, self.move_mm, self.turn_deg, self.onset_known_s)
            self.alerts.append(a)
            self.alerted_at = t
            return a
        return None
