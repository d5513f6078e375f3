"""Analysis of the 7-sphere step test: the VTS against the SPECT, position by position.

Input: for every table position (baseline, vertical steps, axial steps, the final free move)
the sphere centres as the VTS saw them, already mapped into the SPECT frame, and as the SPECT
saw them (centroids in the reconstructed volume), both in one sphere order (S1..S7 of the
baseline). Output, as in docs/design.md:

* per axis (x lateral, y vertical, z axial) the regression of the VTS coordinate against the
  SPECT coordinate over every sphere and position: slope, intercept (mm), R²;
* the VTS–SPECT Euclidean differences over every sphere and position: max, mean, SD (mm);
* the 6-DOF move from the first position to the last as each system sees it (Kabsch): the
  rotations about x, y, z (degrees, extrinsic x then y then z) and the translation of the
  phantom's centre (mean of its spheres, mm) — a translation that does not depend on where the
  SPECT frame's origin happens to be — and their differences VTS − SPECT.

It reads like pylinac: ``StepAnalysis(...).analyze(tolerances)`` → ``results()`` /
``results_data()`` / ``plot(path)``; results are stamped with the software version and date.
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass

import numpy as np
from scipy import stats

from vts_hw import __version__, catalog
from vts_hw.catalog import STEPS
from vts_hw.errors import DataError
from vts_hw.figures import figure_png
from vts_hw.results import Measure
from vts_hw.tolerance import State, Window, worst
from vts_hw.vision.registration import RigidTransform, kabsch

AXES = ("x", "y", "z")
AXIS_NAMES = {"x": "lateral", "y": "vertical", "z": "axial"}

# metric -> (subject, unit) of what the analysis measures and judges
METRICS = (
    "steps_slope",
    "steps_intercept_mm",
    "steps_r2",
    "steps_diff_max_mm",
    "steps_diff_mean_mm",
    "steps_diff_sd_mm",
    "steps_rotation_diff_deg",
    "steps_translation_diff_mm",
)


@dataclass(frozen=True)
class Regression:
    axis: str
    slope: float
    intercept_mm: float
    r2: float
    n: int


@dataclass(frozen=True)
class Move:
    """A 6-DOF move as one system saw it."""

    rotation_xyz_deg: np.ndarray  # about x, y, z
    translation_mm: np.ndarray  # of the phantom's centre
    transform: RigidTransform

    def as_dict(self) -> dict:
        return {"rotation_xyz_deg": self.rotation_xyz_deg.tolist(), "translation_mm": self.translation_mm.tolist()}


def six_dof(before: np.ndarray, after: np.ndarray) -> Move:
    """The rigid move taking the spheres ``before`` onto ``after`` (both M×3, same order)."""
    T = kabsch(before, after)
    shift = after.mean(axis=0) - before.mean(axis=0)
    return Move(np.asarray(T.as_euler_xyz_deg(), float), shift, T)


class StepAnalysis:
    """The step test from per-position sphere centres.

    ``labels`` (P) name the positions; ``vts`` and ``spect`` are P×M×3 (mm, SPECT frame, the
    same sphere order at every position). The first position is the baseline, the last the
    free move.
    """

    procedure = STEPS.name

    def __init__(self, labels, vts, spect, kinds=None, meta: dict | None = None):
        self.labels = [str(x) for x in labels]
        self.vts = np.asarray(vts, float)
        self.spect = np.asarray(spect, float)
        self.kinds = list(kinds) if kinds is not None else ["step"] * len(self.labels)
        self.meta = dict(meta or {})
        if self.vts.shape != self.spect.shape or self.vts.ndim != 3 or self.vts.shape[2] != 3:
            raise DataError(
                f"VTS {self.vts.shape} and SPECT {self.spect.shape} sphere arrays must both be positions × spheres × 3."
            )
        if len(self.labels) != self.vts.shape[0]:
            raise DataError(f"{len(self.labels)} labels for {self.vts.shape[0]} positions.")
        if self.vts.shape[0] < 2:
            raise DataError("the step test needs at least two positions.")
        if not (np.all(np.isfinite(self.vts)) and np.all(np.isfinite(self.spect))):
            raise DataError("a sphere position is missing (non-finite) in the step data.")
        self.analyzed_at: str | None = None
        self.measures: list[Measure] = []

    # ------------------------------------------------------------------ analysis
    def analyze(self, tolerances: dict | None = None) -> StepAnalysis:
        tol: dict[str, Window] = catalog.windows(tolerances)
        v = self.vts.reshape(-1, 3)
        s = self.spect.reshape(-1, 3)
        self.regressions = {}
        for k, ax in enumerate(AXES):
            fit = stats.linregress(s[:, k], v[:, k])
            self.regressions[ax] = Regression(ax, float(fit.slope), float(fit.intercept), float(fit.rvalue**2), len(s))
        self.diffs = np.linalg.norm(self.vts - self.spect, axis=2)  # P×M
        self.move_vts = six_dof(self.vts[0], self.vts[-1])
        self.move_spect = six_dof(self.spect[0], self.spect[-1])
        self.rotation_diff_deg = self.move_vts.rotation_xyz_deg - self.move_spect.rotation_xyz_deg
        self.translation_diff_mm = self.move_vts.translation_mm - self.move_spect.translation_mm

        out: list[Measure] = []

        def add(subject, metric, value, unit):
            w = tol.get(metric)
            out.append(Measure(subject, metric, float(value), unit, w.state(float(value)) if w else State.OK))

        for ax, r in self.regressions.items():
            add(ax, "steps_slope", r.slope, "")
            add(ax, "steps_intercept_mm", r.intercept_mm, "mm")
            add(ax, "steps_r2", r.r2, "")
        add("all", "steps_diff_max_mm", self.diffs.max(), "mm")
        add("all", "steps_diff_mean_mm", self.diffs.mean(), "mm")
        add("all", "steps_diff_sd_mm", self.diffs.std(ddof=1) if self.diffs.size > 1 else 0.0, "mm")
        for k, ax in enumerate(AXES):
            add(f"move_{ax}", "steps_rotation_diff_deg", self.rotation_diff_deg[k], "deg")
            add(f"move_{ax}", "steps_translation_diff_mm", self.translation_diff_mm[k], "mm")
        self.measures = out
        self.analyzed_at = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        return self

    def _need(self) -> None:
        if self.analyzed_at is None:
            raise RuntimeError("call analyze() first")

    @property
    def state(self) -> State:
        self._need()
        return worst(m.state for m in self.measures)

    # ------------------------------------------------------------------ output
    def results_data(self) -> dict:
        self._need()
        return {
            "procedure": "sphere-steps",
            "date": self.analyzed_at,
            "vts_hw_version": __version__,
            "state": str(self.state),
            "positions": [
                {
                    "label": lab,
                    "kind": kind,
                    "vts_mm": self.vts[i].tolist(),
                    "spect_mm": self.spect[i].tolist(),
                    "diff_mm": self.diffs[i].tolist(),
                }
                for i, (lab, kind) in enumerate(zip(self.labels, self.kinds))
            ],
            "regression": {
                ax: {"slope": r.slope, "intercept_mm": r.intercept_mm, "r2": r.r2, "n": r.n}
                for ax, r in self.regressions.items()
            },
            "differences_mm": {
                "max": float(self.diffs.max()),
                "mean": float(self.diffs.mean()),
                "sd": float(self.diffs.std(ddof=1)) if self.diffs.size > 1 else 0.0,
            },
            "move": {
                "vts": self.move_vts.as_dict(),
                "spect": self.move_spect.as_dict(),
                "difference": {
                    "rotation_xyz_deg": self.rotation_diff_deg.tolist(),
                    "translation_mm": self.translation_diff_mm.tolist(),
                },
                "from": self.labels[0],
                "to": self.labels[-1],
            },
            "measurements": [
                {"subject": m.subject, "metric": m.metric, "value": m.value, "unit": m.unit, "state": str(m.state)}
                for m in self.measures
            ],
            "meta": self.meta,
        }

    def results(self) -> str:
        d = self.results_data()
        bad = {(m.subject, m.metric): m.state for m in self.measures if m.state != State.OK}

        def flag(subject, metric):
            st = bad.get((subject, metric))
            return f"  <- {st}" if st else ""

        lines = [
            f"7-sphere step test: {d['state']}  ({len(self.labels)} positions × "
            f"{self.vts.shape[1]} spheres; {d['date']}, vts-hw {__version__})",
            "  regression of VTS against SPECT position:",
        ]
        for ax, r in self.regressions.items():
            lines.append(
                f"    {ax} ({AXIS_NAMES[ax]:<8}) slope {r.slope:.5f}{flag(ax, 'steps_slope')}"
                f"  intercept {r.intercept_mm:+.3f} mm{flag(ax, 'steps_intercept_mm')}"
                f"  R² {r.r2:.6f}{flag(ax, 'steps_r2')}"
            )
        df = d["differences_mm"]
        lines.append(
            f"  VTS–SPECT distance: max {df['max']:.2f} mm{flag('all', 'steps_diff_max_mm')},"
            f" mean {df['mean']:.2f} mm{flag('all', 'steps_diff_mean_mm')},"
            f" SD {df['sd']:.2f} mm{flag('all', 'steps_diff_sd_mm')}"
        )
        lines.append(
            f"  6-DOF move {self.labels[0]} → {self.labels[-1]}:"
            "        rx°      ry°      rz°     tx mm    ty mm    tz mm"
        )
        for name, mv in (("VTS", self.move_vts), ("SPECT", self.move_spect)):
            lines.append(
                f"    {name:<27}"
                + "".join(f"{a:9.3f}" for a in mv.rotation_xyz_deg)
                + "".join(f"{t:9.2f}" for t in mv.translation_mm)
            )
        lines.append(
            "    difference (VTS − SPECT)   "
            + "".join(f"{a:+9.3f}" for a in self.rotation_diff_deg)
            + "".join(f"{t:+9.2f}" for t in self.translation_diff_mm)
        )
        flagged = [
            f"{m.subject} {m.metric} {m.value:+.3f} {m.unit} {m.state}"
            for m in self.measures
            if m.state != State.OK and m.metric in ("steps_rotation_diff_deg", "steps_translation_diff_mm")
        ]
        lines += [f"    <- {f}" for f in flagged]
        return "\n".join(lines)

    def plot(self, path=None):
        """Three regression panels (VTS vs SPECT per axis) and the differences per position."""
        self._need()
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 4, figsize=(16, 4.2))
        v = self.vts.reshape(-1, 3)
        s = self.spect.reshape(-1, 3)
        for k, ax in enumerate(AXES):
            a = axes[k]
            r = self.regressions[ax]
            a.plot(s[:, k], v[:, k], ".", ms=4, color="tab:blue")
            lo, hi = float(s[:, k].min()), float(s[:, k].max())
            xs = np.array([lo, hi])
            a.plot(xs, r.slope * xs + r.intercept_mm, "-", color="tab:red", lw=1)
            a.set_xlabel(f"SPECT {ax} ({AXIS_NAMES[ax]}) mm")
            a.set_ylabel(f"VTS {ax} mm")
            a.set_title(f"{ax}: slope {r.slope:.4f}, R² {r.r2:.5f}", fontsize=10)
            a.grid(alpha=0.3)
        a = axes[3]
        pos = np.arange(len(self.labels))
        for m in range(self.diffs.shape[1]):
            a.plot(pos, self.diffs[:, m], ".-", lw=0.6, ms=3, label=f"sphere {m + 1}")
        a.set_xticks(pos)
        a.set_xticklabels(self.labels, rotation=90, fontsize=7)
        a.set_ylabel("VTS–SPECT distance mm")
        a.set_title(f"mean {self.diffs.mean():.2f} mm, max {self.diffs.max():.2f} mm", fontsize=10)
        a.legend(fontsize=6, ncol=2)
        a.grid(alpha=0.3)
        fig.suptitle(f"7-sphere step test ({self.analyzed_at}, vts-hw {__version__}): {self.state}")
        fig.tight_layout()
        if path is not None:
            figure_png(fig, path, dpi=110)  # whole or not at all (a full disk: WriteFailed)
            plt.close(fig)
        return fig
