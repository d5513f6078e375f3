"""A camera's drift baseline: the wall markers it saw when the baseline was set.

The record the drift procedure compares against (procedures/drift.py), the results store
reads back (store/baselines.py) and the baseline procedure takes (procedures/baseline.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vts_hw.errors import VtsError
from vts_hw.vision.detect import DetectorSettings, detect_jpeg
from vts_hw.vision.marker_roles import GATE_PX, follow, match_markers, roles_of_tracks  # noqa: F401  (re-exported)


class NoBaseline(VtsError):
    """A camera without a drift baseline (exit 5)."""

    exit_code = 5


@dataclass(frozen=True)
class BaselineMarker:
    id: str
    x: float
    y: float


@dataclass(frozen=True)
class Baseline:
    """The wall markers of one camera when the baseline was set."""

    camera: str
    markers: tuple[BaselineMarker, ...]
    taken: float
    run_id: int | None = None
    #: the markers seen that are not wall markers: ``((x, y, Role), ...)`` (vision/marker_roles.py);
    #: not stored (a baseline run keeps its wall markers only), said when it is set
    others: tuple = ()

    @classmethod
    def of_points(cls, camera: str, points, taken: float, others: tuple = ()) -> "Baseline":
        """The wall markers at ``points`` (N x 2 px), IDs M1.. in reading order (rows, then columns)."""
        pts = np.asarray(points, float).reshape(-1, 2)
        order = sorted(range(len(pts)), key=lambda k: (round(pts[k][1] / 40), pts[k][0]))
        return cls(camera, tuple(BaselineMarker(f"M{n + 1}", float(pts[k][0]), float(pts[k][1]))
                                 for n, k in enumerate(order)), taken, None, tuple(others))

    @classmethod
    def from_frames(cls, camera: str, jpegs: list[bytes], taken: float,
                    settings: DetectorSettings | None = None) -> "Baseline":
        """One camera's wall markers by motion alone (vision/marker_roles.py, rule 1): the markers
        seen still in every frame, averaged; those that moved or came and went are ``others``.
        Where they lie (rule 2) needs the other cameras: procedures/baseline.py."""
        return cls.of_tracks(camera, follow(frame_points(jpegs, settings)), taken)

    @classmethod
    def of_tracks(cls, camera: str, tracks, taken: float, placed=None) -> "Baseline":
        """The wall markers among one camera's ``tracks`` (marker_roles.follow): rule 1, then
        ``placed`` (rule 2, a Role or None per track, :meth:`Room.place`'s order: the still ones)."""
        roles = roles_of_tracks(tracks)
        still = [k for k, r in enumerate(roles) if r is None]
        for k, r in zip(still, placed if placed is not None else [None] * len(still)):
            roles[k] = r
        wall = [t for t, r in zip(tracks, roles) if r is None or r.is_wall]
        others = tuple((round(t.x, 2), round(t.y, 2), r) for t, r in zip(tracks, roles) if r is not None and not r.is_wall)
        return cls.of_points(camera, [(t.x, t.y) for t in wall], taken, others)

    def points(self) -> np.ndarray:
        return np.array([(m.x, m.y) for m in self.markers]).reshape(-1, 2)


def frame_points(jpegs: list[bytes], settings: DetectorSettings | None = None) -> list[np.ndarray]:
    """Each frame's marker centres (N x 2 px), as the drift QA detects them."""
    return [np.array([(b.x, b.y) for b in detect_jpeg(j, settings or DetectorSettings()).blobs]).reshape(-1, 2)
            for j in jpegs]
