"""The wall markers among what one camera saw: a drift baseline taken from frames or tracks.

Rule 1 of the markers' roles (:mod:`vts_hw.vision.marker_roles`): the markers seen still in every
frame, averaged; those that moved or came and went are the baseline's ``others``. Where they lie
(rule 2) needs the other cameras: ``placed``, from procedures/baseline.py. The record itself is
:class:`vts_hw.vision.wall_baseline.Baseline`.
"""

from __future__ import annotations

import numpy as np

from vts_hw.vision.detect import DetectorSettings, detect_jpeg
from vts_hw.vision.marker_roles import follow, roles_of_tracks
from vts_hw.vision.wall_baseline import Baseline


def frame_points(jpegs: list[bytes], settings: DetectorSettings | None = None) -> list[np.ndarray]:
    """Each frame's marker centres (N x 2 px), as the drift QA detects them."""
    return [
        np.array([(b.x, b.y) for b in detect_jpeg(j, settings or DetectorSettings()).blobs]).reshape(-1, 2)
        for j in jpegs
    ]


def baseline_of_tracks(camera: str, tracks, taken: float, placed=None) -> Baseline:
    """The wall markers among one camera's ``tracks`` (marker_roles.follow): rule 1, then
    ``placed`` (rule 2, a Role or None per track, :meth:`RoomGeometry.place`'s order: the still ones)."""
    roles = roles_of_tracks(tracks)
    still = [k for k, r in enumerate(roles) if r is None]
    for k, r in zip(still, placed if placed is not None else [None] * len(still)):
        roles[k] = r
    wall = [t for t, r in zip(tracks, roles) if r is None or r.is_wall]
    others = tuple((round(t.x, 2), round(t.y, 2), r) for t, r in zip(tracks, roles) if r is not None and not r.is_wall)
    return Baseline.of_points(camera, [(t.x, t.y) for t in wall], taken, others)


def baseline_from_frames(
    camera: str, jpegs: list[bytes], taken: float, settings: DetectorSettings | None = None
) -> Baseline:
    """One camera's wall markers by motion alone (rule 1) in ``jpegs``."""
    return baseline_of_tracks(camera, follow(frame_points(jpegs, settings)), taken)


__all__ = ["frame_points", "baseline_of_tracks", "baseline_from_frames"]
