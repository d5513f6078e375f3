"""A checkerboard calibration as a QA result (vts_hw.results shape): its RMS reprojection
errors per camera and of the whole set, judged by the ``calibration_rms_px`` window, so that
`vts calibrate stereo` / `vts calibrate cameras` store a run the one way, under one name, and
the reports show the room's calibration history."""

from __future__ import annotations

from vts_hw import catalog
from vts_hw.figures import figure_png
from vts_hw.results import Measure, overall_state
from vts_hw.tolerance import State

#: the one procedure name of a calibration run, whichever command made it (the catalog's)
PROCEDURE = catalog.CALIBRATION.name
#: the subject of the whole set's figure (the cameras' own are named after the camera)
SET_SUBJECT = "set"


def rms_measures(
    per_camera: dict[str, float], overall: float, tolerances=None, converged: bool | None = None
) -> list[Measure]:
    """One ``calibration_rms_px`` measure per camera and one for the set (``SET_SUBJECT``);
    with ``converged`` given, a ``calibration_converged`` measure (1 or 0) too."""
    tol = catalog.windows(tolerances)
    w = tol["calibration_rms_px"]
    out = [Measure.judged(name, "calibration_rms_px", rms, "px", w) for name, rms in per_camera.items()]
    out.append(Measure.judged(SET_SUBJECT, "calibration_rms_px", overall, "px", w))
    if converged is not None:
        out.append(
            Measure.judged(
                SET_SUBJECT, "calibration_converged", 1.0 if converged else 0.0, "", tol["calibration_converged"]
            )
        )
    return out


class CalibrationResult:
    """Mixin for the calibration runs: ``measures`` comes from :meth:`rms_figures`."""

    procedure = PROCEDURE
    tolerances: dict | None = None  # the rig config's windows, set by the caller; None: the defaults

    def rms_figures(self) -> tuple[dict[str, float], float, bool | None]:
        raise NotImplementedError

    @property
    def measures(self) -> list[Measure]:
        per_camera, overall, converged = self.rms_figures()
        return rms_measures(per_camera, overall, self.tolerances, converged)

    @property
    def state(self) -> State:
        return overall_state(self.measures)

    def plot(self, path=None) -> bytes:
        """The RMS per camera and of the set as bars, with the tolerance and action levels."""
        from matplotlib.figure import Figure

        w = catalog.windows(self.tolerances)["calibration_rms_px"]
        ms = [m for m in self.measures if m.metric == "calibration_rms_px"]
        fig = Figure(figsize=(6, 3.2))
        ax = fig.add_subplot()
        ax.bar([m.subject for m in ms], [m.value or 0.0 for m in ms], color="#4c72b0")
        for level, colour in ((w.tolerance_high, "#e6a700"), (w.action_high, "#c62828")):
            if level is not None:
                ax.axhline(level, color=colour, lw=1, ls="--")
        ax.set_ylabel("RMS reprojection error (px)")
        fig.tight_layout()
        return figure_png(fig, path)
