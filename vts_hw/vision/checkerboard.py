"""The checkerboard: its corners in an image, its corners in its own plane, image pairs.

:func:`find_corners` finds the inner corners of the board in one grey image (classic
``cv2.findChessboardCorners``, then ``cv2.cornerSubPix``: decision 0012), :func:`board_points`
gives them on the board (z = 0) in the same order, :func:`find_pairs` the ``leftNN``/``rightNN``
images of a folder and :func:`load_gray` an image from a path, naming it when it cannot be read.
The calibration that uses them: :mod:`vts_hw.vision.calibration`.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from vts_hw.errors import DataError

__all__ = ["PATTERN", "ImageOrPath", "board_points", "find_corners", "find_pairs", "load_gray"]

PATTERN = (9, 6)
SUBPIX_WINDOW = (11, 11)
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 30, 1e-3)

ImageOrPath = np.ndarray | str | Path


def find_corners(gray: np.ndarray, pattern: tuple[int, int] = PATTERN) -> np.ndarray | None:
    """Inner corners (N × 1 × 2 float32, row by row) of a `pattern` board, or None if not found.

    A colour image is converted to grey first.
    """
    gray = to_gray(gray)
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
        right = next(
            (p for p in sorted(directory.glob(f"right{m.group(1)}.*")) if p.suffix.lower() == left.suffix.lower()), None
        )
        if right is not None:
            pairs.append((left, right))
    return pairs


def to_gray(img: np.ndarray) -> np.ndarray:
    """A grey image from a grey, BGR or BGRA array."""
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
    if isinstance(src, (str, Path)):
        img = cv2.imread(str(src), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise DataError(f"{src}: cannot be read as an image.")
        return img
    return to_gray(src)
