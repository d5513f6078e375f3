"""The stereo calibration as a procedure: checkerboard pairs in, a checked calibration saved.

:func:`run` checks that the output may be replaced (:func:`replaceable`: a calibration in mm is
not replaced by one in squares by mistake), calibrates (:func:`vts_hw.vision.calibration.calibrate_stereo`),
judges the change from the previous calibration and, for simulated views, the errors against the
true cameras (:mod:`vts_hw.vision.calibration_uncertainty`), and saves it so that a full disk cannot lose
it (:func:`vts_hw.save_or_keep.save_or_keep`). The :class:`CalibrationRun` it returns prints
itself (``results()``) and gives its JSON (``results_data()``); it raises nothing once the
calibration is computed: a failed write is in ``saved.error`` for the caller to raise after
showing the figures. Warnings never fail the run. See docs/decisions/0024-calibration-uncertainty.md.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from vts_hw.vision.calibration import calibrate_stereo, find_pairs
from vts_hw.vision.calibration_io import StereoCalibration
from vts_hw.vision.multi_calibration_io import load_calibration
from vts_hw.vision.calibration_uncertainty import K_SIGMA, compare_with_truth
from vts_hw.errors import DataError
from vts_hw.procedures.camera_calibration import replaceable as any_replaceable
from vts_hw.procedures.calibration_result import STEREO_PROCEDURE, CalibrationResult
from vts_hw.save_or_keep import Saved, save_or_keep

_IMAGE = re.compile(r"^(left|right)(.*)\.(jpe?g|png|bmp|tiff?)$", re.IGNORECASE)


def image_pairs(args: list[str]) -> list[tuple[Path, Path]]:
    """(left, right) image paths from directories and/or files named leftNN / rightNN.

    A directory gives its pairs (:func:`vts_hw.vision.calibration.find_pairs`); files are paired by
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
            raise DataError(f"{path}: image names must be leftNN.jpg / rightNN.jpg (or .png) so"
                            " that left and right can be paired.")
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


def replaceable(out_path: Path, unit: str, force: bool = False) -> StereoCalibration | None:
    """:func:`camera_calibration.replaceable`, the calibration there read as a stereo pair."""
    old = any_replaceable(out_path, unit, force, what="stereo calibration")
    return None if old is None else _as_stereo(old)


def _as_stereo(calib) -> StereoCalibration:
    """A stereo calibration, or an N-camera one's first two cameras as one (to compare with)."""
    return calib if isinstance(calib, StereoCalibration) else calib.stereo()


@dataclass
class CalibrationRun(CalibrationResult):
    """A computed calibration, how it compares, and where it was saved; as a QA result
    (procedure ``calibration``) the RMS of each camera and of the pair."""

    procedure = STEREO_PROCEDURE

    calib: StereoCalibration
    saved: Saved
    previous_path: Path | None = None
    change: dict[str, Any] | None = None
    truth: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)

    def rms_figures(self):
        c = self.calib
        return {"left": c.rms_left, "right": c.rms_right}, c.rms_stereo, None

    @property
    def warnings(self) -> list[str]:
        out = list(self.truth["warnings"]) if self.truth else []
        return out + (list(self.change["warnings"]) if self.change else [])

    def results_data(self) -> dict[str, Any]:
        data = self.calib.results_data()
        data.update(self.saved.data())
        if self.change is not None:
            data["change"] = dict(self.change, previous=str(self.previous_path))
        if self.truth is not None:
            data["sim_truth"] = self.truth
        data["warnings"] = self.warnings
        return data

    def results(self) -> str:
        lines = [self.calib.results()]
        if self.truth is not None:
            lines.append(truth_text(self.truth))
        if self.change is not None:
            lines.append(change_text(self.change, self.previous_path))
        if self.saved.written:
            lines.append(f"wrote {self.saved.written}")
        if self.warnings:
            lines.append(f"{len(self.warnings)} warning(s) above; the calibration was still saved"
                         " (a warning does not fail the run: exit code 0).")
        return "\n".join(lines)


def run(pairs, *, output, pattern=(9, 6), square: float = 1.0, unit: str = "squares",
        names=None, previous=None, force: bool = False, truth=None,
        distortion: str = "auto") -> CalibrationRun:
    """Calibrate from ``pairs`` and save to ``output`` (see the module docstring). ``previous``:
    the calibration file to compare with (default: the one now in ``output``); ``truth``: the
    true cameras as a StereoCalibration, for simulated views; ``distortion``: see
    :func:`vts_hw.vision.calibration.fit_camera`."""
    out_path = Path(output)
    current = replaceable(out_path, unit, force)
    prev_path, prev = None, None
    if previous is not None:
        prev_path = Path(previous)
        prev = _as_stereo(load_calibration(prev_path))
    elif current is not None:
        prev_path, prev = out_path, current
    calib = calibrate_stereo(pairs, pattern=pattern, square=square, unit=unit, names=names,
                             distortion=distortion)
    change = calib.compare(prev) if prev is not None else None
    judged_truth = compare_with_truth(calib, truth) if truth is not None else None
    saved = save_or_keep(out_path, calib.text(), "calibration")
    return CalibrationRun(calib, saved, prev_path, change, judged_truth)


def _pm(sd, fmt: str) -> str:
    return f" ± {sd:{fmt}}" if sd is not None else ""


def truth_text(truth: dict[str, Any]) -> str:
    """The errors against the simulated truth, each with the fit's standard deviation."""
    lines = ["Compared with the simulated truth (estimated - true ± the fit's standard deviation):"]
    for name, rows in truth["cameras"].items():
        fx, fy, cx, cy, k1 = (rows[k] for k in ("fx", "fy", "cx", "cy", "k1"))
        lines.append(f"  {name}: fx {fx['error']:+.2f}{_pm(fx['sd'], '.2g')} px ({fx['error_percent']:+.3f} %),"
                     f" fy {fy['error']:+.2f}{_pm(fy['sd'], '.2g')} px ({fy['error_percent']:+.3f} %),"
                     f" cx {cx['error']:+.2f}{_pm(cx['sd'], '.2g')} px, cy {cy['error']:+.2f}{_pm(cy['sd'], '.2g')} px,"
                     f" k1 {k1['estimated']:+.4f} vs {k1['true']:+.4f} ({k1['error']:+.4f}{_pm(k1['sd'], '.2g')})")
    rot, base = truth["rotation"], truth["baseline"]
    lines.append(f"  stereo rotation {rot['estimated_deg']:.4f} deg vs {rot['true_deg']:.4f} deg:"
                 f" off by {rot['error_deg']:.4f}{_pm(rot['sd_deg'], '.2g')} deg")
    lines.append(f"  baseline {base['estimated']:.2f} vs {base['true']:.2f} {base['unit']}:"
                 f" {base['error']:+.2f}{_pm(base['sd'], '.2g')} {base['unit']} ({base['error_percent']:+.3f} %),"
                 f" direction off by {base['direction_error_deg']:.4f} deg")
    lines += [f"  {w}" for w in truth["warnings"]] or [
        f"  every fitted parameter is within {K_SIGMA:g} standard deviations of the truth"]
    return "\n".join(lines)


def change_text(change: dict[str, Any], prev_path) -> str:
    """The change from the previous calibration, judged against the combined uncertainty."""
    unit = change["unit"]
    sds = {r["parameter"]: r["sd"] for r in change.get("judged", [])}
    lines = [f"Change from the previous calibration {prev_path}"
             + (" (± combined standard deviation):" if sds else ":")]
    for cam in ("1", "2"):
        parts = [f"{k} {change[k + cam]:+.2f}{_pm(sds.get(k + cam), '.2g')}" for k in ("fx", "fy", "cx", "cy")]
        lines.append(f"  camera {cam}: {' '.join(parts)} px")
    text = (f"  rotation between cameras changed by {change['rotation_deg']:.4f}"
            f"{_pm(sds.get('rotation'), '.2g')} deg")
    if unit is None:
        text += "; translation not compared (different units)"
    else:
        text += (f", translation by {change['translation']:.4g}{_pm(sds.get('translation'), '.2g')} {unit},"
                 f" baseline {change['baseline']:+.4g} {unit}")
    lines.append(text)
    if sds and not change.get("previous_has_uncertainty", True):
        lines.append("  (the previous file has no uncertainties: taken as equal to this one's)")
    if sds:
        lines += [f"  {w}" for w in change["warnings"]] or [
            f"  every change is within {K_SIGMA:g} combined standard deviations"]
    return "\n".join(lines)
