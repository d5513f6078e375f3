"""The 7-sphere phantom found in what the calibrated cameras see now, its spheres named S1..S7.

What names a sphere is the phantom's *shape* as the VTS → SPECT mapping measured it: the mapping
file keeps the SPECT's sphere centres (``spheres_spect_mm`` in its meta, SPECT frame, sphere 1
first: procedures/spect_mapping.py), and a rigid body's shape is the same in every frame. So:

1. each camera's detections (pixels) of about one instant, two cameras or more of the rig's
   calibration (``calibration.cameras``);
2. the phantom found among them by its shape, as the step test and the mapping find it
   (:func:`vts_hw.vision.body_finder.locate_body_views`: every epipolar-allowed pairing with two
   cameras, the multi-view matches with more; a detection used by two spheres, or a second fit
   as good, is no answer);
3. the fit is believed only when its RMS (template moved onto the 3D points) is within
   :data:`RMS_LIMIT_MM` and at least :data:`MIN_SPHERES` spheres are seen; then each sphere
   seen names the detections that made its 3D point, per camera.

Anything less -- no calibration or mapping, a mapping made before it kept the spheres, fewer
than two cameras with markers, too many markers to search (:data:`MAX_DETECTIONS`), a fit too
poor or ambiguous -- names nothing and says why (:attr:`PhantomSeen.why`): never a wrong name.
docs/decisions/0073-phantom-names.md says why this source and these limits.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from vts_hw.errors import DataError, VtsError
from vts_hw.vision.body_finder import locate_body_views
from vts_hw.vision.camera_set import in_rig_names, load_cameras, named_cameras
from vts_hw.vision.registration import RigidTransform

__all__ = [
    "PhantomLocator",
    "PhantomSeen",
    "phantom_template",
    "RMS_LIMIT_MM",
    "MIN_SPHERES",
    "MAX_DETECTIONS",
    "TEMPLATE_KEY",
]

TEMPLATE_KEY = "spheres_spect_mm"
RMS_LIMIT_MM = 2.0  # the mapping's own FRE limit (spect_mapping.FRE_LIMIT_MM): a consistent set is far below it
MIN_SPHERES = 4  # a rigid fit on 4 points has a residual to judge it by (3 fit any triangle exactly)
MAX_DETECTIONS = 40  # per camera: more, and the shape search is not bounded enough for the console's tick
TOL_MM = 3.0  # the step test's shape tolerance (body_finder.DEFAULT_TOL_MM)


def phantom_template(mapping) -> np.ndarray:
    """The phantom's sphere centres (M×3, mm) kept in a VTS → SPECT mapping (a path or a loaded
    :class:`~vts_hw.vision.registration.RigidTransform`); DataError naming the file when it keeps none."""
    t = mapping if isinstance(mapping, RigidTransform) else RigidTransform.load(mapping)
    raw = (t.meta or {}).get(TEMPLATE_KEY)
    where = "the mapping" if isinstance(mapping, RigidTransform) else f"the mapping {mapping}"
    if raw is None:
        raise DataError(
            f"{where} keeps no sphere centres (made before they were kept): run the "
            "mapping again (`vts calibrate spect`) to name the phantom's spheres"
        )
    try:
        pts = np.asarray(raw, float).reshape(-1, 3)
    except (TypeError, ValueError):
        raise DataError(f"{where}: {TEMPLATE_KEY} is not a list of [x, y, z] in mm") from None
    if len(pts) < MIN_SPHERES or not np.all(np.isfinite(pts)):
        raise DataError(f"{where}: {TEMPLATE_KEY} holds {len(pts)} usable sphere(s), {MIN_SPHERES} or more needed")
    return pts


@dataclass(frozen=True)
class PhantomSeen:
    """What :meth:`PhantomLocator.locate` made of one set of detections: ``names`` per camera
    (``[(S1, x, y), ...]``, the detections' own pixels; empty when ``why``), the fit's RMS (mm),
    how many spheres were seen of how many the phantom has."""

    names: dict[str, list[tuple[str, float, float]]] = field(default_factory=dict)
    rms_mm: float | None = None
    found: int = 0
    spheres: int = 0
    why: str = ""

    @property
    def source(self) -> str:
        """Where the names come from, in words (the page's legend)."""
        if self.why:
            return f"phantom not located: {self.why}"
        return f"phantom fitted, RMS {self.rms_mm:.1f} mm, {self.found} of {self.spheres} spheres"


class PhantomLocator:
    """Find the phantom whose sphere centres are ``template`` (M×3, mm, any frame; sphere ``i``
    is named ``S{i+1}``) with the calibrated ``cameras`` (``{name: camera}``, one world frame, mm)."""

    def __init__(
        self,
        cameras: Mapping,
        template,
        *,
        rms_limit_mm: float = RMS_LIMIT_MM,
        min_spheres: int = MIN_SPHERES,
        tol_mm: float = TOL_MM,
        max_px: float = 2.0,
        max_detections: int = MAX_DETECTIONS,
    ):
        self.cameras = named_cameras(dict(cameras))
        self.template = np.asarray(template, float).reshape(-1, 3)
        self.rms_limit_mm = float(rms_limit_mm)
        self.min_spheres = int(min_spheres)
        self.tol_mm = float(tol_mm)
        self.max_px = float(max_px)
        self.max_detections = int(max_detections)

    @classmethod
    def from_files(cls, calibration, mapping, rig_cameras: Sequence[str] = (), **kw) -> PhantomLocator:
        """From the rig's calibration file (stereo or N cameras, its cameras named as the rig's:
        :func:`~vts_hw.vision.camera_set.covered_names`) and its mapping file (the template)."""
        return cls(in_rig_names(load_cameras(calibration), list(rig_cameras)), phantom_template(mapping), **kw)

    def locate(self, detections: Mapping[str, np.ndarray]) -> PhantomSeen:
        """The spheres among ``detections`` (camera name -> N×2 px of about one instant; cameras
        the calibration does not hold are left out), or why not."""
        m = len(self.template)
        views = {n: np.asarray(p, float).reshape(-1, 2) for n, p in detections.items() if n in self.cameras and len(p)}
        if len(views) < 2:
            return PhantomSeen(spheres=m, why=f"{len(views)} calibrated camera(s) see markers, two are needed")
        crowded = [n for n, p in views.items() if len(p) > self.max_detections]
        if crowded:
            return PhantomSeen(
                spheres=m, why=f"{', '.join(crowded)} see(s) more than {self.max_detections} markers: not searched"
            )
        names = list(views)
        try:
            fit = locate_body_views(
                [self.cameras[n] for n in names],
                [views[n] for n in names],
                self.template,
                tol_mm=self.tol_mm,
                max_px=self.max_px,
                min_points=self.min_spheres,
            )
        except (VtsError, ValueError, np.linalg.LinAlgError) as exc:
            return PhantomSeen(spheres=m, why=str(exc).rstrip("."))
        if fit.rms_mm > self.rms_limit_mm:
            return PhantomSeen(
                rms_mm=fit.rms_mm,
                found=fit.found,
                spheres=m,
                why=f"the best fit's RMS {fit.rms_mm:.1f} mm is above {self.rms_limit_mm:g} mm",
            )
        seen_by = fit.detections
        if seen_by is None:  # locate_body_views gives them always
            raise RuntimeError("the phantom's fit came without the detections that made it")
        out: dict[str, list[tuple[str, float, float]]] = {n: [] for n in names}
        for i in range(m):
            for c, n in enumerate(names):
                d = int(seen_by[i, c])
                if d >= 0:
                    x, y = views[n][d]
                    out[n].append((f"S{i + 1}", float(x), float(y)))
        return PhantomSeen(out, fit.rms_mm, fit.found, m)
