"""The N-camera calibration as a procedure: checkerboard images of N cameras in, one calibration
of all of them in one frame saved.

:func:`camera_images` finds which camera and which view each image is (``<camera>_<view>.<ext>``,
one folder per camera, or the stereo ``leftNN``/``rightNN``); :func:`run` finds the corners,
calibrates (:func:`vts_hw.vision.multi_calibration.calibrate_cameras`), compares with the
previous calibration (the ``-o`` file if there is one) and, for simulated views, with the truth,
and saves it so that a full disk cannot lose it. The :class:`CamerasRun` it returns prints
itself and gives its JSON; a failed write is in ``saved.error`` for the caller to raise after
showing the figures. See docs/decisions/0030-n-camera-calibration.md.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vts_hw.errors import DataError, UsageError
from vts_hw.procedures.calibration_result import CAMERAS_PROCEDURE, CalibrationResult
from vts_hw.save_or_keep import Saved, save_or_keep
from vts_hw.vision.calibration import find_corners, load_gray
from vts_hw.vision.calibration_uncertainty import K_SIGMA
from vts_hw.vision.multi_calibration import calibrate_cameras
from vts_hw.vision.multi_calibration_io import CameraCalibration, load_calibration
from vts_hw.vision.multi_compare import compare_cameras

MAX_RMS_PX = 1.0   # a checkerboard fit above this overall RMS is not trusted (corner noise: 0.05-0.5 px)
IMAGE_SUFFIXES = {".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff"}
_NAMED = re.compile(r"^(?P<camera>.+)_(?P<view>[^_]+)$")
_STEREO = re.compile(r"^(?P<camera>left|right)(?P<view>.+)$", re.IGNORECASE)


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
                raise DataError(f"{path}: image names must be <camera>_<view>.jpg (or .png), or the images"
                                " of each camera in a folder named after it.")
            add(*cv, path)
            continue
        if not path.is_dir():   # a device, a FIFO, a socket
            raise DataError(f"{path}: not an image file or a folder of images.")
        subdirs = sorted(p for p in path.iterdir() if p.is_dir() and _images_in(p))
        if subdirs:
            for sub in subdirs:
                for img in _images_in(sub):
                    add(sub.name, img.stem, img)
            continue
        images = _images_in(path)
        named = [(img, _camera_and_view(img)) for img in images]
        if images and all(cv is not None for _, cv in named):
            for img, cv in named:
                add(*cv, img)
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
                raise DataError(f"{src if isinstance(src, (str, Path)) else f'camera {cam}, view {view}'} is"
                                f" {size[0]}x{size[1]} px, the other images of camera {cam} are"
                                f" {sizes[cam][0]}x{sizes[cam][1]} px.")
            found = find_corners(gray, pattern)
            if found is None:
                skipped[f"{cam}/{view}"] = f"no {pattern[0]}x{pattern[1]} board found"
            else:
                corners[cam][view] = found
    return corners, sizes, skipped


def replaceable(out_path: Path, unit: str, force: bool = False, what: str = "calibration"):
    """The calibration now in ``out_path`` (None if there is no file), once it is clear that a
    new one in ``unit`` may replace it (decision 0024): UsageError (exit 2) for an mm
    calibration about to be replaced by one in squares (a forgotten --square), DataError
    (exit 3) for a file that is not a calibration (``what`` names the kind in the message);
    ``force`` replaces either."""
    if not out_path.exists():
        return None
    try:
        old = load_calibration(out_path)
    except DataError:
        if force:
            return None
        raise DataError(f"{out_path} exists and is not a {what} file; give another -o, move it"
                        " away, or give --force to replace it.") from None
    if old.unit == "mm" and unit == "squares" and not force:
        raise UsageError(f"{out_path} holds a calibration in mm (squares of {old.square:g} mm) and this one"
                         " would be in squares because --square was not given: give --square with the side"
                         " of a square in mm, another -o, or --force to replace it.")
    return old


def fit_warnings(calib: CameraCalibration) -> list[str]:
    """WARNING lines for a fit that cannot be trusted: a bundle adjustment that stopped before it
    converged, or an overall RMS above ``MAX_RMS_PX``."""
    out = []
    adj = calib.adjustment
    if adj and not adj.get("converged", True):
        out.append(f"WARNING: the bundle adjustment did not converge ({adj.get('evaluations')} evaluations:"
                   f" {adj.get('status')}).")
    if calib.rms > MAX_RMS_PX:
        out.append(f"WARNING: RMS reprojection error {calib.rms:.3f} px is above the {MAX_RMS_PX:g} px a"
                   " checkerboard calibration reaches: views that do not fit, or too few views per camera.")
    return out


@dataclass
class CamerasRun(CalibrationResult):
    """A computed N-camera calibration, how it compares, and where it was saved; as a QA result
    (procedure ``calibration_cameras``) the RMS of each camera and of the set, and whether the
    bundle adjustment converged."""

    procedure = CAMERAS_PROCEDURE

    calib: CameraCalibration
    saved: Saved
    previous_path: Path | None = None
    change: dict[str, Any] | None = None
    truth: dict[str, Any] | None = None
    sim: dict[str, Any] | None = None

    def rms_figures(self):
        c = self.calib
        return ({f.name: f.rms for f in c.camera_fits}, c.rms,
                bool((c.adjustment or {}).get("converged", True)))

    @property
    def untrusted(self) -> list[str]:
        """The fit's own warnings (:func:`fit_warnings`): not written over -o without --force."""
        return fit_warnings(self.calib)

    @property
    def warnings(self) -> list[str]:
        return self.untrusted + (list(self.truth["warnings"]) if self.truth else []) + (
            list(self.change["warnings"]) if self.change else [])

    @property
    def refused(self) -> str | None:
        """Why the calibration was not written (an untrusted fit without --force), else None."""
        if not self.untrusted or self.saved.written or self.saved.error is not None:
            return None
        why = self.untrusted[0].removeprefix("WARNING: ").rstrip(".")
        return f"{self.saved.path} was not written, the fit cannot be trusted: {why}; give --force to write it anyway."

    def results_data(self) -> dict[str, Any]:
        data = self.calib.results_data()
        data.update(self.saved.data())
        if self.change is not None:
            data["change"] = dict(self.change, previous=str(self.previous_path))
        if self.truth is not None:
            data["sim_truth"] = self.truth
        if self.sim is not None:
            data["sim"] = self.sim
        data["warnings"] = self.warnings
        return data

    def results(self) -> str:
        g = self.calib.view_graph
        lines = [self.calib.results(), "View graph: " + ("connected" if g.get("connected") else "NOT connected")]
        for cam, views in g.get("cameras", {}).items():
            lines.append(f"  {cam}: {', '.join(views)}")
        lines += [f"  {e['cameras'][0]} - {e['cameras'][1]}: {e['shared_views']} shared view(s)"
                  for e in g.get("edges", [])]
        if self.truth is not None:
            lines.append(truth_text(self.truth))
        if self.change is not None:
            lines.append(change_text(self.change, self.previous_path))
        if self.saved.written:
            lines.append(f"wrote {self.saved.written}")
        lines += [f"  {w}" for w in self.untrusted]
        if self.refused:
            lines.append(f"NOT SAVED: {self.refused}")
        elif self.untrusted:
            lines.append(f"{len(self.warnings)} warning(s); the fit cannot be trusted but --force wrote it.")
        elif self.warnings:
            lines.append(f"{len(self.warnings)} warning(s) above; the calibration was still saved"
                         " (a warning does not fail the run: exit code 0).")
        return "\n".join(lines)


def run(images, *, output, pattern=(9, 6), square: float = 1.0, unit: str = "squares", previous=None,
        force: bool = False, distortion: str = "auto", reference: str | None = None, truth=None,
        score=None, sim: dict | None = None) -> CamerasRun:
    """Calibrate the cameras of ``images`` (camera → view → path or grey image) and save to
    ``output``. ``previous``: the file to compare with (default the one in ``output``);
    ``truth``/``score``: for simulated views, the true cameras and a function (calib, truth) →
    their errors. A fit that cannot be trusted (:func:`fit_warnings`) is not written unless
    ``force`` (the caller exits 3: :attr:`CamerasRun.refused`)."""
    out_path = Path(output)
    current = replaceable(out_path, unit, force)
    prev_path, prev = None, None
    if previous is not None:
        prev_path, prev = Path(previous), load_calibration(previous)
    elif current is not None:
        prev_path, prev = out_path, current
    corners, sizes, skipped = find_all_corners(images, pattern)
    calib = calibrate_cameras(corners, sizes, pattern=pattern, square=square, unit=unit, distortion=distortion,
                              reference=reference, skipped=skipped)
    change = None
    if prev is not None:
        if not isinstance(prev, CameraCalibration):
            prev = CameraCalibration.from_stereo(prev, calib.names[:2])
        change = compare_cameras(calib, prev)
    judged = score(calib, truth) if score is not None and truth is not None else None
    if fit_warnings(calib) and not force:     # an untrusted fit does not replace the file
        saved = Saved(out_path)
    else:
        saved = save_or_keep(out_path, calib.text(), "calibration")
    return CamerasRun(calib, saved, prev_path, change, judged, sim)


def _pm(sd) -> str:
    return f" ± {sd:.2g}" if sd is not None else ""


def truth_text(truth: dict[str, Any]) -> str:
    p = truth["points_3d"]
    lines = ["Compared with the simulated truth (estimated - true ± the fit's standard deviation):"]
    for name, rows in truth["cameras"].items():
        lines.append(f"  {name}: " + ", ".join(f"{k} {rows[k]['error']:+.{4 if k == 'k1' else 2}f}{_pm(rows[k]['sd'])}"
                                               for k in ("fx", "fy", "cx", "cy", "k1"))
                     + f"; turned {rows['rotation_error_deg']:.4f} deg, moved {rows['position_error']:.2f}"
                       f" {p['unit']}")
    if p["rms"] is not None:
        lines.append(f"  3D error of {p['n']} points over the field of view: RMS {p['rms']:.3f} {p['unit']},"
                     f" max {p['max']:.3f} {p['unit']}; after the best rigid fit RMS"
                     f" {p['rms_after_rigid_fit']:.4f} {p['unit']}")
    lines += [f"  {w}" for w in truth["warnings"]] or [
        f"  every fitted intrinsic is within {K_SIGMA:g} standard deviations of the truth"]
    return "\n".join(lines)


def change_text(change: dict[str, Any], prev_path) -> str:
    unit = change["unit"]
    lines = [f"Change from the previous calibration {prev_path} (cameras matched by {change['matched_by']}):"]
    for name, row in change["cameras"].items():
        pos = (f", moved {row['position']:.4g} {unit}" if row["position"] is not None
               else "; position not compared (different units)")
        lines.append(f"  {name}: fx {row['fx']:+.2f} fy {row['fy']:+.2f} cx {row['cx']:+.2f} cy {row['cy']:+.2f} px,"
                     f" k1 {row['k1']:+.4f}; turned {row['rotation_deg']:.4f} deg{pos}")
    if change["judged"]:
        lines += [f"  {w}" for w in change["warnings"]] or [
            f"  every change is within {K_SIGMA:g} combined standard deviations"]
    return "\n".join(lines)
