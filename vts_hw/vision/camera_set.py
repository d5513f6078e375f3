"""Calibrated cameras by name, whatever holds them: the one small interface N-camera code reads.

Tracking, processing and the QA procedures need only a list of named cameras, each with
``K``, ``dist``, ``R``, ``t`` in one world frame (mm). :func:`named_cameras` makes that
``{name: Camera}`` from any of:

* a dict ``name -> camera-like`` (anything with ``K, dist, R, t``: a scene ``CameraModel``, a
  :class:`~vts_hw.vision.triangulate.PinholeCamera`, a calibration's camera);
* a list of camera-likes with names (``.name``), else named like the recording's cameras;
* a calibration (:class:`~vts_hw.vision.calibration_io.CameraCalibration`, any number of cameras;
  the world is its reference camera's frame), or anything with ``cameras`` -- a dict, a list of
  named cameras, or a method returning one.

:func:`load_cameras` reads a calibration file through the one loader
(:func:`~vts_hw.vision.calibration_io.read_calibration`: every calibration file ever written, or
any JSON with a ``cameras`` list of ``{"name", "K", "dist", "R", "t"}``, ``unit`` mm when given).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vts_hw.errors import DataError
from vts_hw.vision.calibration_io import read_calibration
from vts_hw.vision.triangulate import PinholeCamera, as_camera

__all__ = ["named_cameras", "load_cameras", "covered_names"]


def _check_unit(obj: Any) -> None:
    unit = getattr(obj, "unit", "mm")
    if unit != "mm":
        raise DataError(
            f"the calibration's translation is in {unit!r}, not mm: calibrate with the "
            "checkerboard's square size to get positions in mm"
        )


def named_cameras(obj: Any, available: Sequence[str] = ()) -> dict[str, PinholeCamera]:
    """``{name: Camera}`` from any form above. ``available``: the names to give cameras that
    have none (a calibration's cameras named after its images or a stereo file's cam1, cam2 when
    they are not the rig's; an unnamed list), in order."""
    available = list(available)
    if isinstance(obj, dict):
        return {str(k): _named(v, str(k)) for k, v in obj.items()}
    if hasattr(obj, "camera_fits"):  # a calibration (calibration_io): every camera
        _check_unit(obj)
        fits = list(obj.camera_fits)
        names = [c.name for c in fits]
        unnamed = str(getattr(obj, "method", "")).startswith("stereo calibration file")  # cam1, cam2 by position
        if available and (unnamed or not set(names) <= set(available)):  # the recording's names, in order
            names = (available + names[len(available) :])[: len(fits)]
        return {n: PinholeCamera(c.K, c.d, c.R, c.t, n) for n, c in zip(names, fits)}
    if hasattr(obj, "cameras") and not isinstance(obj, (list, tuple)):
        _check_unit(obj)
        cams = obj.cameras() if callable(obj.cameras) else obj.cameras
        return named_cameras(cams, available)
    cams = [as_camera(c) for c in obj]
    names = [c.name for c in cams]
    if not all(names) or len(set(names)) != len(names):
        names = (available + [f"cam{i + 1}" for i in range(len(cams))][len(available) :])[: len(cams)]
    return {n: _named(c, n) for n, c in zip(names, cams)}


def covered_names(calibration: Any, rig_names: Sequence[str]) -> list[str]:
    """The rig's cameras (names, in the rig's order) that ``calibration`` calibrated: those it
    names when it names only rig cameras, else the first as many as it holds (a stereo file, an
    N-camera file named after its images)."""
    own = list(named_cameras(calibration))
    rig_names = list(rig_names)
    if set(own) <= set(rig_names):
        return [n for n in rig_names if n in own]
    return rig_names[: len(own)]


def in_rig_names(cameras: dict, rig_names: Sequence[str]) -> dict[str, PinholeCamera]:
    """``cameras`` (``{name: camera}``, e.g. :func:`load_cameras`) named as the rig's: unchanged
    when they name only rig cameras, else the rig's first names in order (a stereo file's cam1,
    cam2; an N-camera file named after its images), as :func:`covered_names` counts them."""
    own = list(cameras)
    if not rig_names or set(own) <= set(rig_names):
        return dict(cameras)
    return {r: _named(cameras[o], r) for r, o in zip(covered_names(cameras, rig_names), own)}


def _named(cam: Any, name: str) -> PinholeCamera:
    c = as_camera(cam)
    return c if c.name == name else PinholeCamera(c.K, c.dist, c.R, c.t, name)


def load_cameras(path) -> dict[str, PinholeCamera]:
    """The named cameras of a calibration file (stereo, N-camera, or a plain list of cameras),
    read by the one loader (:func:`~vts_hw.vision.calibration_io.read_calibration`);
    :class:`DataError` naming the file when it is none of them."""
    return named_cameras(read_calibration(Path(path)))
