"""The stereo calibration record: its numbers, its text summary, its JSON file, its comparison.

`StereoCalibration` is what `vts_hw.vision.calibration.calibrate_stereo` returns. It is saved as JSON
with every matrix written as nested lists, so the file can be read and diffed by hand. Loading
checks every key; a missing or malformed one raises `DataError` naming the file and the key.
"""

from __future__ import annotations

import copy
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vts_hw.bounded import SMALL, read_text
from vts_hw.vision.calibration_uncertainty import beyond, differences, optional_keys, warning_text
from vts_hw.errors import DataError
from vts_hw.files import write_atomic

FORMAT = "vts-hw stereo calibration"
FORMAT_VERSION = 1
UNITS = ("squares", "mm")

# (key, shape) of the matrices kept in the file; None in a shape means "any length".
_MATRICES = {
    "K1": (3, 3),
    "d1": (None,),
    "K2": (3, 3),
    "d2": (None,),
    "R": (3, 3),
    "T": (3,),
}


@dataclass(frozen=True)
class ViewError:
    """RMS reprojection error (px) of one stereo pair in the stereo fit, per camera."""

    name: str
    left: float
    right: float
    outlier: bool = False

    @property
    def rms(self) -> float:
        """The pair's RMS over both images (the figure the outlier rule uses)."""
        return math.sqrt((self.left**2 + self.right**2) / 2.0)


@dataclass(eq=False)
class StereoCalibration:
    """Intrinsics, distortion and extrinsics of a stereo pair of cameras.

    `R`, `T` take a point from camera 1's frame to camera 2's (OpenCV: x2 = R x1 + T); `T` is in
    `unit` ("squares" when the square size is unknown, else "mm"). RMS figures are in pixels.
    """

    K1: np.ndarray
    d1: np.ndarray
    K2: np.ndarray
    d2: np.ndarray
    R: np.ndarray
    T: np.ndarray
    image_size: tuple[int, int]  # (width, height) in px
    pattern: tuple[int, int]  # inner corners (columns, rows)
    square: float
    unit: str
    rms_left: float
    rms_right: float
    rms_stereo: float
    per_view: list[ViewError]
    outlier_rule: str
    skipped: dict[str, str] = field(default_factory=dict)  # view name -> why it was left out
    created: str = ""  # UTC ISO 8601
    software: str = ""  # vts_hw.__version__
    # camera1/camera2 -> {"fitted": [distortion terms], "chosen_by": why}; {} in older files
    distortion_model: dict[str, Any] = field(default_factory=dict)
    # standard deviations (vts_hw.vision.calibration_uncertainty.stereo_covariance); None in older files
    uncertainty: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        for key in _MATRICES:
            shape = (-1,) if _MATRICES[key] == (None,) else _MATRICES[key]
            setattr(self, key, np.asarray(getattr(self, key), dtype=float).reshape(shape))
        if self.unit not in UNITS:
            raise ValueError(f"unit must be one of {UNITS}, not {self.unit!r}")

    # ---- derived figures -------------------------------------------------------------
    @property
    def baseline(self) -> float:
        """Distance between the two optical centres, |T|, in `unit`."""
        return float(np.linalg.norm(self.T))

    @property
    def outliers(self) -> list[str]:
        """Names of the views flagged by the outlier rule."""
        return [v.name for v in self.per_view if v.outlier]

    def projection_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """P1 = K1 [I | 0] and P2 = K2 [R | T] (3 × 4), camera 1's frame as the reference.

        They project undistorted pixel coordinates: undistort the measured points first
        (cv2.undistortPoints with P=K), then cv2.triangulatePoints gives points in `unit`.
        """
        p1 = self.K1 @ np.hstack([np.eye(3), np.zeros((3, 1))])
        p2 = self.K2 @ np.hstack([self.R, self.T.reshape(3, 1)])
        return p1, p2

    def cameras(self, names=("left", "right")) -> list:
        """The pair as :class:`vts_hw.vision.triangulate.Camera` objects in camera 1's frame (the VTS
        frame): camera 1 at the origin, camera 2 at ``R``, ``T`` (in ``unit``)."""
        return stereo_cameras(self, names)

    # ---- comparison ------------------------------------------------------------------
    def compare(self, previous: StereoCalibration) -> dict[str, Any]:
        """Change from `previous` to this calibration (this minus previous).

        Focal lengths and principal points in px per camera; `rotation_deg` is the angle of
        the rotation R · R_prevᵀ; `translation` is |T − T_prev| and `baseline` the change of
        |T|, both in `unit` (None when the two calibrations use different units). `judged`: each
        fitted parameter's change against its combined standard deviation, and `warnings` one
        line for each beyond K_SIGMA of them (vts_hw.vision.calibration_uncertainty.differences).
        """
        out: dict[str, Any] = {}
        for cam, (k_new, k_old) in (("1", (self.K1, previous.K1)), ("2", (self.K2, previous.K2))):
            out[f"fx{cam}"] = float(k_new[0, 0] - k_old[0, 0])
            out[f"fy{cam}"] = float(k_new[1, 1] - k_old[1, 1])
            out[f"cx{cam}"] = float(k_new[0, 2] - k_old[0, 2])
            out[f"cy{cam}"] = float(k_new[1, 2] - k_old[1, 2])
        out["rotation_deg"] = rotation_angle_deg(self.R @ previous.R.T)
        same_unit = self.unit == previous.unit
        out["translation"] = float(np.linalg.norm(self.T - previous.T)) if same_unit else None
        out["baseline"] = (self.baseline - previous.baseline) if same_unit else None
        out["unit"] = self.unit if same_unit else None
        rows = differences(self, previous, self.uncertainty, previous.uncertainty, same_unit)
        out["judged"] = rows
        out["previous_has_uncertainty"] = previous.uncertainty is not None
        out["warnings"] = [warning_text(r, "moved") for r in beyond(rows)]
        return out

    # ---- reporting -------------------------------------------------------------------
    def results_data(self) -> dict[str, Any]:
        """Everything as JSON-ready types (matrices as nested lists of floats)."""
        data: dict[str, Any] = {"format": FORMAT, "format_version": FORMAT_VERSION}
        for key in _MATRICES:
            data[key] = getattr(self, key).tolist()
        data.update(
            image_size=list(self.image_size),
            pattern=list(self.pattern),
            square=float(self.square),
            unit=self.unit,
            baseline=self.baseline,
            rms_left=float(self.rms_left),
            rms_right=float(self.rms_right),
            rms_stereo=float(self.rms_stereo),
            per_view=[
                {"name": v.name, "left": float(v.left), "right": float(v.right),
                 "outlier": bool(v.outlier)}
                for v in self.per_view
            ],
            outlier_rule=self.outlier_rule,
            outliers=self.outliers,
            skipped=dict(self.skipped),
            created=self.created,
            software=self.software,
        )
        if self.distortion_model:
            data["distortion_model"] = copy.deepcopy(self.distortion_model)
        if self.uncertainty is not None:
            data["uncertainty"] = copy.deepcopy(self.uncertainty)
        return data

    def results(self) -> str:
        """A short text summary for a terminal or a log."""
        u = self.unit
        lines = [
            f"Stereo calibration ({len(self.per_view)} pairs, pattern {self.pattern[0]}x"
            f"{self.pattern[1]}, square {self.square:g} {u}, image {self.image_size[0]}x"
            f"{self.image_size[1]} px; {self.created}, vts-hw {self.software})",
            f"  RMS reprojection error: left {self.rms_left:.3f} px, right {self.rms_right:.3f} px,"
            f" stereo {self.rms_stereo:.3f} px",
        ]
        unc = self.uncertainty or {}
        for cam, k, d in (("1", self.K1, self.d1), ("2", self.K2, self.d2)):
            sd = unc.get(f"camera{cam}", {})
            pm = {n: (f" ± {sd[n]:.2g}" if n in sd else "") for n in ("fx", "fy", "cx", "cy", "k1")}
            fitted = self.distortion_model.get(f"camera{cam}", {}).get("fitted")
            lines.append(f"  camera {cam}: fx {k[0, 0]:.2f}{pm['fx']} fy {k[1, 1]:.2f}{pm['fy']}"
                         f" cx {k[0, 2]:.2f}{pm['cx']} cy {k[1, 2]:.2f}{pm['cy']} px, k1 {d[0]:+.4f}"
                         f"{pm['k1']}" + (f" (distortion fitted: {', '.join(fitted)})" if fitted else ""))
        angle = rotation_angle_deg(self.R)
        st = unc.get("stereo", {})
        b_sd = f" ± {st['baseline']:.2g}" if "baseline" in st else ""
        lines.append(f"  baseline {self.baseline:.4g}{b_sd} {u}, rotation between cameras {angle:.3f} deg"
                     + (f" (± {max(st['rx'], st['ry'], st['rz']):.2g} deg about the least certain axis)"
                        if "rx" in st else ""))
        for v in self.per_view:
            flag = "  OUTLIER" if v.outlier else ""
            lines.append(f"    {v.name}: left {v.left:.3f} right {v.right:.3f} px{flag}")
        lines.append(f"  outlier rule: {self.outlier_rule}")
        for name, why in self.skipped.items():
            lines.append(f"  skipped {name}: {why}")
        return "\n".join(lines)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, StereoCalibration):
            return NotImplemented
        return self.results_data() == other.results_data()

    # ---- file ------------------------------------------------------------------------
    def text(self) -> str:
        """The file's JSON text."""
        return json.dumps(self.results_data(), indent=2) + "\n"

    def save(self, path: str | Path) -> Path:
        """Write the calibration as JSON, whole or not at all (vts_hw.files.write_atomic:
        WriteFailed naming the file, the previous version unchanged)."""
        return write_atomic(path, self.text())

    @classmethod
    def load(cls, path: str | Path) -> StereoCalibration:
        """Read a file written by `save`; DataError (naming the file and key) if it is not one."""
        path = Path(path)
        try:
            text = read_text(path, SMALL, "calibration")
        except (OSError, UnicodeDecodeError) as exc:
            raise DataError(f"{path}: cannot read the calibration file ({exc}).") from exc
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise DataError(f"{path}: not a JSON calibration file ({exc.msg}, line {exc.lineno}).")
        except (ValueError, RecursionError) as exc:  # a 5000-digit number, arrays nested 1000 deep
            raise DataError(f"{path}: not a JSON calibration file ({_json_trouble(exc)}).") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise DataError(f"{path}: key 'format' is not {FORMAT!r}, so this is not a stereo"
                            " calibration file.")
        return _from_data(path, data)


def _shown(value: Any) -> str:
    """A value as messages quote it: its repr, cut to 40 characters."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _json_trouble(exc: Exception) -> str:
    """What json.loads found beyond a syntax error, in words."""
    if isinstance(exc, RecursionError):
        return "nested too deeply"
    return str(exc).split(":")[0]  # "Exceeds the limit (4300 digits) for integer string conversion"


def stereo_cameras(calib, names=("left", "right")) -> list:
    """:meth:`StereoCalibration.cameras` of any object with ``K1, d1, K2, d2, R, T``."""
    from vts_hw.vision.triangulate import Camera
    a, b = names[:2]
    return [Camera(calib.K1, calib.d1, np.eye(3), np.zeros(3), a),
            Camera(calib.K2, calib.d2, calib.R, np.ravel(calib.T), b)]


def rotation_angle_deg(rot: np.ndarray) -> float:
    """Angle (degrees) of a rotation matrix, from its Rodrigues vector (precise for small angles)."""
    vec, _ = cv2.Rodrigues(np.asarray(rot, dtype=float))
    return float(np.degrees(np.linalg.norm(vec)))


def _from_data(path: Path, data: dict[str, Any]) -> StereoCalibration:
    """Build a StereoCalibration from parsed JSON, checking each key."""

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
        if (not isinstance(value, list) or len(value) != 2
                or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in value)):
            raise DataError(f"{path}: key '{key}' must be two positive integers (got {_shown(value)}).")
        return int(value[0]), int(value[1])

    def text(key: str) -> str:
        value = need(key)
        if not isinstance(value, str):
            raise DataError(f"{path}: key '{key}' must be a string (got {_shown(value)}).")
        return value

    mats = {key: matrix(key) for key in _MATRICES}
    unit = text("unit")
    if unit not in UNITS:
        raise DataError(f"{path}: key 'unit' must be one of {', '.join(UNITS)} (got {unit!r}).")
    views = need("per_view")
    if not isinstance(views, list):
        raise DataError(f"{path}: key 'per_view' must be a list of views.")
    per_view = []
    for i, v in enumerate(views):
        key = f"per_view[{i}]"
        if not isinstance(v, dict) or not isinstance(v.get("name"), str):
            raise DataError(f"{path}: key '{key}' must have a 'name', 'left' and 'right'.")
        per_view.append(ViewError(
            name=v["name"],
            left=number(f"{key}.left", v.get("left", "missing")),
            right=number(f"{key}.right", v.get("right", "missing")),
            outlier=bool(v.get("outlier", False)),
        ))
    skipped = need("skipped")
    if not isinstance(skipped, dict) or not all(isinstance(x, str) for x in skipped.values()):
        raise DataError(f"{path}: key 'skipped' must map view names to reasons.")
    return StereoCalibration(
        **mats,
        image_size=int_pair("image_size"),
        pattern=int_pair("pattern"),
        square=number("square"),
        unit=unit,
        rms_left=number("rms_left"),
        rms_right=number("rms_right"),
        rms_stereo=number("rms_stereo"),
        per_view=per_view,
        outlier_rule=text("outlier_rule"),
        skipped=dict(skipped),
        created=text("created"),
        software=text("software"),
        **optional_keys(path, data),
    )
