"""The body pose's health per row of the scan (issue 33 §2): :func:`vts_hw.pose_health.health_series`
given what each row's fit saw -- the markers used (``BodyPose.n_markers``) of the patient's, the fit
residual (``BodyPose.rms_mm``), the cameras that saw the patient's markers in that row
(``MarkerSeries.cameras``), whether frames were recorded then (the timeline), age 0 (each row's pose
is fitted from its own frames). Read beside the pose, never written into it."""

from __future__ import annotations

import numpy as np

from vts_hw.pose_health import HealthSeries, health_series

__all__ = ["body_pose_health", "result_health"]


def body_pose_health(pose, patient, frames=None) -> HealthSeries:
    """``pose``: a BodyPose (``t``, ``R``, ``T``, ``rms_mm``, ``n_markers``); ``patient``: the
    MarkerSeries of the patient's markers it was fitted to (same rows); ``frames``: per row
    whether a frame set was recorded (None: every row)."""
    n = np.asarray(pose.n_markers, float)
    rms = np.where(np.isfinite(np.asarray(pose.T, float)[:, 0]), pose.rms_mm, np.nan)  # no pose: not known
    cams = None
    if getattr(patient, "cameras", None) is not None and patient.cameras.size:
        c = np.asarray(patient.cameras, float)
        seen = c > 0
        cams = np.where(seen.any(axis=1), np.where(seen, c, 0.0).sum(axis=1) / np.maximum(seen.sum(axis=1), 1), np.nan)
    return health_series(n, patient.P.shape[1], rms, cams, 0.0, frames)


def result_health(result) -> HealthSeries:
    """The health of every row of a MotionResult (its pose, patient markers and timeline)."""
    frames = result.timeline.frames if result.timeline is not None else None
    return body_pose_health(result.pose, result.patient, frames)
