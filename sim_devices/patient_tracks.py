"""Marker tracks made straight from the simulated patient, no images: for unit tests and the
motion benchmark's analysis part.

:func:`synthetic_tracks` samples :meth:`Patient.markers_at` at ``fps`` (host times from
``t0``), adds Gaussian noise (``noise_mm`` per axis), drops points now and then (``drop``: the
chance a point is missing; ``dropout_s``: every marker is also hidden for a stretch of that
length once, at a random time, as behind a SPECT head), adds still wall markers, and numbers
the markers as a tracker would (shuffled ids, not C1..A4). Positions are given in the SPECT
frame (``xyz_spect``, the same as ``xyz``: an identity mapping), times on the host clock.
"""

from __future__ import annotations

import numpy as np

from vts_hw.tracking.tracks import Tracks

__all__ = ["synthetic_tracks", "WALL"]

WALL = np.array([[-400.0, 300.0, 1500.0], [-150.0, 420.0, 1500.0], [200.0, 380.0, 1500.0], [450.0, 250.0, 1500.0]])


def synthetic_tracks(
    patient,
    t0: float,
    duration_s: float,
    *,
    fps: float = 25.0,
    noise_mm: float = 0.05,
    drop: float = 0.01,
    dropout_s: float = 0.0,
    seed: int = 0,
    wall: bool = True,
) -> tuple:
    """``(tracks, truth)``: the :class:`Tracks` and a dict ``{"t": times, "ids": {track id:
    marker name}}``."""
    rng = np.random.default_rng([seed, 5])
    t = t0 + np.arange(int(round(duration_s * fps))) / fps
    names = [m.id for m in patient.rest]
    pos = np.array([[m.center for m in patient.markers_at(float(x), np.zeros(3))] for x in t])  # (F, 8, 3)
    if wall:
        pos = np.concatenate([pos, np.broadcast_to(WALL, (len(t),) + WALL.shape)], axis=1)
        names = names + [f"W{i + 1}" for i in range(len(WALL))]
    F, M, _ = pos.shape
    pos = pos + rng.normal(0.0, noise_mm, pos.shape)
    keep = rng.random((F, M)) >= drop
    if dropout_s > 0:
        for m in range(M):
            a = rng.uniform(t[0], t[-1] - dropout_s)
            keep[:, m] &= ~((t >= a) & (t < a + dropout_s))
    ids = rng.permutation(M) + 1
    pf, mk, points = [], [], []
    for f in range(F):
        for j in np.flatnonzero(keep[f]):
            pf.append(f)
            mk.append(ids[j])
            points.append(pos[f, j])
    N = len(pf)
    xyz = np.array(points).reshape(-1, 3)
    tr = Tracks(
        host_time=t,
        camera_names=["cam1", "cam2"],
        camera_time=np.column_stack([t, t]),
        camera_frame=np.column_stack([np.arange(F), np.arange(F)]),
        n_blobs=np.full((F, 2), M),
        point_frame=np.array(pf, int),
        marker=np.array(mk, int),
        xyz=xyz,
        reproj_px=np.zeros(N),
        uv=np.zeros((N, 4)),
        meta={"synthetic": True, "frame_period_s": 1.0 / fps},
        xyz_spect=xyz.copy(),
    )
    return tr, {"t": t, "ids": {int(ids[m]): names[m] for m in range(M)}}
