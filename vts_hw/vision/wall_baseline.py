"""A camera's drift baseline: the wall markers it saw when the baseline was set.

The record the drift procedure compares against (procedures/drift.py), the results store
reads back (store/baselines.py) and the baseline procedure takes (procedures/baseline.py).
The record alone: telling the wall markers among what a camera saw is
:mod:`vts_hw.vision.wall_markers` (the detector and the markers' roles), which a command that
only reads baselines (`vts qa import`) never loads.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vts_hw.errors import VtsError


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
    def of_points(cls, camera: str, points, taken: float, others: tuple = ()) -> Baseline:
        """The wall markers at ``points`` (N x 2 px), IDs M1.. in reading order (rows, then columns)."""
        pts = np.asarray(points, float).reshape(-1, 2)
        order = sorted(range(len(pts)), key=lambda k: (round(pts[k][1] / 40), pts[k][0]))
        return cls(
            camera,
            tuple(BaselineMarker(f"M{n + 1}", float(pts[k][0]), float(pts[k][1])) for n, k in enumerate(order)),
            taken,
            None,
            tuple(others),
        )

    def points(self) -> np.ndarray:
        return np.array([(m.x, m.y) for m in self.markers]).reshape(-1, 2)
