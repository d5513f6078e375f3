"""Stereo calibration of the two VTS cameras from views of a planar checkerboard.

`find_corners` finds the inner corners of the board in one grey image (classic
cv2.findChessboardCorners, then cv2.cornerSubPix). `calibrate_stereo` calibrates each camera
(cv2.calibrateCamera, with the lens model the data support: `fit_camera`), then the pair's
extrinsics with the intrinsics held fixed (cv2.stereoCalibrateExtended with
CALIB_FIX_INTRINSIC), flags views whose stereo RMS is more than `outlier_factor` × the median
of the views, and gives every parameter's standard deviation
(`vts_hw.vision.calibration_uncertainty.stereo_covariance`). These are the steps of the N-camera
calibration for two cameras (`vts_hw.vision.multi_calibration`, its bundle adjustment run with
the intrinsics fixed and a squared loss, which leaves OpenCV's stereo fit as it is). Choices and
measurements: docs/decisions/0012-stereo-calibration.md, 0024-calibration-uncertainty.md and
0030-n-camera-calibration.md.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np

import vts_hw
from vts_hw.vision.calibration_io import StereoCalibration, ViewError
from vts_hw.vision.calibration_uncertainty import stereo_covariance
from vts_hw.errors import DataError

__all__ = [
    "StereoCalibration",
    "ViewError",
    "board_points",
    "calibrate_from_corners",
    "calibrate_stereo",
    "find_corners",
    "find_pairs",
    "fit_camera",
]

PATTERN = (9, 6)
MIN_PAIRS = 3
OUTLIER_FACTOR = 3.0
SUBPIX_WINDOW = (11, 11)
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)
# Lens models: "opencv" is OpenCV's default (k1, k2, p1, p2, k3); "k1" fits the first radial
# term only. "auto" takes the one with the lower Bayesian information criterion (fit_camera).
DISTORTION = {
    "opencv": (0, ["k1", "k2", "p1", "p2", "k3"]),
    "k1": (cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST, ["k1"]),
}

ImageOrPath = np.ndarray | str | Path


def find_corners(gray: np.ndarray, pattern: tuple[int, int] = PATTERN) -> np.ndarray | None:
    """Inner corners (N × 1 × 2 float32, row by row) of a `pattern` board, or None if not found.

    A colour image is converted to grey first.
    """
    gray = _to_gray(gray)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH + cv2.CALIB_CB_NORMALIZE_IMAGE
    found, corners = cv2.findChessboardCorners(gray, pattern, flags=flags)
    if not found:
        return None
    refined = cv2.cornerSubPix(gray, corners, SUBPIX_WINDOW, (-1, -1), SUBPIX_CRITERIA)
    return refined.reshape(-1, 1, 2)  # OpenCV 5 returns N x 2, OpenCV 4 N x 1 x 2


def board_points(pattern: tuple[int, int] = PATTERN, square: float = 1.0) -> np.ndarray:
    """The board's corners in its own plane (N × 3 float32, z = 0), in the order OpenCV finds them."""
    cols, rows = pattern
    pts = np.zeros((cols * rows, 3), np.float32)
    pts[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square
    return pts


def find_pairs(directory: str | Path) -> list[tuple[Path, Path]]:
    """(leftNN, rightNN) image paths in `directory`, matched by their suffix, sorted by name."""
    directory = Path(directory)
    pattern = re.compile(r"^left(.*)\.(jpe?g|png|bmp|tiff?)$", re.IGNORECASE)
    pairs = []
    for left in sorted(directory.iterdir()):
        m = pattern.match(left.name)
        if not m:
            continue
        right = next((p for p in sorted(directory.glob(f"right{m.group(1)}.*"))
                      if p.suffix.lower() == left.suffix.lower()), None)
        if right is not None:
            pairs.append((left, right))
    return pairs


def calibrate_stereo(
    pairs: Sequence[tuple[ImageOrPath, ImageOrPath]],
    pattern: tuple[int, int] = PATTERN,
    square: float = 1.0,
    unit: str = "squares",
    names: Sequence[str] | None = None,
    distortion: str = "auto",
    outlier_factor: float = OUTLIER_FACTOR,
) -> StereoCalibration:
    """Calibrate a stereo pair of cameras from (left, right) images or image paths.

    Pairs in which either image shows no board are skipped and listed in `skipped`.
    `square` is the side of a square in `unit` ("squares" with square=1 when it is unknown).
    `distortion`: the lens model of each camera, "auto", "k1" or "opencv" (:func:`fit_camera`).
    """
    if names is None:
        names = [_pair_name(i, left, right) for i, (left, right) in enumerate(pairs)]
    if len(names) != len(pairs):
        raise ValueError(f"{len(names)} names for {len(pairs)} pairs")
    left_corners, right_corners, kept, skipped = [], [], [], {}
    image_size = None
    for name, (left, right) in zip(names, pairs):
        gl, gr = _load_gray(left), _load_gray(right)
        for img, src in ((gl, left), (gr, right)):
            size = (img.shape[1], img.shape[0])
            if image_size is None:
                image_size = size
            elif size != image_size:
                raise DataError(f"{_label(src, name)} is {size[0]}x{size[1]} px, the other images"
                                f" are {image_size[0]}x{image_size[1]} px.")
        cl, cr = find_corners(gl, pattern), find_corners(gr, pattern)
        if cl is None or cr is None:
            missing = " and ".join(s for s, c in (("left", cl), ("right", cr)) if c is None)
            skipped[name] = f"no {pattern[0]}x{pattern[1]} board found in the {missing} image"
            continue
        left_corners.append(cl)
        right_corners.append(cr)
        kept.append(name)
    if image_size is None:
        raise DataError("no image pairs given for the stereo calibration.")
    return calibrate_from_corners(left_corners, right_corners, image_size, names=kept,
                                  pattern=pattern, square=square, unit=unit, skipped=skipped,
                                  distortion=distortion, outlier_factor=outlier_factor)


def calibrate_from_corners(
    left_corners: Sequence[np.ndarray],
    right_corners: Sequence[np.ndarray],
    image_size: tuple[int, int],
    names: Sequence[str] | None = None,
    pattern: tuple[int, int] = PATTERN,
    square: float = 1.0,
    unit: str = "squares",
    skipped: dict[str, str] | None = None,
    distortion: str = "auto",
    outlier_factor: float = OUTLIER_FACTOR,
) -> StereoCalibration:
    """The calibration itself, from corners already found (one entry per usable pair)."""
    if unit == "squares" and square != 1.0:
        raise ValueError("with unit 'squares' the square size must be 1")
    n = len(left_corners)
    if n != len(right_corners):
        raise ValueError("left and right corner lists differ in length")
    names = list(names) if names is not None else [f"pair{i + 1:02d}" for i in range(n)]
    skipped = dict(skipped or {})
    if n < MIN_PAIRS:
        raise DataError(f"only {n} pair(s) show the board in both images; the stereo calibration"
                        f" needs at least {MIN_PAIRS}.")
    obj = [board_points(pattern, square)] * n
    left = [np.asarray(c, np.float32).reshape(-1, 1, 2) for c in left_corners]
    right = [np.asarray(c, np.float32).reshape(-1, 1, 2) for c in right_corners]
    # The N-camera calibration's steps for two cameras (vts_hw.vision.multi_calibration): each
    # camera's own fit, the pair's pose with the intrinsics fixed (cv2.stereoCalibrateExtended),
    # and the bundle adjustment with the intrinsics fixed and a plain squared loss, which is the
    # stereo fit itself (decision 0012: every figure traceable to one OpenCV fit).
    from vts_hw.vision import multi_calibration as multi

    keys = [f"{i:06d}" for i in range(n)]
    st = multi.start({"camera1": dict(zip(keys, left)), "camera2": dict(zip(keys, right))},
                     {"camera1": image_size, "camera2": image_size}, pattern, square, distortion)
    problem, sol, obs = multi.adjust(st, intrinsics="fixed", loss="linear")
    own1, own2 = st.own["camera1"], st.own["camera2"]
    rms_l, k1, d1, model1 = own1["rms"], own1["K"], own1["d"], own1["model"]
    rms_r, k2, d2, model2 = own2["rms"], own2["K"], own2["d"], own2["model"]
    _, cpose, vpose = problem.unpack(sol.p)
    rot, t = cv2.Rodrigues(cpose[1, :3])[0], cpose[1, 3:].reshape(3, 1)
    rvecs = [v[:3].reshape(3, 1) for v in vpose]      # board poses in camera 1 = the frame
    tvecs = [v[3:].reshape(3, 1) for v in vpose]
    rms_s = multi._rms(sol.residuals)
    err = np.sqrt(np.mean(np.sum(sol.residuals ** 2, axis=2), axis=1))
    per_view = np.zeros((n, 2))
    for e, (ci, vi) in zip(err, obs):
        per_view[vi, ci] = e
    uncertainty = stereo_covariance(obj, left, right, (k1, d1, model1["fitted"], own1["rvecs"], own1["tvecs"]),
                                    (k2, d2, model2["fitted"], own2["rvecs"], own2["tvecs"]), rot, t, rvecs, tvecs)
    views = flag_outliers(
        [ViewError(name, float(e[0]), float(e[1])) for name, e in zip(names, per_view)],
        outlier_factor,
    )
    return StereoCalibration(
        K1=k1, d1=d1, K2=k2, d2=d2, R=rot, T=t,
        image_size=(int(image_size[0]), int(image_size[1])),
        pattern=(int(pattern[0]), int(pattern[1])),
        square=float(square), unit=unit,
        rms_left=float(rms_l), rms_right=float(rms_r), rms_stereo=float(rms_s),
        per_view=views,
        outlier_rule=f"pair RMS (both images) > {outlier_factor:g} x median of the pairs",
        skipped=skipped,
        distortion_model={"camera1": model1, "camera2": model2},
        uncertainty=uncertainty,
        created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
        software=vts_hw.__version__,
    )


def fit_camera(obj, corners, image_size, distortion: str = "auto"):
    """One camera's intrinsics: (rms, K, d, model, (rvecs, tvecs)) with cv2.calibrateCamera.

    `distortion` "opencv" fits OpenCV's default five coefficients, "k1" only the first radial
    term; "auto" fits both and keeps the one with the lower Bayesian information criterion
    (n ln(RSS/n) + p ln n over the n corner coordinates): a narrow lens whose corners stay near
    the image centre cannot tell k2, k3 and the tangential terms from the principal point and
    k1, and fitting them there moves the principal point by many pixels; a wide lens needs
    them (docs/decisions/0024). `model` says which terms were fitted and why.
    """
    if distortion not in ("auto", *DISTORTION):
        raise ValueError(f"distortion must be 'auto', 'k1' or 'opencv', not {distortion!r}")
    fits = {}
    for name in (("k1", "opencv") if distortion == "auto" else (distortion,)):
        flags, fitted = DISTORTION[name]
        rms, K, d, rvecs, tvecs = cv2.calibrateCamera(obj, corners, image_size, None, None, flags=flags)
        fits[name] = (float(rms), K, d, fitted, (rvecs, tvecs))
    if distortion != "auto":
        rms, K, d, fitted, poses = fits[distortion]
        return rms, K, d, {"fitted": fitted, "chosen_by": f"asked for ({distortion})"}, poses
    n_obs = 2 * sum(len(c) for c in corners)  # coordinates
    bic = {}
    for name, (rms, _, _, fitted, _) in fits.items():
        n_par = 4 + len(fitted) + 6 * len(corners)
        bic[name] = n_obs * math.log(max(rms, 1e-300) ** 2 / 2) + n_par * math.log(n_obs)
    name = "opencv" if bic["opencv"] < bic["k1"] else "k1"
    rms, K, d, fitted, poses = fits[name]
    why = ("its lower residual outweighs 4 more terms" if name == "opencv"
           else "4 more terms do not lower the residual enough")
    return rms, K, d, {
        "fitted": fitted,
        "chosen_by": (f"auto (BIC): RMS {fits['opencv'][0]:.4f} px with k1, k2, p1, p2, k3 vs"
                      f" {fits['k1'][0]:.4f} px with k1 alone, BIC {bic['opencv']:.1f} vs {bic['k1']:.1f}:"
                      f" {why}"),
    }, poses


def flag_outliers(views: list[ViewError], factor: float = OUTLIER_FACTOR) -> list[ViewError]:
    """Copies of `views` with `outlier` set where the pair's RMS exceeds factor × the median."""
    if not views:
        return []
    limit = factor * float(np.median([v.rms for v in views]))
    return [ViewError(v.name, v.left, v.right, v.rms > limit) for v in views]


def _to_gray(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    if img.ndim == 3 and img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.ndim == 3 and img.shape[2] == 4:
        return cv2.cvtColor(img, cv2.COLOR_BGRA2GRAY)
    if img.ndim != 2:
        raise ValueError(f"expected a grey or colour image, got shape {img.shape}")
    return img


def load_gray(src: ImageOrPath) -> np.ndarray:
    """A grey image from a path (DataError naming it if it is not an image) or an array."""
    return _load_gray(src)


def _load_gray(src: ImageOrPath) -> np.ndarray:
    if isinstance(src, (str, Path)):
        img = cv2.imread(str(src), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise DataError(f"{src}: cannot be read as an image.")
        return img
    return _to_gray(src)


def _pair_name(i: int, left: ImageOrPath, right: ImageOrPath) -> str:
    """'01' for left01.jpg/right01.jpg, else 'left-stem/right-stem', else 'pairNN'."""
    if isinstance(left, (str, Path)) and isinstance(right, (str, Path)):
        ls, rs = Path(left).stem, Path(right).stem
        if ls.lower().startswith("left") and rs.lower()[5:] == ls.lower()[4:] and ls[4:]:
            return ls[4:]
        return f"{ls}/{rs}"
    return f"pair{i + 1:02d}"


def _label(src: ImageOrPath, name: str) -> str:
    return str(src) if isinstance(src, (str, Path)) else f"an image of pair {name}"
