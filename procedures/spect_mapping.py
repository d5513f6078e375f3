"""VTS → SPECT mapping: the rigid transform from the VTS frame to the SPECT frame.

The 7-sphere phantom is seen by both systems: the VTS gives the sphere centres in its own
frame (triangulated), the SPECT gives them in the SPECT frame (centroids in a reconstructed
volume). Neither side knows which sphere is which, so:

1. :func:`correspond` finds which SPECT point is which VTS point from rigid-invariant
   signatures (each point's sorted distances to the others), a Hungarian assignment on the
   signature distance, then a Kabsch fit to confirm it. When the fit is poor, or when two
   signatures are near-identical (a symmetric phantom), the permutations allowed by the
   signatures are scored by their Kabsch FRE and the best one wins.
2. :class:`SpectMapping` fits the transform (Kabsch, VTS → SPECT), and reports the fiducial
   registration error (FRE, the fit residual) and the leave-one-out target registration error
   (TRE: each sphere predicted from a fit to the others). The fit residual alone says little
   about accuracy (docs/design.md); the TRE is the figure to watch.

The saved transform keeps, besides its figures, the phantom's sphere centres as the SPECT
measured them (``spheres_spect_mm``, SPECT frame, in the order the mapping reports its spheres:
sphere 1 = ``S1``): the phantom's shape, which the console's Room page fits to what the cameras
see to name the spheres (vts_hw/vision/phantom_locator.py, docs/decisions/0073-phantom-names.md).

It reads like pylinac: ``SpectMapping(vts_points, spect_points).analyze()`` →
``results()`` / ``results_data()`` / ``save(path)``.

Limits (mm):

* :data:`FRE_LIMIT_MM` = 2.0 — a correspondence whose Kabsch FRE (RMS) is above this is not
  the same rigid body. The reference system reports VTS–SPECT differences of 0.3–0.4 mm mean
  and 1.1–1.3 mm max, so a consistent set stays well below it, while a sphere moved or
  mislabelled by a centimetre or more lands well above it.
* :data:`SIGNATURE_MARGIN_MM` = 5.0 — a SPECT point whose signature is within this of a VTS
  point's best signature match is a candidate for that point (the permutations tried come from
  these candidates, at most :data:`MAX_PERMUTATIONS`).
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.optimize import linear_sum_assignment

from vts_hw import __version__, catalog
from vts_hw.errors import DataError
from vts_hw.figures import figure_png
from vts_hw.results import Measure, overall_state
from vts_hw.spect import find_spheres, read_volume
from vts_hw.spect.frame import volume_record
from vts_hw.tolerance import State
from vts_hw.vision.body_finder import locate_body, locate_body_views
from vts_hw.vision.camera_set import named_cameras
from vts_hw.vision.registration import LooTre, RigidTransform, fre, kabsch, loo_tre

__all__ = ["correspond", "Correspondence", "SpectMapping", "FRE_LIMIT_MM", "SIGNATURE_MARGIN_MM", "MAX_PERMUTATIONS"]

FRE_LIMIT_MM = 2.0
SIGNATURE_MARGIN_MM = 5.0
WIDE_MARGIN_MM = 40.0  # second pass when the signature-best assignment fits badly
MAX_PERMUTATIONS = 5040  # 7!: every permutation of the 7-sphere phantom at most


@dataclass(frozen=True)
class Correspondence:
    """The outcome of :func:`correspond`: ``order[i]`` is the index in ``b`` of ``a[i]``."""

    order: list[int]
    fre_mm: float  # Kabsch FRE of the chosen order
    runner_up_fre_mm: float | None  # best FRE of any other order tried (None: none tried)
    tried: int  # permutations scored by Kabsch

    @property
    def ambiguous(self) -> bool:
        """True when another order also fits within :data:`FRE_LIMIT_MM` (a symmetric set)."""
        return self.runner_up_fre_mm is not None and self.runner_up_fre_mm <= FRE_LIMIT_MM


def _as_points(p, name: str) -> np.ndarray:
    arr = np.asarray(p, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise DataError(f"the {name} points must be an N×3 array in mm, got shape {arr.shape}.")
    if not np.all(np.isfinite(arr)):
        raise DataError(f"the {name} points hold non-finite coordinates.")
    return arr


def _signatures(p: np.ndarray) -> np.ndarray:
    """Each point's distances to the others, sorted (n, n-1): unchanged by any rigid motion."""
    d = np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1)
    return np.sort(d, axis=1)[:, 1:]


def _fit_fre(a: np.ndarray, b: np.ndarray) -> float:
    try:
        return fre(a, b, kabsch(a, b))
    except ValueError:  # collinear: no rotation can be fitted
        return float("inf")


def _permutations(cands: list[np.ndarray], cap: int):
    """Permutations with ``perm[i] in cands[i]`` and no column used twice (depth first, at
    most ``cap``)."""
    n = len(cands)
    perm = [-1] * n
    used: set[int] = set()
    count = 0

    def walk(i):
        nonlocal count
        if count >= cap:
            return
        if i == n:
            count += 1
            yield list(perm)
            return
        for j in cands[i]:
            j = int(j)
            if j in used:
                continue
            used.add(j)
            perm[i] = j
            yield from walk(i + 1)
            used.discard(j)
            if count >= cap:
                return

    yield from walk(0)


def _match(a: np.ndarray, b: np.ndarray, fre_limit: float) -> Correspondence:
    n = len(a)
    cost = np.linalg.norm(_signatures(a)[:, None, :] - _signatures(b)[None, :, :], axis=-1)
    rows, cols = linear_sum_assignment(cost)
    first = [int(c) for c in cols[np.argsort(rows)]]
    first_fre = _fit_fre(a, b[first])
    scores = {tuple(first): first_fre}

    def candidates(margin):
        return [np.argsort(row)[: int(np.sum(row <= row.min() + margin))] for row in cost]

    cands = candidates(SIGNATURE_MARGIN_MM)
    near_identical = any(len(c) > 1 for c in cands)
    if first_fre > fre_limit or near_identical:
        for perm in _permutations(cands, MAX_PERMUTATIONS):
            key = tuple(perm)
            if key not in scores:
                scores[key] = _fit_fre(a, b[perm])
        if min(scores.values()) > fre_limit:  # the signatures mislead (noise): widen the net
            for perm in _permutations(candidates(WIDE_MARGIN_MM), MAX_PERMUTATIONS):
                key = tuple(perm)
                if key not in scores:
                    scores[key] = _fit_fre(a, b[perm])
    ranked = sorted(scores.items(), key=lambda kv: kv[1])
    best, best_fre = ranked[0]
    runner = ranked[1][1] if len(ranked) > 1 else None
    if not np.isfinite(best_fre):
        raise DataError(f"the {n} points are collinear, so no rigid correspondence can be fitted.")
    if best_fre > fre_limit:
        residuals = np.linalg.norm(kabsch(a, b[list(best)]).apply(a) - b[list(best)], axis=1)
        worst = int(np.argmax(residuals))
        raise DataError(
            f"no consistent correspondence between the two sets of {n} points: the best rigid "
            f"match leaves an FRE of {best_fre:.1f} mm (limit {fre_limit:.1f} mm, worst at "
            f"point {worst + 1}, {residuals[worst]:.1f} mm), so a sphere is missing, extra or "
            "out of place in one of them."
        )
    return Correspondence(list(best), float(best_fre), runner, len(scores))


def correspond(a, b, fre_limit_mm: float = FRE_LIMIT_MM) -> list[int]:
    """The order of ``b``'s points that matches ``a``'s: ``b[correspond(a, b)]`` lines up with
    ``a`` when both are the same rigid body in unknown frames (e.g. VTS and SPECT).

    Raises :class:`DataError` when the counts differ, there are fewer than 3 points, or no
    order fits a rigid motion within ``fre_limit_mm`` (RMS, :data:`FRE_LIMIT_MM` by default).
    """
    return correspondence(a, b, fre_limit_mm).order


def correspondence(a, b, fre_limit_mm: float = FRE_LIMIT_MM) -> Correspondence:
    """:func:`correspond` with the FRE of the chosen order and of the runner-up."""
    a, b = _as_points(a, "first"), _as_points(b, "second")
    if len(a) != len(b):
        raise DataError(f"cannot match {len(a)} points to {len(b)} points: both sets must hold the same spheres.")
    if len(a) < 3:
        raise DataError(f"cannot match {len(a)} points: at least 3 are needed for a rigid fit.")
    return _match(a, b, float(fre_limit_mm))


class Fitted(NamedTuple):
    """What SpectMapping.analyze() found, all of it."""

    match: Correspondence
    transform: RigidTransform
    residuals_mm: np.ndarray
    tre: LooTre


class SpectMapping:
    """The VTS → SPECT rigid mapping from the 7-sphere phantom seen by both systems.

    ``vts_points`` (N×3, mm, VTS frame) and ``spect_points`` (N×3, mm, SPECT frame) may come in
    any order; N ≥ 4 (the leave-one-out TRE fits on N − 1 points).
    """

    def __init__(self, vts_points, spect_points, fre_limit_mm: float = FRE_LIMIT_MM):
        self.vts_points = _as_points(vts_points, "VTS")
        self.spect_points = _as_points(spect_points, "SPECT")
        self.fre_limit_mm = float(fre_limit_mm)
        self.match: Correspondence | None = None
        self.transform: RigidTransform | None = None
        self.residuals_mm: np.ndarray | None = None
        self.tre: LooTre | None = None
        self.analyzed_at: str | None = None
        self.tolerances: dict | None = None
        self.vts_cameras: list[str] | None = None  # the cameras that measured the VTS side, if known
        self.spect_volume: dict | None = None  # the volume that places the SPECT frame (spect/frame.py)

    @classmethod
    def from_volume(cls, vts_points, volume_path, fre_limit_mm: float = FRE_LIMIT_MM, **find_kwargs) -> SpectMapping:
        """SPECT points from a reconstructed volume (any format :func:`read_volume` knows);
        a sphere count other than the VTS count raises :class:`DataError`."""
        vts = _as_points(vts_points, "VTS")
        volume, record = _read_volume(volume_path)
        found = find_spheres(volume, n_expected=len(vts), strict=True, **find_kwargs)
        mapping = cls(vts, found.centroids, fre_limit_mm)
        mapping.spect_volume = record
        return mapping

    @classmethod
    def from_stereo(
        cls, calibration, pts_left, pts_right, volume_path, tol_mm: float = 3.0, fre_limit_mm: float = FRE_LIMIT_MM
    ) -> SpectMapping:
        """The phantom seen by the stereo VTS (marker detections in px, left and right, wall
        markers and all) and by the SPECT (a volume): the spheres are picked out of the VTS's
        stereo hypotheses by the shape of the SPECT's centroids
        (:func:`vts_hw.vision.body_finder.locate_body`), so nothing but the two measurements decides
        which detection is a sphere."""
        volume, record = _read_volume(volume_path)
        spect = find_spheres(volume, strict=True).centroids
        fit = locate_body(calibration.cameras(), pts_left, pts_right, spect, tol_mm=tol_mm)
        mapping = cls(fit.points, spect, fre_limit_mm)
        mapping.spect_volume = record
        return mapping

    @classmethod
    def from_views(
        cls, calibration, points_px: dict, volume_path, tol_mm: float = 3.0, fre_limit_mm: float = FRE_LIMIT_MM
    ) -> SpectMapping:
        """As :meth:`from_stereo`, from any number of cameras: ``points_px`` maps a camera name
        (the calibration's, or the rig's for a file named otherwise) to its detections (px)."""
        names = list(points_px)
        cams = named_cameras(calibration, names)
        missing = [n for n in names if n not in cams]
        if missing:
            raise DataError(f"camera(s) {', '.join(missing)} not in the calibration (it has {', '.join(cams)}).")
        volume, record = _read_volume(volume_path)
        spect = find_spheres(volume, strict=True).centroids
        fit = locate_body_views(
            [cams[n] for n in names],
            [np.asarray(points_px[n], float).reshape(-1, 2) for n in names],
            spect,
            tol_mm=tol_mm,
        )
        mapping = cls(fit.points, spect, fre_limit_mm)
        mapping.vts_cameras = names
        mapping.spect_volume = record
        return mapping

    # ------------------------------------------------------------------ analysis
    def analyze(self, tolerances: dict | None = None) -> SpectMapping:
        """Correspondence, Kabsch fit, FRE and leave-one-out TRE; ``tolerances``: the rig's
        windows over the defaults (``mapping_fre_mm``, ``mapping_tre_rms_mm`` judge)."""
        self.tolerances = tolerances
        n_v, n_s = len(self.vts_points), len(self.spect_points)
        if n_v != n_s:
            raise DataError(
                f"the VTS sees {n_v} spheres but the SPECT volume gives {n_s}: both must see the same spheres."
            )
        if n_v < 4:
            raise DataError(f"the mapping needs at least 4 spheres (leave-one-out TRE), got {n_v}.")
        self.match = correspondence(self.vts_points, self.spect_points, self.fre_limit_mm)
        spect = self.spect_points[self.match.order]
        self._spheres = spect  # the spheres in the reported order (S1..): kept in the file
        T = kabsch(self.vts_points, spect)
        self.residuals_mm = np.linalg.norm(T.apply(self.vts_points) - spect, axis=1)
        self.tre = loo_tre(self.vts_points, spect)
        self.transform = RigidTransform(T.R, T.t, self._meta())
        self.analyzed_at = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        return self

    def fitted(self) -> Fitted:
        """What analyze() found (the correspondence, the transform, its residuals and TRE);
        RuntimeError before it."""
        if self.match is None or self.transform is None or self.residuals_mm is None or self.tre is None:
            raise RuntimeError("call analyze() first")
        return Fitted(self.match, self.transform, self.residuals_mm, self.tre)

    @property
    def correspondence(self) -> list[int]:
        """``correspondence[i]``: the index in ``spect_points`` of VTS point ``i``."""
        return list(self.fitted().match.order)

    @property
    def fre_mm(self) -> float:
        return self.fitted().match.fre_mm

    def _figures(self) -> dict:
        """Correspondence, FRE and TRE: kept with the saved transform and in the results (made
        by analyze() before the transform, whose meta they are)."""
        match, residuals, tre = self.match, self.residuals_mm, self.tre
        if match is None or residuals is None or tre is None:
            raise RuntimeError("call analyze() first")
        return {
            "n_spheres": len(self.vts_points),
            "correspondence": list(match.order),
            "fre_mm": match.fre_mm,
            "fre_limit_mm": self.fre_limit_mm,
            "runner_up_fre_mm": match.runner_up_fre_mm,
            "residuals_mm": residuals.tolist(),
            "tre_rms_mm": tre.rms,
            "tre_max_mm": tre.max,
            "tre_per_sphere_mm": tre.per_point.tolist(),
            **({"vts_cameras": list(self.vts_cameras)} if self.vts_cameras else {}),
        }

    def _meta(self) -> dict:
        return {
            "from_frame": "VTS",
            "to_frame": "SPECT",
            "procedure": catalog.MAPPING.name,
            **self._figures(),
            **({"spect_volume": self.spect_volume} if self.spect_volume else {}),
            "spheres_spect_mm": np.round(self._spheres, 3).tolist(),
        }

    # ------------------------------------------------------------------ the QA result shape
    procedure = catalog.MAPPING.name

    @property
    def measures(self) -> list[Measure]:
        """FRE and leave-one-out TRE RMS, judged by the tolerance table (subject: the phantom)."""
        fit = self.fitted()
        tol = catalog.windows(self.tolerances)
        return [
            Measure.judged("phantom", "mapping_fre_mm", fit.match.fre_mm, "mm", tol["mapping_fre_mm"]),
            Measure.judged("phantom", "mapping_tre_rms_mm", fit.tre.rms, "mm", tol["mapping_tre_rms_mm"]),
        ]

    @property
    def state(self) -> State:
        return overall_state(self.measures)

    def plot(self, path=None) -> bytes:
        """Per sphere: the fit's residual and the leave-one-out TRE (mm), the limits marked."""
        from matplotlib.figure import Figure

        fit = self.fitted()
        tol = catalog.windows(self.tolerances)
        fig = Figure(figsize=(7, 3.6))
        ax = fig.add_subplot()
        k = np.arange(len(fit.residuals_mm))
        ax.bar(k - 0.2, fit.residuals_mm, 0.4, label="residual of the fit")
        ax.bar(k + 0.2, fit.tre.per_point, 0.4, label="leave-one-out TRE")
        for w, style in (
            (tol["mapping_tre_rms_mm"].tolerance_high, ":"),
            (tol["mapping_tre_rms_mm"].action_high, "--"),
        ):
            if w is not None:
                ax.axhline(w, color="0.4", ls=style, lw=1)
        ax.set_xticks(k, [f"S{i + 1}" for i in k])
        ax.set_ylabel("mm")
        ax.set_title(
            f"VTS → SPECT mapping ({self.analyzed_at}, vts-hw {__version__}): FRE "
            f"{fit.match.fre_mm:.2f} mm, TRE RMS {fit.tre.rms:.2f} mm — {self.state}",
            fontsize=9,
        )
        ax.legend(fontsize=8, frameon=False)
        return figure_png(fig, path)

    # ------------------------------------------------------------------ output
    def results_data(self) -> dict:
        """JSON-ready results: date, software version, transform, FRE and TRE (mm)."""
        fit = self.fitted()
        T = fit.transform
        return {
            "procedure": catalog.MAPPING.name,
            "date": self.analyzed_at,
            "vts_hw_version": __version__,
            "ambiguous": fit.match.ambiguous,
            "transform": {
                "R": T.R.tolist(),
                "t_mm": T.t.tolist(),
                "euler_xyz_deg": T.as_euler_xyz_deg().tolist(),
                "rotation_angle_deg": T.rotation_angle_deg,
            },
            **self._figures(),
            "spect_volume": self.spect_volume,
            "state": str(self.state),
            "measures": [m.as_dict() for m in self.measures],
        }

    def results(self) -> str:
        """A short text report for people."""
        d = self.results_data()
        rx, ry, rz = d["transform"]["euler_xyz_deg"]
        tx, ty, tz = d["transform"]["t_mm"]
        lines = [
            f"VTS → SPECT mapping ({d['n_spheres']} spheres), {d['date']}, vts-hw {d['vts_hw_version']}",
            f"  rotation about x, y, z: {rx:.2f}°, {ry:.2f}°, {rz:.2f}° "
            f"(angle {d['transform']['rotation_angle_deg']:.2f}°)",
            f"  translation: {tx:.2f}, {ty:.2f}, {tz:.2f} mm",
            f"  FRE (RMS fit residual): {d['fre_mm']:.2f} mm (limit {d['fre_limit_mm']:.1f} mm)",
            f"  leave-one-out TRE: RMS {d['tre_rms_mm']:.2f} mm, max {d['tre_max_mm']:.2f} mm",
            "  sphere  SPECT#  residual mm  TRE mm",
        ]
        for i, (j, r, e) in enumerate(zip(d["correspondence"], d["residuals_mm"], d["tre_per_sphere_mm"])):
            lines.append(f"  {i + 1:>6}  {j + 1:>6}  {r:>11.2f}  {e:>6.2f}")
        if d["ambiguous"]:
            lines.append(
                f"  WARNING: another sphere order also fits (FRE "
                f"{d['runner_up_fre_mm']:.2f} mm): the phantom looks symmetric; check "
                "the correspondence."
            )
        return "\n".join(lines)

    def save(self, path) -> Path:
        """Write the VTS → SPECT transform file (FRE and TRE in its meta); read it back with
        :meth:`RigidTransform.load`."""
        return self.fitted().transform.save(path)


def _read_volume(path):
    """The volume and what the mapping keeps of it (the frame it places: vts_hw.spect.frame)."""
    volume = read_volume(path)
    return volume, volume_record(path, volume)


def replaceable(out_path: Path, force: bool = False) -> None:
    """Refuse, before any work, an ``-o`` that exists and is not a VTS → SPECT mapping file (a
    rig.yaml or a calibration given by mistake would be lost): DataError (exit 3) naming it;
    ``force`` replaces it anyway. An earlier mapping there is replaced, as before."""
    if force or not out_path.exists():
        return
    try:
        RigidTransform.load(out_path)
    except DataError:
        raise DataError(
            f"{out_path} exists and is not a VTS → SPECT mapping file; give another -o,"
            " move it away, or give --force to replace it."
        ) from None
