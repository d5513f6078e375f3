"""The motion analysis of one session's marker tracks, start to end (method and reasons:
docs/decisions/0035-breathing-and-body-motion.md).

1. The patient's markers (:mod:`.bands`): those that breathe or move, grouped into bands.
2. A first pose: the rigid fit (Kabsch) of every frame to a provisional reference (the first
   seconds). What is left in the body's frame is the non-rigid part of breathing: its first
   principal component (band-passed) is the first respiratory signal (:mod:`.respiration`).
3. Still periods: the markers carried by the first pose, minus their regression on that signal
   (the rigid part breathing puts into the pose), give a speed; frames away from fast runs
   are still. The **reference** is the first still period (its mean positions).
4. Breathing vectors per marker: displacement per unit of the signal, regressed over the still
   periods (each run detrended on its own, its pose held fixed: the rigid part of breathing is
   in the vectors, so it leaves the pose).
5. Pose and breathing together per frame (:meth:`.patient_model.PatientModel.fit`); the
   respiratory signal is now the fitted one (its slow part kept). Steps 3-5 once more with the
   still periods from the new pose.
6. Events and motion states (:mod:`.events`, :mod:`.states`); breaths seen whole, their phase
   and rate (:mod:`.cycles`).

Time without frames (issue 20; docs/decisions/0046-time-without-frames.md): the series is first
put on the scan's frame grid (:mod:`.timeline`): a row without markers for every frame time the
recording lacks, so that every share is a share of the scan's time. A stretch without a pose of
at most ``bridge_s``, with the same pose on both sides, may join a still period (for the
reference and the breathing vectors); nothing is fitted in it, and no breath is counted over it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import uniform_filter1d

from vts_hw.errors import DataError
from vts_hw.motion.bands import Bands, find_bands
from vts_hw.motion.body_pose import POOR_FIT_MM, BodyPose
from vts_hw.motion.cycles import breathing_figures, find_breaths, signal_noise
from vts_hw.motion.events import MotionEvent, find_events
from vts_hw.motion.markers import MarkerSeries
from vts_hw.motion.patient_model import PatientModel, back_to_reference, model_columns, orient, rigid_poses
from vts_hw.motion.respiration import Respiration, breathing_vectors, principal_signal
from vts_hw.motion.signal import fill_gaps, highpass
from vts_hw.motion.states import BRIDGE_S, MotionState, cover_states, motion_states
from vts_hw.motion.timeline import Timeline, on_grid
from vts_hw.motion.timeline import runs as _runs

__all__ = ["MotionResult", "MotionSettings", "analyze_motion", "MotionEvent", "MotionState"]

BREATH_MM = 0.25  # a marker breathes above this RMS at 0.08-1 Hz (bands.find_bands's default)


@dataclass(frozen=True)
class MotionSettings:
    """``state_mm``/``state_deg``: a motion state's extent (rig.yaml ``motion:``);
    ``event_mm``/``event_deg``: the least change an event makes; ``min_speed``: mm/s a
    marker must move at before anything counts as motion; ``ref_min_s``/``ref_max_s``: the
    reference still period's least and largest length; ``margin_s``: frames this close to
    motion are not still; ``iterations``: passes of steps 3-5; ``outlier_rigid_mm``/``outlier_mm``: a
    point further than this from the rigid fit (breathing not modelled) / from the fit with breathing
    is left out of that frame (a wrong match, a ghost)."""

    state_mm: float = 2.0
    state_deg: float = 1.0
    event_mm: float = 1.0
    event_deg: float = 0.5
    min_speed: float = 1.0
    ref_min_s: float = 3.0
    ref_max_s: float = 10.0
    margin_s: float = 1.0
    iterations: int = 2
    outlier_rigid_mm: float = 40.0
    max_outlier_share: float = 0.5
    outlier_mm: float = 3.0
    bridge_s: float = BRIDGE_S


@dataclass
class MotionResult:
    """What :func:`analyze_motion` found (times on ``series.clock``, positions in ``series.frame``).
    Every per-frame array has a row per frame time of the scan (``timeline``), frames or not."""

    series: MarkerSeries
    bands: Bands
    patient: MarkerSeries
    reference: np.ndarray  # (M, 3) the patient's markers in the reference pose
    reference_period: tuple
    pose: BodyPose
    respiration: Respiration
    events: list
    states: list
    speed: np.ndarray
    moving: np.ndarray
    still: np.ndarray
    thresholds: dict
    settings: MotionSettings
    notes: list = field(default_factory=list)
    timeline: Timeline | None = None
    covered: np.ndarray | None = None  # (F,) rows some motion state covers (states.cover_states)
    bridged: list = field(default_factory=list)
    model: PatientModel | None = None  # the patient model the poses were fitted with (learned here or given)

    @property
    def unknown(self) -> list[dict]:
        """The stretches without a pose, with why (:meth:`Timeline.unknown`)."""
        return self._timeline().unknown(self.pose.valid)

    @property
    def gaps(self) -> list:
        """[start, end] times without a pose (no frames, or fewer than 3 markers)."""
        return [[u["t_start"], u["t_end"]] for u in self.unknown]

    @property
    def coverage(self) -> dict:
        """Time with a pose against the scan's duration (:meth:`Timeline.coverage`)."""
        return self._timeline().coverage(self.pose.valid)

    def _timeline(self) -> Timeline:
        if self.timeline is None:  # analyze_motion always gives one
            raise ValueError("this motion result was made without its timeline")
        return self.timeline


def _dilate(mask, n):
    if n <= 0 or not mask.any():
        return mask.copy()
    k = np.ones(2 * n + 1)
    return np.convolve(mask.astype(float), k, mode="same") > 0


def _reference(P, seen, sel, R=None, T=None):
    """Mean positions over the frames ``sel``; a marker unseen there: its median over every
    frame taken back through the pose (R, T), NaN without one."""
    Q = P if R is None else back_to_reference(R, T, P)
    M = P.shape[1]
    ref = np.full((M, 3), np.nan)
    for m in range(M):
        ok = sel & seen[:, m]
        if ok.sum() >= 3:
            ref[m] = P[ok, m].mean(axis=0)
        elif R is not None:
            ok = seen[:, m] & np.isfinite(Q[:, m, 0])
            if ok.any():
                ref[m] = np.median(Q[ok, m], axis=0)
    return ref


def _pose_with_reference(P, seen, ref, weights=None):
    R, T, _ = rigid_poses(P, seen, ref, (), weights)
    return R, T


def _robust_pose(P, seen, ref, scales=(60.0, 40.0)):
    """A rigid fit per frame that a wrong point does not drag (:func:`.patient_model.rigid_poses`)."""
    return rigid_poses(P, seen, ref, scales)


def _segment_poses(t, P, seen, ref, still):
    """Positions in the body frame with one pose per still run (NaN elsewhere)."""
    D = np.full(P.shape, np.nan)
    for a, b in _runs(still):
        mean = np.array(
            [P[a:b, m][seen[a:b, m]].mean(axis=0) if seen[a:b, m].any() else [np.nan] * 3 for m in range(P.shape[1])]
        )
        ok = np.isfinite(mean[:, 0])
        if ok.sum() < 3:
            continue
        R, T, _ = _robust_pose(mean[None], ok[None], ref, (20.0, 5.0, 2.0))
        D[a:b] = back_to_reference(np.repeat(R, b - a, 0), np.repeat(T, b - a, 0), P[a:b])
    return D


def _provisional_moving(t, pose_pts, s, settings, fs):
    """``(moving, Xc)``: frames moving, from the carried markers minus their regression on the
    signal (``Xc``, (F, M, 3), NaN where the pose is unknown). No speed is made across time
    without a pose: a frame whose window reaches into it is not called moving."""
    X = pose_pts.reshape(len(t), -1)
    ok = np.isfinite(X).all(axis=1) & np.isfinite(s)
    if ok.sum() < 20:
        return np.zeros(len(t), bool), np.full(pose_pts.shape, np.nan)
    hx = highpass(t, np.where(ok[:, None], X, np.nan), 0.1)
    hs = highpass(t, np.where(ok, s, np.nan)[:, None], 0.1)[:, 0]
    k = (hs[ok] @ hx[ok]) / max(float(hs[ok] @ hs[ok]), 1e-12)
    Xc = X - np.outer(np.nan_to_num(s), k)
    clean = np.where(ok[:, None], Xc, np.nan).reshape(pose_pts.shape)
    h = max(1, int(round(0.2 * fs)))
    Xs = uniform_filter1d(fill_gaps(t, Xc), 2 * h + 1, axis=0).reshape(
        pose_pts.shape
    )  # provisional: smearing is harmless
    sp = np.zeros(len(t))
    if len(t) > 2 * h:
        sp[h:-h] = np.linalg.norm(Xs[2 * h :] - Xs[: -2 * h], axis=2).max(axis=1) / (t[2 * h :] - t[: -2 * h])
    near = uniform_filter1d((~ok).astype(float), 4 * h + 1) > 0  # within 2 h rows of unknown time
    sp = np.where(near, 0.0, np.nan_to_num(sp))
    sig = 1.4826 * np.median(np.abs(sp - np.median(sp)))
    return sp > max(2.0 * settings.min_speed, np.median(sp) + 6 * sig), clean


def _bridged(t, still, valid, X, period, bridge_s, tol_mm, settle_s=1.0):
    """``still`` with the stretches without a pose of at most ``bridge_s`` between still frames
    added where the markers ``X`` (F, K, 3; breathing out) agree on both sides within
    ``tol_mm`` (medians over ``settle_s``): a still period may span them (nothing is fitted
    in them: they have no markers)."""
    out = still.copy()
    F = len(t)
    for a, b in _runs(~valid):
        if a == 0 or b == F or (b - a) * period > bridge_s + 1e-9 or not (still[a - 1] and still[b]):
            continue
        before = still & (t >= t[a] - settle_s) & (t < t[a])
        after = still & (t > t[b - 1]) & (t <= t[b - 1] + settle_s)
        if not before.any() or not after.any():
            continue
        d = np.nanmedian(X[after], axis=0) - np.nanmedian(X[before], axis=0)
        if np.nanmax(np.linalg.norm(d, axis=1)) < tol_mm:
            out[a:b] = True
    return out


def _not_with_the_body(P, seen, ref, bands, bad, limit_mm: float = 5.0, share: float = 0.2) -> dict:
    """The markers taken for the patient's because they *moved* (not because they breathe) that
    do not move with the body: further than ``limit_mm`` from where the rigid fit of the other
    markers carries them in more than ``share`` of their frames (a wall marker whose blob met a
    band marker's in one camera for a while "moves" too, and after a body move it pulled the fit)."""
    out = {}
    for m in range(P.shape[1]):
        if m in bad or bands.breath_rms_mm[bands.patient[m]] >= BREATH_MM or not np.isfinite(ref[m]).all():
            continue
        others = seen.copy()
        others[:, m] = False
        R, T = _pose_with_reference(P, others, ref)
        ok = seen[:, m] & np.isfinite(T[:, 0])
        if ok.sum() < 10:
            continue
        res = np.linalg.norm(P[ok, m] - (np.einsum("fij,j->fi", R[ok], ref[m]) + T[ok]), axis=1)
        off = float(np.mean(res > limit_mm))
        if off > share:
            out[m] = (
                f"moved, but not with the body: off the rigid fit of the others by over {limit_mm:g} mm "
                f"in {100 * off:.0f} % of its frames: not the patient's"
            )
    return out


def _inliers(P, seen, model, limit_mm):
    """``seen`` without the points further than ``limit_mm`` from the model (F, M, 3)."""
    res = np.linalg.norm(np.where(seen[..., None], P - model, 0.0), axis=2)
    return seen & ~(np.nan_to_num(res, nan=np.inf) > limit_mm)


def analyze_motion(
    series: MarkerSeries,
    settings: MotionSettings | None = None,
    *,
    span: tuple | None = None,
    missing=(),
    model: PatientModel | None = None,
) -> MotionResult:
    """The whole analysis (see the module). ``span``: (first, last) frame time the recording
    should hold, on the series' clock (:mod:`vts_hw.recording.extent`; None: the first and last
    frame); ``missing``: sentences on what the recording lacks, kept with the result. DataError
    when the patient's markers cannot be found or no still period of ``ref_min_s`` exists for the
    reference. ``model``: the patient model to fit (the one the scan's live path learned,
    :func:`with_model`) instead of one learned here."""
    st = settings or MotionSettings()
    series, timeline = on_grid(series, span, missing)
    if model is not None:
        return with_model(series, timeline, model, st)
    bands = find_bands(series, frames=timeline.frames)
    S = series.subset(bands.patient)
    t, P, seen = S.t, S.P, S.seen
    seen_all = seen.copy()
    period = timeline.period
    fs = 1.0 / period
    notes = []
    # 2. provisional reference and pose; the first respiratory signal
    t_first = float(t[timeline.frames][0])
    sel0 = (t >= t_first) & (t <= t_first + st.ref_max_s)
    ref = _reference(P, seen, sel0)
    R0, T0 = _pose_with_reference(P, seen, ref)
    ref = _reference(P, seen, sel0, R0, T0)
    R0, T0, w = _robust_pose(P, seen, ref)
    # a marker the robust fit leaves out in most frames is not one of the patient's (a wrong
    # match, a ghost made of pieces); a single point far off the fit is left out of its frame
    out_share = 1.0 - (seen & (w > 0)).sum(axis=0) / np.maximum(seen.sum(axis=0), 1)
    bad = {
        m: (
            f"off the rigid fit of the others in {100 * out_share[m]:.0f} % of its frames: not the "
            f"patient's (a wrong match?)"
        )
        for m in range(P.shape[1])
        if out_share[m] > st.max_outlier_share
    }
    bad.update(_not_with_the_body(P, seen, ref, bands, bad))
    if bad and P.shape[1] - len(bad) >= 3:
        for m, why in bad.items():
            col = bands.patient[m]
            bands.why[col] = why
            notes.append(f"{S.label(m)} left out: {bands.why[col]}")
        keep = [m for m in range(P.shape[1]) if m not in bad]
        bands.patient = [bands.patient[m] for m in keep]
        bands.groups = [[c for c in g if c in bands.patient] for g in bands.groups]
        bands.groups = [g for g in bands.groups if g]
        S = series.subset(bands.patient)
        P, seen, ref = S.P, S.seen, ref[keep]
        seen_all = seen.copy()
        R0, T0, w = _robust_pose(P, seen, ref)
    seen = _inliers(P, seen, np.einsum("fij,mj->fmi", R0, ref) + T0[:, None], st.outlier_rigid_mm)
    R0, T0 = _pose_with_reference(P, seen, ref)
    D = back_to_reference(R0, T0, P) - ref[None]
    D[~seen] = np.nan
    s, _, _ = principal_signal(t, D)
    pts = np.einsum("fij,mj->fmi", R0, ref) + T0[:, None]
    moving, X_still = _provisional_moving(t, pts, s, st, fs)
    tol = 2.0 * st.event_mm  # the first pose still holds some breathing
    v = np.zeros_like(ref)
    R, T = R0, T0
    ref_period = (t_first, t_first)
    for _ in range(max(1, st.iterations)):
        valid = np.isfinite(R[:, 0, 0])
        still = valid & ~_dilate(moving, int(round(st.margin_s * fs)))
        still_b = _bridged(t, still, valid, X_still, period, st.bridge_s, tol)
        runs = [
            (a, b)
            for a, b in _runs(still_b)
            if t[b - 1] - t[a] >= st.ref_min_s and still[a:b].sum() * period >= 0.5 * st.ref_min_s
        ]
        if not runs:
            raise DataError(
                f"no still period of {st.ref_min_s:g} s for the reference: the patient moved "
                f"all the time (or the markers were not seen)"
            )
        a, b = runs[0]
        b = min(b, a + int(round(st.ref_max_s * fs)))
        ref_sel = np.zeros(len(t), bool)
        ref_sel[a:b] = still[a:b]
        ref_period = (float(t[a]), float(t[b - 1]))
        ref = _reference(P, seen, ref_sel, R, T)
        Dseg = _segment_poses(t, P, seen, ref, still_b) - ref[None]
        v = breathing_vectors(t, Dseg, s, still_b)
        R0, T0, _ = _robust_pose(P, seen, ref)
        model = PatientModel(ref, v, series.frame)
        R, T, s, rms, _ = model.fit(P, seen, R0, T0, s)
        seen_in = _inliers(P, seen_all, model.positions(R, T, s), st.outlier_mm)
        if (seen_in != seen).any():
            seen = seen_in
            R, T, s, rms, _ = model.fit(P, seen, R0, T0, s)
        known = ref[np.isfinite(ref).all(axis=1)]
        pose = BodyPose(t, R, T, s, rms, seen.sum(axis=1), known.mean(axis=0))
        events, speed, moving, thr = find_events(
            pose, known, min_speed=st.min_speed, event_mm=st.event_mm, event_deg=st.event_deg
        )
        X_still = np.where(pose.valid[:, None, None], pose.points(known), np.nan)
        tol = st.event_mm
    # scale and sign of the respiratory signal: mm of the marker that breathes most, + = inhaled
    breathes = bool(np.any(bands.breath_rms_mm[bands.patient] >= BREATH_MM)) and bool(np.any(v))
    if breathes:
        v, s, _ = orient(v, s, series.frame)
        mean_s = float(np.nanmean(s[ref_sel]))
        s = s - mean_s
        ref = ref + v * mean_s  # the model's reference: the period's mean breath (s = 0)
    model = PatientModel(
        ref,
        v,
        series.frame,
        [[bands.patient.index(c) for c in g] for g in bands.groups],
        [],
        ref_period,
        series.clock,
        breathes=breathes,
    )
    return _finish(series, timeline, bands, S, model, pose, s, events, speed, moving, still, thr, st, notes)


def with_model(series, timeline, model: PatientModel, st: MotionSettings) -> MotionResult:
    """The analysis with a patient model given (learned live during the scan): its markers found
    among the series' columns (:func:`.patient_model.model_columns`), every frame fitted with it,
    then the events, breaths and states as when the model is learned here."""
    if model.frame != series.frame:
        raise DataError(
            f"the patient model is in the {model.frame.upper()} frame and the marker tracks in the "
            f"{series.frame.upper()} frame: they cannot be fitted together"
        )
    t, F = series.t, len(series.t)
    cols = model_columns(t, series.P, model)
    matched = [m for m, cs in enumerate(cols) if cs]
    if len(matched) < 3:
        raise DataError(
            f"only {len(matched)} of the patient model's {model.n_markers} markers were found in the "
            f"recording's tracks (3 needed): the model does not belong to this recording?"
        )
    P = np.full((F, model.n_markers, 3), np.nan)
    for m, cs in enumerate(cols):
        for c in cs:
            fill = np.isfinite(series.P[:, c, 0]) & ~np.isfinite(P[:, m, 0])
            P[fill, m] = series.P[fill, c]
    seen = np.isfinite(P[..., 0])
    R0, T0, _ = rigid_poses(P, seen, model.reference)
    R, T, s, rms, used = model.fit(P, seen, R0, T0)
    seen_in = _inliers(P, seen, model.positions(R, T, s), st.outlier_mm)
    if (seen_in != seen).any():
        R, T, s, rms, used = model.fit(P, seen_in, R0, T0, s)
    known = model.reference[model.known]
    pose = BodyPose(t, R, T, s, rms, used.sum(axis=1), model.centre)
    events, speed, moving, thr = find_events(
        pose, known, min_speed=st.min_speed, event_mm=st.event_mm, event_deg=st.event_deg
    )
    still = pose.valid & ~_dilate(moving, int(round(st.margin_s / timeline.period)))
    first = [cs[0] if cs else None for cs in cols]
    n = series.P.shape[1]
    why = ["not one of the patient model's markers" for _ in range(n)]
    for m, cs in enumerate(cols):
        for c in cs:
            why[c] = f"the patient model's marker {m + 1}"
    bands = Bands(
        [c for c in first if c is not None],
        [[first[m] for m in g if first[m] is not None] for g in model.bands],
        np.zeros(n),
        np.zeros(n),
        series.seen[timeline.frames].mean(axis=0) if n else np.zeros(0),
        why,
    )
    S = MarkerSeries(
        t,
        P,
        [[i for c in cs for i in series.ids[c]] for cs in cols],
        series.clock,
        series.frame,
        None,
        list(series.camera_names),
        [],
        [series.number(cs[0]) if cs else 0 for cs in cols],
    )
    if series.cameras is not None:
        S.cameras = np.zeros((F, model.n_markers), int)
        for m, cs in enumerate(cols):
            for c in cs:
                S.cameras[:, m] = np.maximum(S.cameras[:, m], series.cameras[:, c])
    notes = [
        f"poses fitted with the patient model learned live during the scan ({len(matched)} of its "
        f"{model.n_markers} markers found in the tracks)"
    ]
    return _finish(series, timeline, bands, S, model, pose, s, events, speed, moving, still, thr, st, notes)


def _finish(series, timeline, bands, S, model, pose, s, events, speed, moving, still, thr, st, notes):
    """What every analysis ends with, whichever way its model came: the breaths, the figures,
    the motion states (steps 6)."""
    t, period = S.t, timeline.period
    known = model.reference[model.known]
    valid = pose.valid
    v = model.vectors
    br = find_breaths(t, s, valid, period, moving=moving)  # no breath chained through a move (0089)
    cycles, phase, rate = br.cycles, br.phase, br.rate
    figures = breathing_figures(br, period, timeline.duration_s, signal_noise(s, valid), model.breathes)
    if figures.status == "none":
        notes.append(f"breathing: {figures.why}: no respiratory signal, phase or respiratory subsets")
        s = np.where(valid, 0.0, np.nan)
        cycles, phase, rate = [], np.full(len(t), np.nan), np.full(len(t), np.nan)
    pose.resp = s
    resp = Respiration(t, s, phase, rate, cycles, v, figures)
    poor = pose.poor_fit & ~moving
    still_pose = pose.valid & ~moving
    if still_pose.any() and poor.sum() > 0.05 * still_pose.sum():
        notes.append(
            f"pose degraded in {100 * poor.sum() / still_pose.sum():.0f} % of the still frames with a pose: "
            f"the body model leaves over {POOR_FIT_MM:g} mm of residual there (median "
            f"{float(np.nanmedian(pose.rms_mm[poor])):.2f} mm; a good fit leaves under 0.1 mm): those "
            f"frames are marked 'poor fit', their pose not measured to {POOR_FIT_MM:g} mm"
        )
    states = motion_states(pose, events, moving, known, state_mm=st.state_mm, state_deg=st.state_deg)
    covered, bridged = cover_states(
        states, pose, moving, known, period, event_mm=st.event_mm, event_deg=st.event_deg, bridge_s=st.bridge_s
    )
    return MotionResult(
        series,
        bands,
        S,
        model.reference,
        model.period,
        pose,
        resp,
        events,
        states,
        speed,
        moving,
        still,
        thr,
        st,
        notes,
        timeline,
        covered,
        bridged,
        model,
    )
