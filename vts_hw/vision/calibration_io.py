"""The calibration record and its file; one reader for every calibration file.

:class:`CameraCalibration` holds N ≥ 2 cameras in one frame, the reference camera's (its R is the
identity, its t zero), so that a two-camera calibration means what a stereo one always meant
(the VTS frame is camera 1's). It is what :func:`vts_hw.vision.calibration.calibrate_cameras`
returns, for `vts calibrate cameras` and for `vts calibrate stereo` (two cameras), and what both
write (format ``vts-hw camera calibration``). ``K1, d1, K2, d2, R, T, baseline`` are its first
two cameras as a pair (camera 2 from camera 1), which the pair's comparison and truth use.
:func:`load_calibration` reads every calibration file ever written: the stereo files written
before one record (format ``vts-hw stereo calibration``) load as two cameras
(:mod:`vts_hw.vision.calibration_stereo_file`). Decision 0056. :func:`read_calibration` is the
one loader every reader goes through (the room, tracking, the sync check, the named cameras of
:mod:`vts_hw.vision.camera_set`): it also reads a plain list of named cameras (decision 0099).
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from vts_hw.bounded import SMALL, read_text
from vts_hw.errors import DataError
from vts_hw.files import write_atomic
from vts_hw.vision.calibration_stereo_file import stereo_fields
from vts_hw.vision.calibration_uncertainty import check_pair_uncertainty, rotation_angle_deg
from vts_hw.vision.triangulate import PinholeCamera

FORMAT = "vts-hw camera calibration"
FORMAT_VERSION = 1
STEREO_FORMAT = "vts-hw stereo calibration"  # the two-camera files written before one record
UNITS = ("squares", "mm")


@dataclass(eq=False)
class CameraFit:
    """One calibrated camera: intrinsics ``K``, distortion ``d`` (OpenCV order), pose ``R``, ``t``
    (x_cam = R x + t, x in the calibration's frame, t in its unit), its RMS (px) over the views it saw."""

    name: str
    K: np.ndarray
    d: np.ndarray
    R: np.ndarray
    t: np.ndarray
    image_size: tuple[int, int]
    rms: float = 0.0
    n_views: int = 0
    distortion_model: dict[str, Any] = field(default_factory=dict)
    sd: dict[str, float] | None = None  # standard deviations of the fitted parameters

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, float).reshape(3, 3)
        self.d = np.asarray(self.d, float).ravel()
        self.R = np.asarray(self.R, float).reshape(3, 3)
        self.t = np.asarray(self.t, float).ravel()

    @property
    def dist(self) -> np.ndarray:
        return self.d

    @property
    def center(self) -> np.ndarray:
        return -self.R.T @ self.t

    def project(self, points) -> np.ndarray:
        """Pixels (n × 2) of points (n × 3) in the calibration's frame, distortion included."""
        uv, _ = cv2.projectPoints(
            np.asarray(points, float).reshape(-1, 1, 3), cv2.Rodrigues(self.R)[0], self.t, self.K, self.d
        )
        return uv.reshape(-1, 2)

    def data(self) -> dict[str, Any]:
        out = {
            "name": self.name,
            "image_size": list(self.image_size),
            "K": self.K.tolist(),
            "d": self.d.tolist(),
            "R": self.R.tolist(),
            "t": self.t.tolist(),
            "rms": float(self.rms),
            "views": int(self.n_views),
            "distortion_model": dict(self.distortion_model),
        }
        if self.sd is not None:
            out["sd"] = dict(self.sd)
        return out


@dataclass(frozen=True)
class ViewFit:
    """RMS (px) of one checkerboard view in each camera that saw it."""

    name: str
    errors: dict[str, float]
    outlier: bool = False

    @property
    def rms(self) -> float:
        return math.sqrt(sum(e * e for e in self.errors.values()) / len(self.errors))


@dataclass(eq=False)
class CameraCalibration:
    """N cameras in the reference camera's frame (see the module docstring)."""

    camera_fits: list[CameraFit]
    pattern: tuple[int, int]
    square: float
    unit: str
    rms: float
    per_view: list[ViewFit]
    outlier_rule: str
    view_graph: dict[str, Any] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)
    initial: dict[str, Any] = field(default_factory=dict)  # figures before the bundle adjustment
    adjustment: dict[str, Any] = field(default_factory=dict)  # converged, evaluations, status
    method: str = ""
    created: str = ""
    software: str = ""
    # two cameras whose intrinsics were held fixed (the stereo case): the pair's own uncertainty,
    # propagated through the two OpenCV fits actually run (0024) -- "stereo" (rx, ry, rz in deg,
    # tx, ty, tz, baseline) and "stereo_cov" (6 x 6); None otherwise
    pair: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        if self.unit not in UNITS:
            raise ValueError(f"unit must be one of {UNITS}, not {self.unit!r}")
        if len(self.camera_fits) < 2:
            raise ValueError("a camera calibration needs at least two cameras")

    # ---- its cameras; the first two as a pair (camera 2 from camera 1) ---------------------
    @property
    def names(self) -> list[str]:
        return [c.name for c in self.camera_fits]

    @property
    def reference(self) -> str:
        return self.camera_fits[0].name

    def camera(self, name: str) -> CameraFit:
        for c in self.camera_fits:
            if c.name == name:
                return c
        raise KeyError(name)

    @property
    def K1(self) -> np.ndarray:
        return self.camera_fits[0].K

    @property
    def d1(self) -> np.ndarray:
        return self.camera_fits[0].d

    @property
    def K2(self) -> np.ndarray:
        return self.camera_fits[1].K

    @property
    def d2(self) -> np.ndarray:
        return self.camera_fits[1].d

    @property
    def R(self) -> np.ndarray:
        """Camera 2 from camera 1 (x2 = R x1 + T), as in a stereo file."""
        a, b = self.camera_fits[:2]
        return b.R @ a.R.T

    @property
    def T(self) -> np.ndarray:
        a, b = self.camera_fits[:2]
        return b.t - self.R @ a.t

    @property
    def baseline(self) -> float:
        return float(np.linalg.norm(self.T))

    @property
    def image_size(self) -> tuple[int, int]:
        return self.camera_fits[0].image_size

    @property
    def uncertainty(self) -> dict[str, Any] | None:
        """The pair's uncertainty as 0024 keeps it (each camera's standard deviations as
        ``camera1``/``camera2``, ``stereo``, ``stereo_cov``); None without :attr:`pair`."""
        if self.pair is None:
            return None
        a, b = self.camera_fits[:2]
        return {"camera1": dict(a.sd or {}), "camera2": dict(b.sd or {}), **self.pair}

    @property
    def outliers(self) -> list[str]:
        return [v.name for v in self.per_view if v.outlier]

    def cameras(self, names=None) -> list:
        """Every camera as a :class:`vts_hw.vision.triangulate.PinholeCamera` in the calibration's
        frame, named as calibrated (or by ``names``, in order)."""
        names = list(names) if names is not None else self.names
        return [PinholeCamera(c.K, c.d, c.R, c.t, n) for c, n in zip(self.camera_fits, names)]

    def projection_matrices(self) -> tuple[np.ndarray, np.ndarray]:
        """P1 = K1 [I | 0] and P2 = K2 [R | T] (3 × 4) of the first two cameras, camera 1's frame
        as the reference; they project undistorted pixels (cv2.undistortPoints with P=K first)."""
        p1 = self.K1 @ np.hstack([np.eye(3), np.zeros((3, 1))])
        p2 = self.K2 @ np.hstack([self.R, self.T.reshape(3, 1)])
        return p1, p2

    # ---- reporting --------------------------------------------------------------------
    def results_data(self) -> dict[str, Any]:
        return {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "frame": f"camera {self.reference}'s (x_cam = R x + t)",
            "reference": self.reference,
            "n_cameras": len(self.camera_fits),
            "pattern": list(self.pattern),
            "square": float(self.square),
            "unit": self.unit,
            "cameras": [c.data() for c in self.camera_fits],
            "rms": float(self.rms),
            "per_view": [
                {"name": v.name, "errors": dict(v.errors), "rms": v.rms, "outlier": bool(v.outlier)}
                for v in self.per_view
            ],
            "outlier_rule": self.outlier_rule,
            "outliers": self.outliers,
            "view_graph": self.view_graph,
            "skipped": dict(self.skipped),
            "initial": dict(self.initial),
            "adjustment": dict(self.adjustment),
            "method": self.method,
            "created": self.created,
            "software": self.software,
        } | ({"pair_uncertainty": dict(self.pair)} if self.pair is not None else {})

    def results(self) -> str:
        u = self.unit
        lines = [
            f"Camera calibration: {len(self.camera_fits)} cameras, {len(self.per_view)} views"
            f" (pattern {self.pattern[0]}x{self.pattern[1]}, square {self.square:g} {u}; frame of"
            f" {self.reference}; {self.created}, vts-hw {self.software})",
            f"  RMS reprojection error {self.rms:.3f} px over every corner"
            + (f" (after the pairwise start: {self.initial['rms']:.3f} px)" if "rms" in self.initial else ""),
        ]
        for c in self.camera_fits:
            sd = c.sd or {}
            pm = {n: (f" ± {sd[n]:.2g}" if n in sd else "") for n in ("fx", "fy", "cx", "cy", "k1")}
            pos = c.center
            fitted = c.distortion_model.get("fitted")
            lines.append(
                f"  {c.name}: RMS {c.rms:.3f} px over {c.n_views} views; fx {c.K[0, 0]:.2f}{pm['fx']}"
                f" fy {c.K[1, 1]:.2f}{pm['fy']} cx {c.K[0, 2]:.2f}{pm['cx']} cy {c.K[1, 2]:.2f}{pm['cy']}"
                f" px, k1 {c.d[0]:+.4f}{pm['k1']}; at ({pos[0]:.4g}, {pos[1]:.4g}, {pos[2]:.4g}) {u},"
                f" turned {rotation_angle_deg(c.R):.3f} deg from {self.reference}"
                + (f" (distortion fitted: {', '.join(fitted)})" if fitted else "")
            )
        if self.pair is not None:
            st = self.pair["stereo"]
            lines.append(
                f"  baseline {self.baseline:.4g} ± {st['baseline']:.2g} {u}, rotation between"
                f" {self.names[0]} and {self.names[1]} {rotation_angle_deg(self.R):.3f} deg"
                f" (± {max(st['rx'], st['ry'], st['rz']):.2g} deg about the least certain axis)"
            )
        for v in self.per_view:
            errs = " ".join(f"{k} {e:.3f}" for k, e in v.errors.items())
            lines.append(f"    view {v.name}: {errs} px" + ("  OUTLIER" if v.outlier else ""))
        lines.append(f"  outlier rule: {self.outlier_rule}")
        for name, why in self.skipped.items():
            lines.append(f"  skipped {name}: {why}")
        return "\n".join(lines)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CameraCalibration):
            return NotImplemented
        return self.results_data() == other.results_data()

    # ---- file ------------------------------------------------------------------------
    def text(self) -> str:
        return json.dumps(self.results_data(), indent=2) + "\n"

    def save(self, path: str | Path) -> Path:
        return write_atomic(path, self.text())

    @classmethod
    def load(cls, path: str | Path) -> CameraCalibration:
        """:func:`load_calibration`."""
        return load_calibration(path)


def read_calibration(source):
    """THE calibration loader (issue 34 §1: every reader of a calibration goes through it): a
    calibration (or cameras) given as an object comes back as it is; a path is read once, as a
    calibration file of this format, a stereo file written before one record, or a plain list of
    named cameras (the simulator's true ``cameras.json``: ``{name: PinholeCamera}``). DataError
    naming the file (and the key) for anything else."""
    if source is None or not isinstance(source, (str, os.PathLike)):
        return source
    path = Path(source)
    data = _read_json(path)
    if (
        isinstance(data, dict)
        and data.get("format") not in (FORMAT, STEREO_FORMAT)
        and isinstance(data.get("cameras"), list)
    ):
        return _camera_list(path, data)
    return _calibration(path, data)


def load_calibration(path: str | Path) -> CameraCalibration:
    """The calibration in ``path``: a file of this format, or a stereo file written before one
    record (its cameras named cam1, cam2). DataError naming the file (and the key) for anything
    else (a plain list of cameras among them: :func:`read_calibration` reads that too)."""
    path = Path(path)
    return _calibration(path, _read_json(path))


def _read_json(path: Path):
    try:
        return json.loads(read_text(path, SMALL, "calibration"))
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read the calibration file ({exc}).") from exc
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: not a JSON calibration file ({exc.msg}, line {exc.lineno}).") from None
    except RecursionError:
        raise DataError(f"{path}: not a JSON calibration file (nested too deeply).") from None
    except ValueError as exc:  # a 5000-digit number: "Exceeds the limit (4300 digits) for integer ..."
        raise DataError(f"{path}: not a JSON calibration file ({str(exc).split(':')[0]}).") from None


def _camera_list(path: Path, data: dict) -> dict[str, PinholeCamera]:
    """A plain list of named cameras ``{"cameras": [{"name", "K", "dist", "R", "t"}], "unit"}``."""
    rows = data["cameras"]
    if len(rows) < 2:
        raise DataError(f"{path}: not a calibration (neither a stereo pair nor a list of 2 or more cameras)")
    if data.get("unit", "mm") != "mm":
        raise DataError(f"{path}: the cameras' translations are in {data.get('unit')!r}, not mm")
    out = {}
    for i, row in enumerate(rows):
        try:
            name = str(row.get("name") or f"cam{i + 1}")
            out[name] = PinholeCamera(row["K"], row["dist"], row["R"], row["t"], name)
        except (AttributeError, KeyError, TypeError, ValueError) as exc:
            raise DataError(
                f"{path}: camera {i + 1} is not whole ({type(exc).__name__}: "
                f"{str(exc)[:80]}); each needs name, K, dist, R, t"
            ) from None
    return out


def _calibration(path: Path, data) -> CameraCalibration:
    kind = data.get("format") if isinstance(data, dict) else None
    if kind == STEREO_FORMAT:
        f = stereo_fields(path, data, UNITS)
        fits = [CameraFit(**c) for c in f.pop("cameras")]
        views = [ViewFit(*v) for v in f.pop("per_view")]
        return CameraCalibration(
            fits, f.pop("pattern"), f.pop("square"), f.pop("unit"), f.pop("rms"), views, f.pop("outlier_rule"), **f
        )
    if kind != FORMAT:
        raise DataError(
            f"{path}: key 'format' is neither {FORMAT!r} nor {STEREO_FORMAT!r}, so this is not a calibration file."
        )
    return _from_data(path, data)


def _from_data(path: Path, data: dict[str, Any]) -> CameraCalibration:
    def need(obj, key, where=""):
        if not isinstance(obj, dict) or key not in obj:
            raise DataError(f"{path}: key '{where}{key}' is missing.")
        return obj[key]

    def number(value, key):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not abs(value) < 1e300:
            raise DataError(f"{path}: key '{key}' must be a finite number.")
        return float(value)

    def matrix(value, key, shape):
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError, OverflowError):
            raise DataError(f"{path}: key '{key}' must be a list of numbers.") from None
        if (shape is not None and arr.shape != shape) or arr.size == 0 or not np.all(np.isfinite(arr)):
            raise DataError(
                f"{path}: key '{key}' must be a {' × '.join(map(str, shape or ('n',)))} list of finite numbers."
            )
        return arr

    def pair(value, key):
        if (
            not isinstance(value, list)
            or len(value) != 2
            or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in value)
        ):
            raise DataError(f"{path}: key '{key}' must be two positive integers.")
        return int(value[0]), int(value[1])

    unit = need(data, "unit")
    if unit not in UNITS:
        raise DataError(f"{path}: key 'unit' must be one of {', '.join(UNITS)} (got {unit!r}).")
    cams = need(data, "cameras")
    if not isinstance(cams, list) or len(cams) < 2:
        raise DataError(f"{path}: key 'cameras' must list at least two cameras.")
    fits = []
    for i, c in enumerate(cams):
        w = f"cameras[{i}]."
        name = need(c, "name", w)
        if not isinstance(name, str) or not name:
            raise DataError(f"{path}: key '{w}name' must be a camera name.")
        sd = c.get("sd")
        if sd is not None and (
            not isinstance(sd, dict)
            or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x >= 0
                for x in sd.values()
            )
        ):
            raise DataError(f"{path}: key '{w}sd' must hold finite, non-negative standard deviations.")
        model = c.get("distortion_model", {})
        if not isinstance(model, dict):
            raise DataError(f"{path}: key '{w}distortion_model' must be a mapping.")
        fits.append(
            CameraFit(
                name,
                matrix(need(c, "K", w), w + "K", (3, 3)),
                matrix(need(c, "d", w), w + "d", None),
                matrix(need(c, "R", w), w + "R", (3, 3)),
                matrix(need(c, "t", w), w + "t", (3,)),
                pair(need(c, "image_size", w), w + "image_size"),
                number(need(c, "rms", w), w + "rms"),
                int(number(c.get("views", 0), w + "views")),
                model,
                sd,
            )
        )
    if len({f.name for f in fits}) != len(fits):
        raise DataError(f"{path}: key 'cameras' names a camera twice.")
    views = need(data, "per_view")
    if not isinstance(views, list):
        raise DataError(f"{path}: key 'per_view' must be a list of views.")
    per_view = []
    for i, v in enumerate(views):
        errs = need(v, "errors", f"per_view[{i}].")
        if not isinstance(v.get("name"), str) or not isinstance(errs, dict) or not errs:
            raise DataError(f"{path}: key 'per_view[{i}]' must have a 'name' and 'errors' per camera.")
        per_view.append(
            ViewFit(
                v["name"],
                {k: number(e, f"per_view[{i}].errors.{k}") for k, e in errs.items()},
                bool(v.get("outlier", False)),
            )
        )
    texts = {}
    for key in ("outlier_rule", "created", "software"):
        texts[key] = need(data, key)
        if not isinstance(texts[key], str):
            raise DataError(f"{path}: key '{key}' must be a string.")
    skipped = data.get("skipped", {})
    if not isinstance(skipped, dict):
        raise DataError(f"{path}: key 'skipped' must map views to reasons.")
    return CameraCalibration(
        fits,
        pair(need(data, "pattern"), "pattern"),
        number(need(data, "square"), "square"),
        unit,
        number(need(data, "rms"), "rms"),
        per_view,
        texts["outlier_rule"],
        view_graph=data.get("view_graph") or {},
        skipped=dict(skipped),
        initial=data.get("initial") or {},
        adjustment=a if isinstance(a := data.get("adjustment"), dict) else {},
        method=str(data.get("method", "")),
        created=texts["created"],
        software=texts["software"],
        pair=check_pair_uncertainty(path, data.get("pair_uncertainty"), "pair_uncertainty"),
    )
