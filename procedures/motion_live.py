"""The scan's live path, read back for its offline analysis: the patient model it learned (the
offline fit uses that very model) and the poses it showed, compared with the offline poses
(:mod:`vts_hw.motion.agreement`; issue 33, docs/decisions/0092).

Times: the live poses and alerts are on the host clock; the offline series is on the SPECT's
list-mode clock when the scan was synchronised (mapped through the tracks' frame sets, which
carry both), else on the host clock too.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vts_hw.errors import DataError
from vts_hw.motion.agreement import Agreement, compare_live, explain_alerts
from vts_hw.motion.exports import time_origin
from vts_hw.motion.patient_model import PatientModel
from vts_hw.tracking.live.pose_log import LivePoses, load_model, read_poses

__all__ = ["LiveRecord", "read_live", "host_to_series", "agreement"]

PAIR_FRACTION = 0.4  # a live pose and an offline frame are the same frame set within this many periods


@dataclass
class LiveRecord:
    """What the scan's live path left: its model, its poses, its alerts (manifest), and what
    could not be read (one sentence each)."""

    model: PatientModel | None
    poses: LivePoses | None
    alerts: list
    problems: list


def read_live(folder, manifest: dict | None) -> LiveRecord:
    """The live record of the session ``folder`` (empty when the scan had no live path)."""
    folder = Path(folder)
    lm = (manifest or {}).get("live_motion") or {}
    problems, model, poses = [], None, None
    if folder.is_dir():
        try:
            model = load_model(folder)
        except DataError as exc:
            problems.append(f"live model not used: {exc}")
        try:
            poses = read_poses(folder)
        except DataError as exc:
            problems.append(f"live poses not compared: {exc}")
    if poses is not None and poses.skipped:
        problems.append(
            f"live poses: {poses.skipped} row(s) could not be read (a row torn when the scan "
            f"was stopped?) and were left out"
        )
    if lm.get("keep_problem"):
        problems.append(f"live poses: {lm['keep_problem']}")
    alerts = [a for a in lm.get("alerts") or [] if isinstance(a, dict) and "onset" in a and "time" in a]
    return LiveRecord(model, poses, alerts, problems)


def host_to_series(tracks, clock: str):
    """A function taking host s to the series' clock (the SPECT's when ``clock`` is spect:
    the line through the tracks' frame sets, which carry both), or None when it cannot be told."""
    if clock != "spect":
        return lambda t: np.asarray(t, float)
    h = np.asarray(tracks.host_time, float)
    sp = np.asarray(tracks.spect_time, float) if tracks.spect_time is not None else np.full(len(h), np.nan)
    ok = np.isfinite(h) & np.isfinite(sp)
    if ok.sum() < 2:
        return None
    a, b = np.polyfit(h[ok] - h[ok][0], sp[ok], 1)
    h0 = h[ok][0]
    return lambda t: a * (np.asarray(t, float) - h0) + b


def agreement(live: LiveRecord, result, tracks, alert_mm: float, alert_deg: float) -> Agreement | None:
    """The live poses against the offline ones of ``result`` (fitted with the live model), and
    each live alert explained or not; None when there is nothing to compare."""
    if live.poses is None or result.model is None or live.model is None:
        return None
    to_series = host_to_series(tracks, result.series.clock)
    if to_series is None:
        raise DataError(
            "the live poses' host times cannot be put on the list-mode clock (fewer than two frame sets with both)"
        )
    pose, period = result.pose, result.timeline.period
    p = live.poses
    agree = compare_live(to_series(p.t), p.R, p.T, pose.t, pose.R, pose.T, result.model.centre, PAIR_FRACTION * period)
    alerts = [{"onset": float(to_series(a["onset"])), "time": float(to_series(a["time"]))} for a in live.alerts]
    agree.alerts = explain_alerts(
        alerts, result.events, pose.t, pose.R, pose.T, result.model.centre, alert_mm, alert_deg, t0=time_origin(result)
    )
    return agree
