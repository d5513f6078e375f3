"""The VTS side of the VTS → SPECT mapping: the phantom's sphere centres from a points file,
or measured now by the calibrated cameras (given, opened by the caller): two or more.

What `vts calibrate spect --vts FILE` and `--from-cameras` run; a script calls the same.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from vts_hw.bounded import SMALL, read_text
from vts_hw.errors import ConfigError, DataError


def camera_calibration_for(rig, calibration_path=None, what: str = "--from-cameras"):
    """The camera calibration given, else the rig config's (stereo or N cameras); ConfigError
    when there is none or the rig has fewer than two cameras (``what`` needs them)."""
    from vts_hw.vision.calibration_io import load_calibration

    path = calibration_path or rig.calibration.stereo
    if path is None:
        raise ConfigError("no camera calibration: give --calibration or set calibration.stereo in the "
                          "rig config (`vts calibrate stereo` or `vts calibrate cameras`).")
    if len(rig.cameras) < 2:
        raise ConfigError(f"{what} needs two cameras in the rig config.")
    return load_calibration(path)


def calibrated_cameras(rig, calibration) -> list:
    """The rig's camera configs the calibration covers (all of them for an N-camera file named
    after the rig's cameras, the first two for a stereo file): the ones to open and measure
    with. ConfigError when fewer than two."""
    from vts_hw.vision.camera_set import covered_names

    names = covered_names(calibration, [c.name for c in rig.cameras])
    if len(names) < 2:
        raise ConfigError(f"the calibration covers {len(names)} of the rig's cameras; two or more are needed.")
    return [c for c in rig.cameras if c.name in names]


def mapping_from_cameras(cameras: Sequence, calibration, volume, frames: int = 10,
                         progress: Callable[[str], None] | None = None):
    """The analysed mapping, its VTS side measured now: per camera LED on, ``frames``
    snapshots, centroids averaged; the spheres picked out by the shape of the SPECT's, seen
    by every camera given (two or more, named as in the calibration or the rig)."""
    from vts_hw.procedures.spect_mapping import SpectMapping
    from vts_hw.procedures.steps import LED_SETTLE_S, SNAPSHOT_COMPRESSION, average_centroids
    from vts_hw.vision.detect import detect_jpeg

    if len(cameras) < 2:
        raise DataError(f"the mapping from cameras needs two cameras or more, got {len(cameras)}.")
    if not Path(volume).exists():
        raise DataError(f"{volume}: no such file or directory.")
    pts = {}
    for k, cam in enumerate(cameras):
        cam.led_on()
        time.sleep(LED_SETTLE_S)
        if progress:
            progress(f"{cam.name}: {frames} snapshots")
        pts[getattr(cam, "name", None) or f"cam{k + 1}"] = average_centroids(
            [detect_jpeg(cam.snapshot(SNAPSHOT_COMPRESSION).jpeg) for _ in range(frames)])
    return SpectMapping.from_views(calibration, pts, volume).analyze()


def read_points(path) -> np.ndarray:
    """Sphere centres (N×3, mm) from a CSV with a header x,y,z or a JSON list of [x, y, z].

    DataError for a missing or unreadable file, a missing column, a non-number or a row that
    is not three numbers.
    """
    import csv
    import json

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: no such file.")
    try:
        text = read_text(path, SMALL, "points file", encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read the points ({exc}).") from None
    if path.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno}).") from None
        except (ValueError, RecursionError) as exc:  # too deep, or a number of thousands of digits
            raise DataError(f"{path}: not usable JSON ({str(exc) or 'nested too deeply'}).") from None
        if isinstance(data, dict) and "points" in data:
            data = data["points"]
        if not isinstance(data, list) or not all(
                isinstance(p, list) and len(p) == 3
                and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in p)
                for p in data):
            raise DataError(f"{path}: expected a JSON list of [x, y, z] points in mm.")
        try:
            pts = np.array(data, dtype=float).reshape(-1, 3)
        except OverflowError:
            raise DataError(f"{path}: a coordinate is too large to be a number of mm.") from None
    else:
        rows = [r for r in csv.reader(text.splitlines()) if any(c.strip() for c in r)]
        if not rows:
            raise DataError(f"{path}: empty; expected a CSV with a header x,y,z (mm).")
        header = [c.strip().lower() for c in rows[0]]
        missing = [k for k in ("x", "y", "z") if k not in header]
        if missing:
            raise DataError(f"{path}: the header {','.join(rows[0])!r} lacks column(s) "
                            f"{','.join(missing)}; expected x,y,z (mm).")
        cols = [header.index(k) for k in ("x", "y", "z")]
        pts_list = []
        for n, row in enumerate(rows[1:], start=2):
            try:
                pts_list.append([float(row[c]) for c in cols])
            except (IndexError, ValueError):
                raise DataError(f"{path}, line {n}: {','.join(row)!r} is not three numbers "
                                "x,y,z.") from None
        pts = np.array(pts_list, dtype=float).reshape(-1, 3)
    if len(pts) == 0:
        raise DataError(f"{path}: no points.")
    if not np.all(np.isfinite(pts)):
        raise DataError(f"{path}: non-finite coordinates.")
    return pts


