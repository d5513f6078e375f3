"""The VTS side of the VTS → SPECT mapping measured now by the calibrated cameras (given,
opened by the caller): two or more. The points file (`--vts FILE`) is read by
procedures/mapping_points.py.

What `vts calibrate spect --from-cameras` runs; a script calls the same.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from pathlib import Path

from vts_hw.camera_led import light
from vts_hw.errors import ConfigError, DataError
from vts_hw.procedures.spect_mapping import SpectMapping
from vts_hw.procedures.steps import LED_SETTLE_S, SNAPSHOT_COMPRESSION, average_centroids
from vts_hw.vision.calibration_io import load_calibration
from vts_hw.vision.camera_set import covered_names
from vts_hw.vision.detect import detect_jpeg


def camera_calibration_for(rig, calibration_path=None, what: str = "--from-cameras"):
    """The camera calibration given, else the rig config's (stereo or N cameras); ConfigError
    when there is none or the rig has fewer than two cameras (``what`` needs them)."""
    path = calibration_path or rig.calibration.cameras
    if path is None:
        raise ConfigError(
            "no camera calibration: give --calibration or set calibration.cameras in the "
            "rig config (`vts calibrate stereo` or `vts calibrate cameras`)."
        )
    if len(rig.cameras) < 2:
        raise ConfigError(f"{what} needs two cameras in the rig config.")
    return load_calibration(path)


def calibrated_cameras(rig, calibration) -> list:
    """The rig's camera configs the calibration covers (all of them for an N-camera file named
    after the rig's cameras, the first two for a stereo file): the ones to open and measure
    with. ConfigError when fewer than two."""
    names = covered_names(calibration, [c.name for c in rig.cameras])
    if len(names) < 2:
        raise ConfigError(f"the calibration covers {len(names)} of the rig's cameras; two or more are needed.")
    return [c for c in rig.cameras if c.name in names]


def mapping_from_cameras(
    cameras: Sequence, calibration, volume, frames: int = 10, progress: Callable[[str], None] | None = None
):
    """The analysed mapping, its VTS side measured now: per camera LED on, ``frames``
    snapshots, centroids averaged; the spheres picked out by the shape of the SPECT's, seen
    by every camera given (two or more, named as in the calibration or the rig)."""
    if len(cameras) < 2:
        raise DataError(f"the mapping from cameras needs two cameras or more, got {len(cameras)}.")
    if not Path(volume).exists():
        raise DataError(f"{volume}: no such file or directory.")
    pts = {}
    for k, cam in enumerate(cameras):
        if light(cam) == "on":  # a camera without an LED (a replay) shows its frames as they are
            time.sleep(LED_SETTLE_S)
        if progress:
            progress(f"{cam.name}: {frames} snapshots")
        pts[getattr(cam, "name", None) or f"cam{k + 1}"] = average_centroids(
            [detect_jpeg(cam.snapshot(SNAPSHOT_COMPRESSION).jpeg) for _ in range(frames)]
        )
    return SpectMapping.from_views(calibration, pts, volume).analyze()
