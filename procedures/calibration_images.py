"""Which checkerboard image is which camera and which view, and the corners in them.

:func:`camera_images` reads the names `vts calibrate cameras` takes (``<camera>_<view>.<ext>``,
one folder per camera, or the stereo ``leftNN``/``rightNN``), :func:`image_pairs` the
``leftNN``/``rightNN`` pairs `vts calibrate stereo` takes, :func:`find_all_corners` the board in
each image (:func:`vts_hw.vision.checkerboard.find_corners`).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from vts_hw.errors import DataError
from vts_hw.vision.checkerboard import find_corners, find_pairs, load_gray

IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff"}
_NAMED = re.compile(r"^(?P<camera>.+)_(?P<view>[^_]+)$")
_STEREO = re.compile(r"^(?P<camera>left|right)(?P<view>.+)$", re.IGNORECASE)
_IMAGE = re.compile(r"^(left|right)(.*)\.(jpe?g|png|bmp|tiff?)$", re.IGNORECASE)


def _images_in(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def _camera_and_view(path: Path) -> tuple[str, str] | None:
    m = _STEREO.match(path.stem) or _NAMED.match(path.stem)
    return (m.group("camera").lower() if m.re is _STEREO else m.group("camera"), m.group("view")) if m else None


def camera_images(args: list[str]) -> dict[str, dict[str, Path]]:
    """camera → view → image path, from files and folders (see ``vts calibrate cameras --help``):

    * a file ``<camera>_<view>.<ext>`` (the camera is the name before the last ``_``), or the
      stereo names ``leftNN`` / ``rightNN`` (cameras ``left``, ``right``);
    * a folder of such files;
    * a folder of folders, one per camera (named after it), each image named after its view;
    * a folder of images without ``_`` in their names is one camera's (named after the folder).

    DataError for a missing path, a name that says no camera, a view given twice, or no images.
    """
    out: dict[str, dict[str, Path]] = {}

    def add(camera: str, view: str, path: Path) -> None:
        views = out.setdefault(camera, {})
        if view in views:
            raise DataError(f"{path} and {views[view]} are both view {view!r} of camera {camera!r}.")
        views[view] = path

    for arg in args:
        path = Path(arg)
        if not path.exists():
            raise DataError(f"{path}: no such file or directory.")
        if path.is_file():
            cv = _camera_and_view(path)
            if cv is None or path.suffix.lower() not in IMAGE_SUFFIXES:
                raise DataError(
                    f"{path}: image names must be <camera>_<view>.jpg (or .png), or the images"
                    " of each camera in a folder named after it."
                )
            add(*cv, path)
            continue
        if not path.is_dir():  # a device, a FIFO, a socket
            raise DataError(f"{path}: not an image file or a folder of images.")
        subdirs = sorted(p for p in path.iterdir() if p.is_dir() and _images_in(p))
        if subdirs:
            for sub in subdirs:
                for img in _images_in(sub):
                    add(sub.name, img.stem, img)
            continue
        images = _images_in(path)
        named = [(img, cv) for img in images if (cv := _camera_and_view(img)) is not None]
        if images and len(named) == len(images):
            for img, (camera, view) in named:
                add(camera, view, img)
        else:
            for img in images:
                add(path.name, img.stem, img)
    if not out:
        raise DataError("no images given: name them <camera>_<view>.jpg, or give one folder per camera.")
    return out


def find_all_corners(images, pattern) -> tuple[dict, dict, dict]:
    """(corners: camera → view → corners, image size per camera, skipped: "camera/view" → why)
    of images (paths or grey arrays)."""
    corners: dict[str, dict[str, np.ndarray]] = {}
    sizes: dict[str, tuple[int, int]] = {}
    skipped: dict[str, str] = {}
    for cam, views in images.items():
        corners[cam] = {}
        for view, src in views.items():
            gray = load_gray(src)
            size = (gray.shape[1], gray.shape[0])
            if sizes.setdefault(cam, size) != size:
                raise DataError(
                    f"{src if isinstance(src, (str, Path)) else f'camera {cam}, view {view}'} is"
                    f" {size[0]}x{size[1]} px, the other images of camera {cam} are"
                    f" {sizes[cam][0]}x{sizes[cam][1]} px."
                )
            found = find_corners(gray, pattern)
            if found is None:
                skipped[f"{cam}/{view}"] = f"no {pattern[0]}x{pattern[1]} board found"
            else:
                corners[cam][view] = found
    return corners, sizes, skipped


def image_pairs(args: list[str]) -> list[tuple[Path, Path]]:
    """(left, right) image paths from directories and/or files named leftNN / rightNN.

    A directory gives its pairs (:func:`vts_hw.vision.checkerboard.find_pairs`); files are paired by
    what follows 'left' / 'right' in their names. DataError for a missing file, a file not
    named left* or right*, an unmatched image, or no pair at all.
    """
    pairs: list[tuple[Path, Path]] = []
    files: dict[str, dict[str, Path]] = {"left": {}, "right": {}}
    for arg in args:
        path = Path(arg)
        if path.is_dir():
            found = find_pairs(path)
            if not found:
                raise DataError(f"{path}: no leftNN/rightNN image pairs in this directory.")
            pairs.extend(found)
            continue
        if not path.exists():
            raise DataError(f"{path}: no such file or directory.")
        m = _IMAGE.match(path.name)
        if not m:
            raise DataError(
                f"{path}: image names must be leftNN.jpg / rightNN.jpg (or .png) so that left and right can be paired."
            )
        side, key = m.group(1).lower(), m.group(2).lower()
        if key in files[side]:
            raise DataError(f"{path} and {files[side][key]} are both {side} image {key!r}.")
        files[side][key] = path
    for side, other in (("left", "right"), ("right", "left")):
        for key, path in files[side].items():
            if key not in files[other]:
                raise DataError(f"{path} has no matching {other} image ({other}{key}.*).")
    pairs.extend((files["left"][k], files["right"][k]) for k in sorted(files["left"]))
    if not pairs:
        raise DataError("no image pairs given: name leftNN/rightNN images or a directory of them.")
    return pairs
