"""The calibration as a procedure: checkerboard images of N ≥ 2 cameras in, one calibration of
all of them in one frame checked, compared and saved. `vts calibrate stereo` is its two-camera
case and `vts calibrate cameras` its general one: one procedure, one record, one stored name.

:func:`run` checks that the output may be replaced (:func:`replaceable`: a calibration in mm is
not replaced by one in squares by mistake), finds the corners and calibrates
(:func:`vts_hw.vision.calibration.calibrate_cameras`; for a stereo pair
:func:`~vts_hw.vision.calibration.calibrate_stereo`: each camera's intrinsics from its own
views, then the pair, so every figure is plain OpenCV's), compares with the previous calibration
(the ``-o`` file if there is one, or ``previous``) and, for simulated views, with the truth, and
saves it so that a full disk cannot lose it (:func:`vts_hw.save_or_keep.save_or_keep`); a fit
that cannot be trusted (:func:`fit_warnings`) is not written without ``force``. The
:class:`CalibrationRun` it returns is a QA result (procedure ``calibration``) that prints itself
(:mod:`vts_hw.procedures.calibration_text`) and gives its JSON; a failed write is in
``saved.error`` for the caller to raise after showing the figures. Decisions 0012, 0024, 0030, 0056.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vts_hw.errors import DataError, UsageError
from vts_hw.procedures.calibration_images import camera_images, find_all_corners, image_pairs  # noqa: F401
from vts_hw.procedures.calibration_result import PROCEDURE, CalibrationResult
from vts_hw.procedures.calibration_text import run_text
from vts_hw.save_or_keep import Saved, save_or_keep
from vts_hw.vision.calibration import calibrate_cameras, calibrate_stereo
from vts_hw.vision.calibration_io import CameraCalibration, load_calibration
from vts_hw.vision.calibration_uncertainty import compare_pair
from vts_hw.vision.multi_compare import compare_cameras

MAX_RMS_PX = 1.0  # a checkerboard fit above this overall RMS is not trusted (corner noise: 0.05-0.5 px)


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
        raise DataError(
            f"{out_path} exists and is not a {what} file; give another -o, move it away, or give --force to replace it."
        ) from None
    if old.unit == "mm" and unit == "squares" and not force:
        raise UsageError(
            f"{out_path} holds a calibration in mm (squares of {old.square:g} mm) and this one"
            " would be in squares because --square was not given: give --square with the side"
            " of a square in mm, another -o, or --force to replace it."
        )
    return old


def fit_warnings(calib: CameraCalibration) -> list[str]:
    """WARNING lines for a fit that cannot be trusted: a bundle adjustment that stopped before it
    converged, or an overall RMS above ``MAX_RMS_PX``."""
    out = []
    adj = calib.adjustment
    if adj and not adj.get("converged", True):
        out.append(
            f"WARNING: the bundle adjustment did not converge ({adj.get('evaluations')} evaluations:"
            f" {adj.get('status')})."
        )
    if calib.rms > MAX_RMS_PX:
        out.append(
            f"WARNING: RMS reprojection error {calib.rms:.3f} px is above the {MAX_RMS_PX:g} px a"
            " checkerboard calibration reaches: views that do not fit, or too few views per camera."
        )
    return out


@dataclass
class CalibrationRun(CalibrationResult):
    """A computed calibration, how it compares, and where it was saved; as a QA result
    (procedure ``calibration``) the RMS of each camera and of the set, and whether the bundle
    adjustment converged."""

    procedure = PROCEDURE

    calib: CameraCalibration
    saved: Saved
    previous_path: Path | None = None
    change: dict[str, Any] | None = None
    truth: dict[str, Any] | None = None
    sim: dict[str, Any] | None = None

    def rms_figures(self):
        c = self.calib
        return ({f.name: f.rms for f in c.camera_fits}, c.rms, bool((c.adjustment or {}).get("converged", True)))

    @property
    def untrusted(self) -> list[str]:
        """The fit's own warnings (:func:`fit_warnings`): not written over -o without --force."""
        return fit_warnings(self.calib)

    @property
    def warnings(self) -> list[str]:
        return (
            self.untrusted
            + (list(self.truth["warnings"]) if self.truth else [])
            + (list(self.change["warnings"]) if self.change else [])
        )

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
        return run_text(self)


def run(
    images=None,
    *,
    output,
    pairs=None,
    pattern=(9, 6),
    square: float = 1.0,
    unit: str = "squares",
    previous=None,
    force: bool = False,
    distortion: str = "auto",
    reference: str | None = None,
    names=None,
    cameras=("left", "right"),
    truth=None,
    score=None,
    sim: dict | None = None,
    what: str = "calibration",
) -> CalibrationRun:
    """Calibrate and save to ``output``: the cameras of ``images`` (camera → view → path or grey
    image), or the stereo pair of ``pairs`` ((left, right) images; ``names`` the views',
    ``cameras`` the two cameras' names). ``previous``: the file to compare with (default the one
    in ``output``); ``truth``/``score``: for simulated views, the true cameras and a function
    (calib, truth) → their errors. A fit that cannot be trusted (:func:`fit_warnings`) is not
    written unless ``force`` (the caller exits 3: :attr:`CalibrationRun.refused`); ``what`` names
    the kind of file in the refusal of an ``output`` that is not one."""
    if (images is None) == (pairs is None):
        raise ValueError("give either images or pairs")
    out_path = Path(output)
    current = replaceable(out_path, unit, force, what)
    prev_path, prev = None, None
    if previous is not None:
        prev_path, prev = Path(previous), load_calibration(previous)
    elif current is not None:
        prev_path, prev = out_path, current
    if pairs is not None:
        calib = calibrate_stereo(
            pairs, pattern=pattern, square=square, unit=unit, names=names, distortion=distortion, cameras=cameras
        )
    else:
        corners, sizes, skipped = find_all_corners(images, pattern)
        calib = calibrate_cameras(
            corners,
            sizes,
            pattern=pattern,
            square=square,
            unit=unit,
            distortion=distortion,
            reference=reference,
            skipped=skipped,
        )
    change = None
    if prev is not None:  # a pair fitted as OpenCV's stereo fit is judged as a pair (0024), N cameras one by one
        change = compare_pair(calib, prev) if calib.pair is not None else compare_cameras(calib, prev)
    judged = score(calib, truth) if score is not None and truth is not None else None
    if fit_warnings(calib) and not force:  # an untrusted fit does not replace the file
        saved = Saved(out_path)
    else:
        saved = save_or_keep(out_path, calib.text(), "calibration")
    return CalibrationRun(calib, saved, prev_path, change, judged, sim)
