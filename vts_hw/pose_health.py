"""How sure a pose is: its health (known, bounded, not known, and why) and a confidence in [0, 1],
from what the fit saw -- the same rule for the live estimate and the offline analysis
(docs/decisions/0091-every-pose-says-how-sure-it-is.md; issue 33 §2).

Core and light (NumPy only): :mod:`vts_hw.motion` (the offline poses) and
:mod:`vts_hw.tracking.live` (the live estimate) both import it; it imports neither.

Inputs per pose: ``markers`` used by the fit, of the model's ``model_markers``; the fit
``residual_mm`` (RMS over the markers used); ``cameras``: the mean number of cameras that saw
each marker used (a point needs 2; unknown: taken as 2); ``age_s``: seconds since the capture
of the frames the pose comes from (0 offline: each row's pose is fitted from its own frames).

**State** (the first that applies):

* ``not known`` -- no frames at that time; fewer than :data:`MIN_MARKERS` markers; no pose fitted
  (no residual); frames older than :data:`STALE_S`. Confidence 0.
* ``bounded`` -- a pose, not measured to its goal: the residual is over :data:`POOR_FIT_MM` (the
  model does not explain the markers; the pose error is of the residual's order), or only
  :data:`MIN_MARKERS` markers (a wrong point cannot show), or frames older than :data:`FRESH_S`.
* ``known`` -- otherwise.

**Confidence** = ``m * r * c * a``, each factor in [0, 1]:

* markers ``m = sqrt((n - 2) / (M - 2))`` (n used of M, M at least n and 3): 1 with every
  marker, 0.41 with 3 of 8; the pose's error falls roughly as 1/sqrt of the points beyond the
  two a rotation needs;
* residual ``r = 1 / (1 + (rms / POOR_FIT_MM)^2)``: 0.97 at 0.05 mm, 0.5 at the poor-fit line;
* cameras ``c = 1 - 0.4 / k`` (k the mean cameras per marker, at least 1): 0.8 with 2 (no
  third view to catch a wrong match), 0.87 with 3, 0.9 with 4;
* age ``a = exp(-age / AGE_S)``: 0.95 at 0.1 s.

Each factor is monotone in its input (more markers or cameras: never less confidence; more
residual or age: never more), and so is the product; ``tests/unit/test_pose_health.py`` checks it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "PoseHealth",
    "HealthSeries",
    "pose_health",
    "health_series",
    "KNOWN",
    "BOUNDED",
    "NOT_KNOWN",
    "MIN_MARKERS",
    "POOR_FIT_MM",
    "FRESH_S",
    "STALE_S",
    "AGE_S",
]

KNOWN, BOUNDED, NOT_KNOWN = "known", "bounded", "not known"
MIN_MARKERS = 3  # a rigid pose needs 3 points
POOR_FIT_MM = 0.3  # a fit residual over this: the pose is bounded by it, not measured (a good fit leaves
# 0.02-0.1 mm; vts_hw.motion.body_pose.POOR_FIT_MM is the same line)
FRESH_S = 0.5  # frames older than this: the pose is bounded (the body may have moved since)
STALE_S = 5.0  # ... older than this: not known
AGE_S = 2.0  # the age factor's scale
MIN_CAMERAS = 2.0  # a point is triangulated from at least 2 cameras (cameras not known: taken as 2)


@dataclass(frozen=True)
class PoseHealth:
    """One pose's health: ``state`` (:data:`KNOWN`, :data:`BOUNDED`, :data:`NOT_KNOWN`), ``why``
    (empty when known), ``confidence`` in [0, 1] (0 when not known)."""

    state: str
    why: str
    confidence: float

    def to_json(self) -> dict:
        return {"state": self.state, "why": self.why, "confidence": round(self.confidence, 4)}


@dataclass
class HealthSeries:
    """Per row: ``state`` (F,) str, ``why`` (F,) str, ``confidence`` (F,) float."""

    state: np.ndarray
    why: np.ndarray
    confidence: np.ndarray

    def __len__(self) -> int:
        return len(self.state)

    def __getitem__(self, k: int) -> PoseHealth:
        return PoseHealth(str(self.state[k]), str(self.why[k]), float(self.confidence[k]))

    def counts(self) -> dict:
        """Rows per state."""
        return {s: int(np.count_nonzero(self.state == s)) for s in (KNOWN, BOUNDED, NOT_KNOWN)}


def _arr(x, n: int, fill: float) -> np.ndarray:
    a = np.asarray(fill if x is None else x, float)
    return np.broadcast_to(a, (n,)).astype(float) if a.ndim == 0 else a.reshape(-1).astype(float)


def health_series(
    markers, model_markers, residual_mm, cameras=None, age_s=None, frames=None, poor_fit_mm: float = POOR_FIT_MM
) -> HealthSeries:
    """The health of every row (arrays of one length, or scalars for all): see the module.
    ``frames`` (bool per row, None: all): whether frames were recorded at that row's time;
    ``poor_fit_mm``: the residual line of the model that fitted (the live model's may differ)."""
    n = np.asarray(markers, float).reshape(-1)
    F = len(n)
    M = np.maximum(np.maximum(_arr(model_markers, F, MIN_MARKERS), n), MIN_MARKERS)
    rms = _arr(residual_mm, F, np.nan)
    cam = _arr(cameras, F, MIN_CAMERAS)
    cam = np.where(np.isfinite(cam) & (cam > 0), cam, MIN_CAMERAS)
    age = np.maximum(np.nan_to_num(_arr(age_s, F, 0.0), nan=np.inf), 0.0)
    fr = np.ones(F, bool) if frames is None else np.asarray(frames, bool).reshape(-1)
    n_ok = np.nan_to_num(n, nan=0.0)
    m = np.sqrt(np.clip((n_ok - 2.0) / np.maximum(M - 2.0, 1.0), 0.0, 1.0))
    r = 1.0 / (1.0 + (np.nan_to_num(rms, nan=np.inf) / poor_fit_mm) ** 2)
    c = np.clip(1.0 - 0.4 / np.maximum(cam, 1.0), 0.0, 1.0)
    a = np.exp(-np.minimum(age, 1e6) / AGE_S)
    conf = m * r * c * a
    state = np.full(F, KNOWN, dtype=object)
    why = np.full(F, "", dtype=object)
    fmt = lambda v: f"{v:.2f}"  # noqa: E731

    def mark(sel, st, text):
        sel = sel & (state != NOT_KNOWN) & (why == "")
        for k in np.flatnonzero(sel):
            state[k] = st
            why[k] = text(k)

    mark(~fr, NOT_KNOWN, lambda k: "no frames")
    mark(n_ok < MIN_MARKERS, NOT_KNOWN, lambda k: f"fewer than {MIN_MARKERS} markers ({int(n_ok[k])} of {int(M[k])})")
    mark(~np.isfinite(rms), NOT_KNOWN, lambda k: "no pose fitted")
    mark(age > STALE_S, NOT_KNOWN, lambda k: f"its frames are {fmt(age[k])} s old (over {STALE_S:g} s)")
    mark(rms > poor_fit_mm, BOUNDED, lambda k: f"fit residual {fmt(rms[k])} mm over {poor_fit_mm:g} mm")
    mark(n_ok == MIN_MARKERS, BOUNDED, lambda k: f"{MIN_MARKERS} markers of {int(M[k])}: a wrong point cannot show")
    mark(age > FRESH_S, BOUNDED, lambda k: f"its frames are {fmt(age[k])} s old (over {FRESH_S:g} s)")
    conf = np.where(state == NOT_KNOWN, 0.0, np.clip(conf, 0.0, 1.0))
    return HealthSeries(state.astype(str), why.astype(str), conf)


def pose_health(
    markers: int,
    model_markers: int,
    residual_mm: float,
    cameras: float | None = None,
    age_s: float = 0.0,
    frames: bool = True,
    poor_fit_mm: float = POOR_FIT_MM,
) -> PoseHealth:
    """One pose's health (see the module): what the live estimate gives each instant."""
    return health_series(
        [markers], model_markers, [residual_mm], None if cameras is None else [cameras], [age_s], [frames], poor_fit_mm
    )[0]
