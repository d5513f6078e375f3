"""A camera's drift baseline: the wall markers it saw when the baseline was set.

The record the drift procedure compares against (procedures/drift.py), the results store
reads back (store/baselines.py) and the baseline procedure takes (procedures/baseline.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from vts_hw.errors import VtsError
from vts_hw.vision.detect import DetectorSettings, detect_jpeg

GATE_PX = 12.0          # a marker further than this from its baseline position is not that marker


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

    @classmethod
    def from_frames(cls, camera: str, jpegs: list[bytes], taken: float,
                    settings: DetectorSettings | None = None) -> "Baseline":
        """Markers seen in every frame, averaged; IDs M1.. in reading order (rows, then columns)."""
        per_frame = [detect_jpeg(j, settings or DetectorSettings()).blobs for j in jpegs]
        if not per_frame or not per_frame[0]:
            return cls(camera, (), taken)
        ref = np.array([(b.x, b.y) for b in per_frame[0]])
        sums = np.zeros_like(ref)
        counts = np.zeros(len(ref))
        for blobs in per_frame:
            pts = np.array([(b.x, b.y) for b in blobs]).reshape(-1, 2)
            for i, j in match_markers(ref, pts, GATE_PX):
                sums[i] += pts[j]
                counts[i] += 1
        keep = counts == len(per_frame)
        mean = sums[keep] / counts[keep, None]
        order = sorted(range(len(mean)), key=lambda k: (round(mean[k][1] / 40), mean[k][0]))
        markers = tuple(BaselineMarker(f"M{n + 1}", float(mean[k][0]), float(mean[k][1]))
                        for n, k in enumerate(order))
        return cls(camera, markers, taken)

    def points(self) -> np.ndarray:
        return np.array([(m.x, m.y) for m in self.markers]).reshape(-1, 2)


def match_markers(ref: np.ndarray, pts: np.ndarray, gate: float) -> list[tuple[int, int]]:
    """One-to-one nearest matching (Hungarian on distance), pairs further than ``gate`` dropped."""
    if len(ref) == 0 or len(pts) == 0:
        return []
    d = np.linalg.norm(ref[:, None, :] - pts[None, :, :], axis=2)
    rows, cols = linear_sum_assignment(np.minimum(d, 10 * gate))
    return [(int(i), int(j)) for i, j in zip(rows, cols) if d[i, j] <= gate]
