"""The stereo calibration files written before one calibration record, read as two cameras.

Format ``vts-hw stereo calibration`` (version 1): ``K1, d1, K2, d2, R, T`` (camera 2 from camera 1,
x2 = R x1 + T), the RMS of each camera's own fit and of the pair, the error of each pair of
images, and optionally each camera's lens model and the uncertainty of 0024. :func:`from_stereo_data`
checks every key (DataError naming the file and the key) and gives what
:class:`~vts_hw.vision.calibration_io.CameraCalibration` is made of: cameras ``cam1`` (the frame)
and ``cam2``, each view's errors per camera. Nothing writes this format any more (decision 0056).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vts_hw.errors import DataError
from vts_hw.vision.calibration_uncertainty import check_pair_uncertainty, optional_keys

NAMES = ("cam1", "cam2")
_MATRICES = {"K1": (3, 3), "d1": (None,), "K2": (3, 3), "d2": (None,), "R": (3, 3), "T": (3,)}


def _shown(value: Any) -> str:
    """A value as messages quote it: its repr, cut to 40 characters."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def stereo_fields(path: Path, data: dict[str, Any], units) -> dict[str, Any]:
    """The two-camera record's fields from a stereo file's parsed JSON ``data``, every key
    checked: ``cameras`` (each camera's CameraFit arguments), ``per_view`` ((name, errors per
    camera, outlier) each) and the record's other fields by name."""

    def need(key: str) -> Any:
        if key not in data:
            raise DataError(f"{path}: key '{key}' is missing.")
        return data[key]

    def number(key: str, value: Any = None) -> float:
        value = need(key) if value is None else value
        # abs(v) < 1e300: also False for NaN, inf and a 400-digit JSON integer no float holds
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not abs(value) < 1e300:
            raise DataError(f"{path}: key '{key}' must be a finite number (got {_shown(value)}).")
        return float(value)

    def matrix(key: str) -> np.ndarray:
        value = need(key)
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise DataError(f"{path}: key '{key}' must be a list of numbers.") from None
        want = _MATRICES[key]
        ok = arr.ndim == len(want) and all(w is None or w == s for w, s in zip(want, arr.shape))
        if not ok or arr.size == 0 or not np.all(np.isfinite(arr)):
            shape = " × ".join("n" if w is None else str(w) for w in want)
            raise DataError(f"{path}: key '{key}' must be a {shape} list of finite numbers.")
        return arr

    def int_pair(key: str) -> tuple[int, int]:
        value = need(key)
        if (
            not isinstance(value, list)
            or len(value) != 2
            or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in value)
        ):
            raise DataError(f"{path}: key '{key}' must be two positive integers (got {_shown(value)}).")
        return int(value[0]), int(value[1])

    def text(key: str) -> str:
        value = need(key)
        if not isinstance(value, str):
            raise DataError(f"{path}: key '{key}' must be a string (got {_shown(value)}).")
        return value

    m = {key: matrix(key) for key in _MATRICES}
    size = int_pair("image_size")
    unit = text("unit")
    if unit not in units:
        raise DataError(f"{path}: key 'unit' must be one of {', '.join(units)} (got {unit!r}).")
    views = need("per_view")
    if not isinstance(views, list):
        raise DataError(f"{path}: key 'per_view' must be a list of views.")
    a, b = NAMES
    per_view = []
    for i, v in enumerate(views):
        key = f"per_view[{i}]"
        if not isinstance(v, dict) or not isinstance(v.get("name"), str):
            raise DataError(f"{path}: key '{key}' must have a 'name', 'left' and 'right'.")
        per_view.append(
            (
                v["name"],
                {
                    a: number(f"{key}.left", v.get("left", "missing")),
                    b: number(f"{key}.right", v.get("right", "missing")),
                },
                bool(v.get("outlier", False)),
            )
        )
    skipped = need("skipped")
    if not isinstance(skipped, dict) or not all(isinstance(x, str) for x in skipped.values()):
        raise DataError(f"{path}: key 'skipped' must map view names to reasons.")
    extra = optional_keys(path, data)
    model = extra.get("distortion_model", {})
    unc = extra.get("uncertainty")
    cams = [
        dict(
            name=a,
            K=m["K1"],
            d=m["d1"],
            R=np.eye(3),
            t=np.zeros(3),
            rms=number("rms_left"),
            distortion_model=dict(model.get("camera1", {})),
            sd=dict(unc["camera1"]) if unc else None,
        ),
        dict(
            name=b,
            K=m["K2"],
            d=m["d2"],
            R=m["R"],
            t=m["T"],
            rms=number("rms_right"),
            distortion_model=dict(model.get("camera2", {})),
            sd=dict(unc["camera2"]) if unc else None,
        ),
    ]
    for c in cams:
        c.update(image_size=size, n_views=len(per_view))
    return dict(
        cameras=cams,
        per_view=per_view,
        pattern=int_pair("pattern"),
        square=number("square"),
        unit=unit,
        rms=number("rms_stereo"),
        outlier_rule=text("outlier_rule"),
        skipped=dict(skipped),
        method="stereo calibration file (written before one calibration record)",
        created=text("created"),
        software=text("software"),
        pair=check_pair_uncertainty(path, unc, "uncertainty") if unc else None,
    )
