"""A recording's frames per camera, as arrays.

:func:`load_camera_frames` reads one camera's index (frames whose bytes lie past the end of its
``.mjpeg`` are dropped and counted). Mapping them to host time and grouping them into frame
sets across cameras is tracking's (:mod:`vts_hw.tracking.frame_sets`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vts_hw.errors import DataError
from vts_hw.recording.folder import read_index

__all__ = ["CameraFrames", "load_camera_frames"]


@dataclass
class CameraFrames:
    """One camera's indexed frames as arrays (frames past the end of the ``.mjpeg`` dropped).

    ``camera_time`` NaN where a frame had no stamp; ``host_time`` is the *receive* time.
    ``beyond_camera_time``/``beyond_host_time``: the stamps and receive times of the indexed
    frames whose bytes are not in the ``.mjpeg`` (cut short): time the recording should hold."""

    name: str
    mjpeg: Path
    frame: np.ndarray
    offset: np.ndarray
    length: np.ndarray
    camera_time: np.ndarray
    host_time: np.ndarray
    beyond_end: int = 0
    beyond_camera_time: np.ndarray = field(default_factory=lambda: np.zeros(0))
    beyond_host_time: np.ndarray = field(default_factory=lambda: np.zeros(0))


def load_camera_frames(folder: Path, name: str) -> CameraFrames:
    idx, mj = folder / f"{name}.index.csv", folder / f"{name}.mjpeg"
    if not idx.exists() or not mj.exists():
        raise DataError(f"{folder}: camera {name!r} has no {idx.name} and {mj.name}")
    rows = read_index(idx)
    size = mj.stat().st_size
    nan = math.nan
    arr = np.array(
        [
            (
                r.frame,
                r.offset,
                r.length,
                nan if r.camera_time is None else r.camera_time,
                nan if r.host_time is None else r.host_time,
            )
            for r in rows
        ],
        float,
    ).reshape(-1, 5)
    inside = arr[:, 1] + arr[:, 2] <= size
    out = arr[~inside]
    arr = arr[inside]
    return CameraFrames(
        name,
        mj,
        arr[:, 0].astype(np.int64),
        arr[:, 1].astype(np.int64),
        arr[:, 2].astype(np.int64),
        arr[:, 3],
        arr[:, 4],
        int((~inside).sum()),
        out[:, 3],
        out[:, 4],
    )
