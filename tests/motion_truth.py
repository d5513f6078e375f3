"""Helpers of the motion tests: a simulated patient, its synthetic tracks, and scoring against its truth."""

from __future__ import annotations

import numpy as np

from vts_hw.sim_devices.patient import add_patient
from vts_hw.sim_devices.patient_tracks import synthetic_tracks
from vts_hw.sim_devices.scene import Scene


def patient_tracks(
    seed: int,
    duration_s: float = 60.0,
    *,
    n_moves: int = 2,
    breathing: bool = True,
    creep_mm: float = 0.0,
    moves=None,
    **kw,
):
    scene = Scene.reference(seed=seed, start_epoch=1_790_000_000.0)
    t0 = scene.start_epoch + 5.0
    patient = add_patient(
        scene, t0, duration_s, seed, n_moves=n_moves, breathing=breathing, creep_mm=creep_mm, moves=moves
    )
    tracks, truth = synthetic_tracks(patient, t0, duration_s, seed=seed, **kw)
    return patient, tracks, truth, t0


def pose_errors(result, patient, still_only: bool = True):
    """(translation RMS mm, rotation RMS deg) of the body pose against the truth."""
    six = result.pose.six_dof()
    true = np.array([patient.six_dof(float(x)) for x in result.pose.t])
    sel = result.pose.valid & (~result.moving if still_only else True)
    err = six[sel] - true[sel]
    return float(np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1)))), float(
        np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1)))
    )


def true_moves(patient, min_mm: float = 2.0, min_deg: float = 1.0):
    return [
        m
        for m in patient.motion.moves
        if np.linalg.norm(m.translation_mm) >= min_mm or np.linalg.norm(m.rotation_deg) >= min_deg
    ]
