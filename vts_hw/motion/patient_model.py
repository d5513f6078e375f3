"""The patient model: one model of the patient's markers, run two ways -- over a whole recording
(:meth:`PatientModel.fit`, every frame at once: the offline analysis, the reconstruction's
files) and at one instant (:meth:`PatientModel.fit_instant`: the live alert) -- with the same
parameters, the same reference and the same breathing term (issue 33;
docs/decisions/0092-one-patient-model.md).

Marker i at time f is at ``R_f (r_i + v_i s_f) + T_f``: ``r_i`` its reference position (the
reference period: the first still period), ``v_i`` its breathing vector (mm per unit of the
respiratory signal, in the body's reference frame), ``s_f`` the respiratory signal (mm of the
marker that breathes most, + = inhaled, 0 at the reference's mean breath), ``(R_f, T_f)`` the
body's rigid pose (reference -> now, in the model's ``frame``: SPECT or VTS). The pose and the
signal are fitted together per frame (Gauss-Newton on the 7 unknowns, each point weighted by
Tukey's biweight of its residual: a ghost or a mismatch loses its pull), so that no filter runs
over the pose: a body move keeps its shape and its start.

:func:`learn_model` learns ``r`` and ``v`` from the positions of one still period (the live
path's reference seconds; the offline analysis refines ``v`` over every still period of the
recording and builds the same object). A model learned live is saved with the scan session
(:meth:`PatientModel.to_dict`), so that the offline analysis of that session fits the very
model the technologist's alert came from.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from vts_hw.errors import DataError
from vts_hw.motion.markers import rigid_match
from vts_hw.vision.registration import kabsch_batch

__all__ = [
    "PatientModel",
    "InstantPose",
    "learn_model",
    "rigid_poses",
    "back_to_reference",
    "orient",
    "model_columns",
    "MIN_MARKERS",
    "MODEL_FORMAT",
]

MIN_MARKERS = 3
MODEL_FORMAT = "vts-hw patient model v1"
ROBUST_MM = (10.0, 5.0, 3.0)  # Tukey scales of the fit's iterations (the last from then on)
#: a frame's fit stops, at the last robust scale, once its step is below these: rad of the turn,
#: mm of the shift and of the breathing signal (docs/decisions/0093)
CONVERGED = (1e-10, 1e-8)
MAX_MM = 1e5  # a model read back: positions further than this from the origin are not a room's
MAX_VECTOR = 100.0  # ... nor breathing vectors longer than this (they are scaled to the largest: 1)
MIN_BREATH_MM = 0.6  # the marker that breathes most moves at least this (5th to 95th percentile) in
# the reference period, or the model has no breathing term (a still patient)


def back_to_reference(R, T, P):
    """Positions ``P`` (F, M, 3) taken back into the reference frame: ``R^T (P - T)``."""
    return np.einsum("fji,fmj->fmi", R, P - T[:, None])


def rigid_poses(P, seen, ref, scales=(60.0, 40.0), weights=None):
    """A rigid fit per frame of ``ref`` (M, 3; NaN rows unused) onto ``P`` (F, M, 3) that a wrong
    point does not drag: Tukey-weighted Kabsch, its scale shrinking (mm). Returns R, T (the last
    fit) and the weights its residuals give (F, M); no ``scales``: the plain (weighted) fit."""
    has = np.isfinite(ref[:, 0])
    use = seen & has[None]
    ref0 = np.where(has[:, None], ref, 0.0)
    w = use.astype(float) if weights is None else np.where(use, weights, 0.0)
    R = T = None
    for c in scales:
        R, T, _ = kabsch_batch(ref0, P, use, w)
        res = np.linalg.norm(
            np.where(use[..., None], P - (np.einsum("fij,mj->fmi", R, ref0) + T[:, None]), 0.0), axis=2
        )
        u = np.clip(np.nan_to_num(res, nan=np.inf) / c, 0.0, 1.0)
        w = np.where(use, (1 - u**2) ** 2, 0.0)
    if R is None:
        R, T, _ = kabsch_batch(ref0, P, use, w)
    return R, T, w


_EYE3 = np.eye(3)
_EYE7 = np.eye(7)
_TOL7 = np.array([CONVERGED[0]] * 3 + [CONVERGED[1]] * 4)
_CROSS = np.zeros((3, 9))  # q @ _CROSS: [q]x row by row
_CROSS[2, 1] = _CROSS[0, 5] = _CROSS[1, 6] = -1.0
_CROSS[1, 2] = _CROSS[2, 3] = _CROSS[0, 7] = 1.0


def _rotation(w):
    """(F, 3) rotation vectors -> (F, 3, 3) matrices (Rodrigues)."""
    t = np.sqrt(np.sum(w * w, axis=1))
    t = np.where(t > 0, t, 1e-300)[:, None, None]
    h = 0.5 * t
    K = _skew(w)
    # I + sin(t)/t [w]x + (1 - cos t)/t^2 [w]x^2, the last as 2 sin^2(t/2)/t^2 (no loss of digits near 0)
    return _EYE3 + (np.sin(t) / t) * K + (0.5 * (np.sin(h) / h) ** 2) * (K @ K)


def _skew(q):
    """(..., 3) -> (..., 3, 3) cross-product matrices (of finite vectors)."""
    return (q @ _CROSS).reshape(q.shape[:-1] + (3, 3))


@dataclass(frozen=True)
class InstantPose:
    """One instant's fit: ``x -> R x + T`` from the reference, ``s`` the respiratory signal,
    ``rms_mm`` the residual over the points used, ``n_markers`` the markers used."""

    R: np.ndarray
    T: np.ndarray
    s: float
    rms_mm: float
    n_markers: int


@dataclass
class PatientModel:
    """``reference`` (M, 3) mm and ``vectors`` (M, 3) mm per unit of the signal, in ``frame``;
    ``bands``: the markers of each band (indices, in order along the body) and ``band_names``;
    ``period``: (start, end) of the reference period on ``clock``; ``noise_mm``: the model's
    residual RMS over it; ``pose_noise_mm``/``pose_noise_deg``: the still pose's RMS spread
    over it (the centre's move, the turn); ``breathes``: whether the model has a breathing term."""

    reference: np.ndarray
    vectors: np.ndarray
    frame: str = "spect"
    bands: list = field(default_factory=list)
    band_names: list = field(default_factory=list)
    period: tuple = (float("nan"), float("nan"))
    clock: str = "host"
    noise_mm: float = float("nan")
    pose_noise_mm: float = float("nan")
    pose_noise_deg: float = float("nan")
    breathes: bool = True

    def __post_init__(self):
        self.reference = np.asarray(self.reference, float).reshape(-1, 3)
        self.vectors = np.asarray(self.vectors, float).reshape(-1, 3)
        if not self.bands:
            self.bands = [list(range(len(self.reference)))]
            self.band_names = self.band_names or ["band 1"]

    @property
    def n_markers(self) -> int:
        return len(self.reference)

    @property
    def known(self) -> np.ndarray:
        """(M,) markers with a reference position."""
        return np.isfinite(self.reference).all(axis=1)

    @property
    def centre(self) -> np.ndarray:
        """The reference centroid of the markers (mm): where a move is measured."""
        return self.reference[self.known].mean(axis=0)

    def band_of(self) -> np.ndarray:
        """(M,) each marker's band index (-1: none)."""
        out = np.full(self.n_markers, -1)
        for k, g in enumerate(self.bands):
            out[list(g)] = k
        return out

    def positions(self, R, T, s) -> np.ndarray:
        """(F, M, 3): where the model puts each marker for poses ``R`` (F,3,3), ``T`` (F,3), ``s`` (F,)."""
        body = self.reference[None] + self.vectors[None] * np.nan_to_num(np.asarray(s, float))[:, None, None]
        return np.einsum("fij,fmj->fmi", R, body) + T[:, None]

    # -- the fit ---------------------------------------------------------------------------------
    def fit(self, P, seen=None, R0=None, T0=None, s0=None, iterations: int = 6, robust_mm=ROBUST_MM):
        """Per frame, ``(R, T, s)`` minimising ``sum_i |P_i - R (r_i + v_i s) - T|^2`` over the
        markers seen (Gauss-Newton from ``R0, T0, s0``; without them from a robust rigid fit),
        each point weighted by Tukey's biweight of its residual at the scale ``robust_mm[k]`` in
        iteration k; at most ``iterations``, a frame stopping once, at the last scale, its step
        is below :data:`CONVERGED` (the same frame stops at the same step however many frames are
        fitted with it). Returns R (F,3,3), T (F,3), s (F,), rms (F,) mm over the points with
        weight, and used (F, M): the points that kept a weight; NaN poses with fewer than three."""
        P = np.asarray(P, float)
        seen = np.isfinite(P[..., 0]) if seen is None else np.asarray(seen, bool)
        ref, v = self.reference, self.vectors
        known = np.isfinite(ref).all(axis=1) & np.isfinite(v).all(axis=1)
        seen = seen & known[None]
        ref, v = np.nan_to_num(ref), np.nan_to_num(v)
        F, M = seen.shape
        if R0 is None:
            R0, T0, _ = rigid_poses(P, seen, np.where(known[:, None], ref, np.nan))
        ok = (seen.sum(axis=1) >= MIN_MARKERS) & np.isfinite(R0[:, 0, 0])
        R = np.where(ok[:, None, None], R0, np.eye(3))
        T = np.where(ok[:, None], T0, 0.0)
        s = np.zeros(F) if s0 is None else np.where(np.isfinite(s0), s0, 0.0)
        breathing = self.breathes and bool(np.any(np.abs(v) > 0))
        Pz = np.where(seen[..., None], P, 0.0)
        seen_f = seen.astype(float)
        wm = seen_f
        active = ok.copy()  # frames still iterating
        last_scale = max(len(robust_mm) - 1, 0) if robust_mm else 0
        J = np.zeros((F, M, 3, 7))
        J[..., 3:6] = _EYE3
        for it in range(iterations):
            Rt = R.transpose(0, 2, 1)
            q = (ref[None] + v[None] * s[:, None, None]) @ Rt  # (F, M, 3): R (r + v s)
            e = Pz - q - T[:, None]
            c = robust_mm[min(it, len(robust_mm) - 1)] if robust_mm else np.inf
            w = np.where(seen, (1.0 - np.minimum(np.sum(e * e, axis=2) / (c * c), 1.0)) ** 2, 0.0)
            enough = np.count_nonzero(w, axis=1) >= MIN_MARKERS
            w = np.where(enough[:, None], w, seen_f)  # too few left: unweighted
            wm = np.where(active[:, None], w, wm)  # a frame stopped keeps its own
            # J = [-[q]x, I, R v] per point, its rows weighted by w
            J[..., :3] = -_skew(q)
            J[..., 6] = v @ Rt
            Jw = (J * w[..., None, None]).reshape(F, 3 * M, 7)
            Jt = Jw.transpose(0, 2, 1)
            N = Jt @ Jw
            g = (Jt @ (e * w[..., None]).reshape(F, 3 * M, 1))[..., 0]
            N += (1e-9 * (np.trace(N, axis1=1, axis2=2) / 7.0 + 1e-9))[:, None, None] * _EYE7
            if not breathing:
                N[:, 6, :] = 0.0
                N[:, :, 6] = 0.0
                N[:, 6, 6] = 1.0
                g[:, 6] = 0.0
            if not active.all():
                N[~active] = _EYE7
                g[~active] = 0.0
            dx = np.linalg.solve(N, g[..., None])[..., 0]
            R = _rotation(dx[:, :3]) @ R
            T = T + dx[:, 3:6]
            s = s + dx[:, 6]
            if it >= last_scale:
                active &= ~(np.abs(dx) < _TOL7).all(axis=1)
                if not active.any():
                    break
        used = seen & (wm > 0)
        res = np.where(
            used[..., None], P - (ref[None] + v[None] * s[:, None, None]) @ R.transpose(0, 2, 1) - T[:, None], 0.0
        )
        rms = np.sqrt(np.sum(res**2, axis=(1, 2)) / np.maximum(used.sum(axis=1), 1))
        if not ok.all():  # (R, T, s, rms are this call's own arrays)
            R, T, s = R.copy(), T.copy(), s.copy()
            R[~ok], T[~ok], s[~ok], rms[~ok] = np.nan, np.nan, np.nan, np.nan
            used[~ok] = False
        return R, T, s, rms, used

    def fit_instant(self, idx, x, last: InstantPose | None = None, iterations: int = 6) -> InstantPose | None:
        """The pose of one instant: the positions ``x`` (K, 3) of the model's markers ``idx`` (K,),
        fitted as :meth:`fit` fits a frame of a recording (started from ``last``, the previous
        instant's pose, when given). None with fewer than three markers or no pose."""
        idx = np.asarray(idx, int)
        if len(idx) < MIN_MARKERS:
            return None
        P = np.full((1, self.n_markers, 3), np.nan)
        P[0, idx] = np.asarray(x, float).reshape(-1, 3)
        seen = np.isfinite(P[..., 0])
        if last is None:
            R0 = T0 = s0 = None
        else:
            R0, T0, s0 = last.R[None], last.T[None], np.array([last.s])
        R, T, s, rms, used = self.fit(P, seen, R0, T0, s0, iterations=iterations)
        if not np.isfinite(T[0, 0]):
            return None
        return InstantPose(R[0], T[0], float(s[0]), float(rms[0]), int(used[0].sum()))

    # -- the session's copy ----------------------------------------------------------------------
    def to_dict(self) -> dict:
        def r(a):
            return [[None if not np.isfinite(x) else round(float(x), 6) for x in row] for row in a]

        def f(x):
            return None if x is None or not np.isfinite(x) else round(float(x), 6)

        return {
            "format": MODEL_FORMAT,
            "frame": self.frame,
            "clock": self.clock,
            "reference_mm": r(self.reference),
            "breathing_vectors": r(self.vectors),
            "bands": [list(map(int, g)) for g in self.bands],
            "band_names": list(self.band_names),
            "period": [f(self.period[0]), f(self.period[1])],
            "noise_mm": f(self.noise_mm),
            "pose_noise_mm": f(self.pose_noise_mm),
            "pose_noise_deg": f(self.pose_noise_deg),
            "breathes": bool(self.breathes),
        }

    @classmethod
    def from_dict(cls, d) -> PatientModel:
        """The model a session saved (DataError naming what is wrong)."""
        if not isinstance(d, dict) or d.get("format") != MODEL_FORMAT:
            raise DataError(f"not a patient model (format {MODEL_FORMAT!r} expected)")
        try:
            ref = np.array([[np.nan if x is None else float(x) for x in row] for row in d["reference_mm"]], float)
            vec = np.array([[np.nan if x is None else float(x) for x in row] for row in d["breathing_vectors"]], float)
            if ref.ndim != 2 or ref.shape[1:] != (3,) or vec.shape != ref.shape or len(ref) < MIN_MARKERS:
                raise ValueError("reference_mm and breathing_vectors must be the same list of 3 or more [x, y, z]")
            if np.isfinite(ref).all(axis=1).sum() < MIN_MARKERS or not (np.abs(ref[np.isfinite(ref)]) <= MAX_MM).all():
                raise ValueError(f"reference_mm needs 3 or more finite positions within {MAX_MM:g} mm of the origin")
            if not np.isfinite(vec).all() or not (np.abs(vec) <= MAX_VECTOR).all():
                raise ValueError(f"breathing_vectors must be finite, each part within {MAX_VECTOR:g}")
            bands = [[int(i) for i in g] for g in d["bands"]]
            if any(i < 0 or i >= len(ref) for g in bands for i in g):
                raise ValueError("a band names a marker the model does not have")

            def num(x):
                return float("nan") if x is None else float(x)

            period = tuple(num(x) for x in d["period"])
            if len(period) != 2:
                raise ValueError("period must be [start, end]")
            frame = str(d["frame"])
            if frame not in ("spect", "vts"):
                raise ValueError(f"frame {frame!r} is not spect or vts")
            return cls(
                ref,
                vec,
                frame,
                bands,
                [str(n) for n in d["band_names"]],
                period,
                str(d["clock"]),
                num(d["noise_mm"]),
                num(d["pose_noise_mm"]),
                num(d["pose_noise_deg"]),
                bool(d["breathes"]),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise DataError(f"patient model: {exc}") from None


def _principal(D, seen):
    """``s`` (F,): the displacements ``D`` (F, M, 3) projected on their first principal direction
    (over the frames with every marker seen when there are enough, else with the unseen as 0)."""
    F, M, _ = D.shape
    X = np.where(seen[..., None], D, 0.0).reshape(F, -1)
    full = seen.all(axis=1)
    rows = X[full] if full.sum() >= 10 else X
    u = np.linalg.svd(rows - rows.mean(axis=0), full_matrices=False)[2][0].reshape(M, 3)
    num = np.einsum("fmi,mi->f", np.where(seen[..., None], D, 0.0), u)
    den = np.einsum("fm,m->f", seen.astype(float), np.sum(u * u, axis=1))
    return np.where(den > 0.3 * np.sum(u * u), num / np.maximum(den, 1e-12), np.nan)


def _regress(D, seen, s):
    """Per marker ``a_m, v_m``: ``D_fm ~ a_m + v_m (s_f - mean s)`` over the frames seen."""
    M = D.shape[1]
    a, v = np.full((M, 3), np.nan), np.zeros((M, 3))
    for m in range(M):
        ok = seen[:, m] & np.isfinite(s)
        if ok.sum() < 3:
            continue
        ds = s[ok] - s[ok].mean()
        d = D[ok, m]
        a[m] = d.mean(axis=0)
        den = float(ds @ ds)
        if den > 0:
            v[m] = ds @ (d - a[m]) / den
    return a, v


def orient(vectors, s, frame: str):
    """``(vectors, s, scale)`` scaled to mm of the marker that breathes most, + = inhaled: up
    (+Y in the SPECT frame; -Y, the image's down, in the VTS frame of the first camera)."""
    norms = np.linalg.norm(np.nan_to_num(vectors), axis=1)
    scale = float(norms.max()) if norms.size else 0.0
    if scale <= 0:
        return vectors, s, 0.0
    up = np.array([0.0, 1.0, 0.0]) if frame == "spect" else np.array([0.0, -1.0, 0.0])
    sign = 1.0 if float(np.sum(np.nan_to_num(vectors) @ up)) >= 0 else -1.0
    return vectors / (scale * sign), s * scale * sign, scale


def learn_model(
    t,
    P,
    seen=None,
    *,
    frame: str = "spect",
    bands=None,
    band_names=None,
    clock: str = "host",
    iterations: int = 3,
    min_breath_mm: float = MIN_BREATH_MM,
) -> PatientModel:
    """The model from one still period: positions ``P`` (S, M, 3) at times ``t`` (S,) (NaN where a
    marker was not seen; each marker needs a few instants). The reference is the markers' mean
    (their breathing's mean level), the breathing vectors each marker's displacement per unit of
    the first principal component of the displacements from it -- the body keeps still over the
    period, so one pose holds for all of it and the rigid part of breathing (the chest lifting)
    is in the vectors, not in the poses; ``iterations`` of the fit's from there. A patient whose most breathing
    marker moves less than ``min_breath_mm`` gets no breathing term (fitted rigidly)."""
    t = np.asarray(t, float)
    P = np.asarray(P, float)
    seen = np.isfinite(P[..., 0]) if seen is None else np.asarray(seen, bool) & np.isfinite(P[..., 0])
    if P.ndim != 3 or P.shape[1] < MIN_MARKERS:
        raise DataError(f"a patient model needs {MIN_MARKERS} or more markers")
    ref = np.array(
        [P[seen[:, m], m].mean(axis=0) if seen[:, m].sum() >= 3 else [np.nan] * 3 for m in range(P.shape[1])]
    )
    if np.isfinite(ref[:, 0]).sum() < MIN_MARKERS:
        raise DataError(f"fewer than {MIN_MARKERS} markers were seen often enough for a patient model")
    # the body keeps still over the period: one pose for all of it (the reference's), so that
    # the rigid part of breathing (the chest lifting) goes into the vectors, not into the pose
    model = PatientModel(
        ref, np.zeros_like(ref), frame, bands or [], band_names or [], (float(t[0]), float(t[-1])), clock
    )
    D = P - ref[None]
    s = _principal(D, seen)
    a, v = _regress(D, seen, s)
    model.reference = ref + np.nan_to_num(a)
    model.vectors = v
    s = s - np.nanmean(s)
    R, T, s, _, _ = model.fit(P, seen, None, None, s, iterations=max(6, iterations))
    proj = np.where(
        seen,
        np.einsum("fmi,mi->fm", back_to_reference(R, T, P) - model.reference[None], np.nan_to_num(model.vectors)),
        np.nan,
    )
    lead = int(np.argmax(np.linalg.norm(model.vectors, axis=1)))
    lp = proj[:, lead][np.isfinite(proj[:, lead])]
    spread = float(np.percentile(lp, 95) - np.percentile(lp, 5)) if len(lp) >= 3 else 0.0
    spread /= max(float(np.linalg.norm(model.vectors[lead])), 1e-12)
    if spread < min_breath_mm:
        model.vectors = np.zeros_like(model.vectors)
        model.breathes = False
    else:
        model.vectors, s, _ = orient(model.vectors, s, frame)
        # 0 at the period's mean breath: the reference holds the mean, the signal its offsets
        mean_s = float(np.nanmean(s))
        model.reference = model.reference + model.vectors * mean_s
    R, T, s, rms, used = model.fit(P, seen, R, T, None if not model.breathes else s - np.nanmean(s))
    ok = np.isfinite(T[:, 0])
    c = model.centre
    moves = np.linalg.norm(np.einsum("fij,j->fi", R[ok], c) + T[ok] - c, axis=1)
    turns = np.degrees(Rotation.from_matrix(R[ok]).magnitude()) if ok.any() else np.zeros(0)

    def q(x):
        return float(np.sqrt(np.mean(np.square(x)))) if len(x) else float("nan")

    model.noise_mm, model.pose_noise_mm, model.pose_noise_deg = q(rms[ok]), q(moves), q(turns)
    return model


def model_columns(t, P, model: PatientModel, first_s: float = 10.0, gate_mm: float = 10.0) -> list[list[int]]:
    """Which columns of a marker table ``P`` (F, C, 3) at times ``t`` are which of the model's
    markers: per model marker the columns (a marker tracked in pieces has several; none: []).
    First the columns seen in the first ``first_s`` seconds, matched to the reference as one
    rigid body (the body may lie elsewhere than in the reference); then every other column by
    where its points lie in the body's frame (taken back through the poses of the markers known
    so far, the breathing taken out): the model marker within ``gate_mm`` of its median, if its
    frames do not overlap those of a column already given to that marker."""
    F, C, _ = P.shape
    seen = np.isfinite(P[..., 0])
    M = model.n_markers
    out: list[list[int]] = [[] for _ in range(M)]
    if C == 0 or not seen.any():
        return out
    t0 = float(t[np.flatnonzero(seen.any(axis=1))[0]])
    early = t <= t0 + first_s
    cols = [c for c in range(C) if (seen[early, c]).sum() >= 3]
    starts = np.array([np.median(P[early & seen[:, c], c], axis=0) for c in cols]).reshape(-1, 3)
    ref = model.reference
    known = np.flatnonzero(model.known)
    for i, a in rigid_match(starts, ref[known]):
        out[int(known[a])].append(cols[i])
    taken = {c for cs in out for c in cs}
    if sum(map(len, out)) < MIN_MARKERS:
        return out
    Pm = np.full((F, M, 3), np.nan)
    for m, cs in enumerate(out):
        for c in cs:
            Pm[:, m] = P[:, c]
    R, T, s, _, _ = model.fit(Pm)
    body = back_to_reference(R, T, P)  # (F, C, 3)
    for c in range(C):
        if c in taken:
            continue
        ok = seen[:, c] & np.isfinite(T[:, 0])
        if ok.sum() < 3:
            continue
        # its points in the body frame, less each candidate's breathing at that instant
        d = np.linalg.norm(
            body[ok, c][:, None, :] - (ref[None] + model.vectors[None] * np.nan_to_num(s[ok])[:, None, None]), axis=2
        )
        med = np.nanmedian(d, axis=0)
        for m in np.argsort(med):
            if not np.isfinite(med[m]) or med[m] > gate_mm:
                break
            if not any((seen[:, c] & seen[:, o]).any() for o in out[m]):
                out[int(m)].append(c)
                break
    return out
