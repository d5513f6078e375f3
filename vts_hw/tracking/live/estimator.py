"""The live estimate: per band the displacement and breathing, the body's 6-DOF with breathing
separated, and the alert state -- from 3D marker positions, one instant at a time.

Phases: ``waiting`` (no markers yet), ``reference`` (learning the first still period:
``reference_s`` of marker positions, despite gaps; :mod:`vts_hw.tracking.live.reference` finds the
patient's markers by what they do: those that breathe inside the field of view, or with none
breathing every marker inside it; restarted when the body did not keep still -- the model's
residual above ``ref_max_rms_mm``, or its pose spreading by more than a fifth of the alert
thresholds (RMS)), then ``tracking``. Bands: along the SPECT Z axis (the table), without a
mapping along the first camera's viewing direction (the cameras look along the body).

Each :meth:`LiveEstimator.update` says whether that instant **observed** the patient
(``observed``: a pose while tracking; three or more points while learning) and, when not,
why (``note``): what :mod:`vts_hw.tracking.live.watch` needs to say whether the patient is tracked.
The model is the one patient model of :mod:`vts_hw.motion.patient_model`, learned from the
reference and fitted one instant at a time (:meth:`~vts_hw.motion.patient_model.PatientModel.fit_instant`):
the offline analysis of the scan fits the same model over the recording (0092). Every pose is
kept (:attr:`LiveEstimator.poses`): what the technologist was shown can be read afterwards.
See 0036, 0048 and 0092.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from vts_hw.motion.patient_model import InstantPose, PatientModel
from vts_hw.pose_health import pose_health
from vts_hw.tracking.identities import assign
from vts_hw.tracking.live.alerts import Alert, AlertRule
from vts_hw.tracking.live.breathing import BreathingTrace
from vts_hw.tracking.live.reference import ReferenceCollector
from vts_hw.vision.marker_roles import ABDOMEN, CHEST

__all__ = ["LiveSettings", "LiveEstimator", "LiveEstimate", "BandEstimate", "LivePose"]


@dataclass(frozen=True)
class LivePose:
    """One live pose as the technologist was shown it: host ``time`` of its frame set, the pose
    ``R``, ``T`` (reference -> now) and breathing ``s`` of the patient model, the fit's residual,
    the markers used, the cameras per marker used, the alert rule's state, the move and turn it
    measured (from the alert reference pose), the frames it was made from (each camera's frame
    number in its recording), and its health when made (:mod:`vts_hw.pose_health`; "" until the
    pose log works it out from these figures, off the worker's path)."""

    time: float
    R: np.ndarray
    T: np.ndarray
    s: float
    rms_mm: float
    n_markers: int
    cameras: float
    state: str
    move_mm: float
    turn_deg: float
    health: str = ""
    confidence: float = float("nan")
    frames: tuple = ()  # per camera (the tracker's order) the number of its frame in the set, -1: none
    model_markers: int = 0  # the model's markers (what its health is judged against)


@dataclass(frozen=True)
class LiveSettings:
    reference_s: float = 10.0
    band_gap_mm: float = 60.0
    gate_mm: float = 15.0
    min_seen_fraction: float = 0.6  # of the reference's instants (frame sets), not of its time
    ref_min_observed: float = 0.5  # the reference's instants cover at least this share of reference_s
    ref_max_span: float = 3.0  # ... within at most this many reference_s (older instants let go)
    step_s: float = 0.5  # instants further apart than this: the time between is not observed
    ref_max_rms_mm: float = 1.0
    ref_max_move_fraction: float = 0.2  # the pose's RMS spread over the reference: at most this of the thresholds
    min_breath_mm: float = 0.6  # the model's most breathing marker ranges this much (5th to 95th percentile),
    # or the model has no breathing term (the patient's markers: vision.marker_roles)
    onset_fraction: float = 0.15
    settle_s: float = 2.0
    trace_window_s: float = 30.0
    iterations: int = 6  # of the alternating fit, from the last solution
    iterations_after_gap: int = 30  # ... when that solution is older than gap_s (breathing went on meanwhile)
    gap_s: float = 0.2


@dataclass(frozen=True)
class BandEstimate:
    band: int
    markers: int  # in the model
    seen: int  # in the last estimate
    displacement_mm: tuple[float, float, float]  # centre of its seen markers minus the reference's
    breathing_mm: float  # the band's breathing value now (mm along its markers' directions)
    rate_per_min: float
    trace: tuple[float, ...]  # the last seconds of breathing (for a sparkline)
    breathes: bool = True  # False: no breathing seen in the reference (fitted rigidly)
    rate_range: tuple | None = None  # (low, high) /min when the rate is only bounded (not known to 0.5 /min)

    @property
    def distance_mm(self) -> float:
        return float(np.linalg.norm(self.displacement_mm))


@dataclass(frozen=True)
class LiveEstimate:
    phase: str  # waiting | reference | tracking
    frame: str  # spect | vts: the frame of positions and the 6-DOF
    time: float | None  # host s of the last estimate
    bands: tuple[BandEstimate, ...] = ()
    six_dof: tuple[float, ...] | None = None  # tx, ty, tz (mm), rx, ry, rz (deg, extrinsic x-y-z)
    move_mm: float = 0.0  # the body's centre (its markers') from the reference, breathing excluded
    turn_deg: float = 0.0  # the body's turn from the reference
    state: str = ""  # still | off pose | moving | ALERT
    alerts: int = 0
    note: str = ""
    stats: dict = field(default_factory=dict)
    # whether the patient is watched now (filled in by the tracker, vts_hw/tracking/live/watch.py):
    status: str = ""  # TRACKING | REFERENCE | NOT TRACKING ("" : not known here)
    reason: str = ""  # why NOT TRACKING (or what the reference is doing)
    status_for_s: float | None = None  # how long it has been so
    age_s: float | None = None  # how old the figures shown are (from the capture of their frames)
    # how sure the pose is (vts_hw/pose_health.py; the tracker renews it with the age when read)
    health: str = ""  # known | bounded | not known ("": no pose yet)
    health_why: str = ""
    confidence: float | None = None
    fit_figures: tuple | None = None  # (markers used, model's markers, residual mm, cameras per marker or None)


class LiveEstimator:
    """Feed :meth:`update` with each instant's 3D points (mm, in ``frame``); read
    :meth:`snapshot`. ``motion``: anything with ``alert_mm``, ``alert_deg``, ``alert_after_s``
    (the rig's ``motion:`` section). ``space``: the table-and-gantry volume (a
    :class:`~vts_hw.vision.marker_roles.TableSpace`; default the default room's) where a still
    patient's markers lie. ``axis``: the body's long axis (bands are ordered along it), in ``frame``."""

    def __init__(
        self, motion, settings: LiveSettings | None = None, *, frame: str = "spect", axis=(0.0, 0.0, 1.0), space=None
    ):
        self.motion = motion
        self.s = settings or LiveSettings()
        self.frame = frame
        self.axis = np.asarray(axis, float)
        self.phase = "waiting"
        self.note = ""
        self.reference_note = ""
        self.model: PatientModel | None = None
        self.rule: AlertRule | None = None
        self.fit: InstantPose | None = None
        self.poses: list[LivePose] = []  # every pose, in time order (read by the session)
        self.time: float | None = None
        self.traces: list[BreathingTrace] = []
        self.lead = 0  # the band whose rate is the one respiratory signal's (set with the model)
        self.observed = False  # whether the last update observed the patient
        self.learned_at: float | None = None  # host s the reference was learned
        self.restarts = 0
        # the reference's collector, until the reference is learned (then model, rule and traces)
        self._ref: ReferenceCollector | None = ReferenceCollector(self.s, frame, self.axis, space)
        self._seen_idx = np.zeros(0, int)
        self._fit_t: float | None = None
        self._seen_x = np.zeros((0, 3))
        self._seen_pts = np.zeros(0, int)  # where in that instant's points each seen marker was
        self.marker_names: list[str] = []  # per model marker: "<band name> <n>" (set with the model)
        self._cameras = float("nan")  # cameras per marker used in the last pose (mean)

    # -- input ---------------------------------------------------------------------------------
    def update(self, t: float, points, cameras=None, frames: tuple = ()) -> Alert | None:
        """One instant's points (N, 3) (``cameras``: per point the cameras that saw it, or one
        number for all; None: not known; ``frames``: the frames they came from, per camera its
        number, -1 none). Returns an alert when this estimate raised one."""
        pts = np.asarray(points, float).reshape(-1, 3)
        self.time = t
        if self.phase != "tracking":
            self._collect(t, pts)
            if self.phase != "tracking":
                return None
        return self._track(t, pts, cameras, frames)  # (the instant that completed the reference too)

    def _collect(self, t: float, pts: np.ndarray) -> None:
        self.observed = len(pts) >= 3
        if len(pts) == 0:
            return
        if self.phase == "waiting":
            self.phase = "reference"
        ref = self._collector()
        ref.add(t, pts)
        if ref.due(t):
            self._learn(t)

    def _collector(self) -> ReferenceCollector:
        """The reference's collector (there until the reference is learned)."""
        if self._ref is None:
            raise RuntimeError("the reference is learned already: nothing collects it")
        return self._ref

    def _tracked(self) -> tuple[PatientModel, AlertRule]:
        """The reference's model and the alert rule, set together when it is learned."""
        if self.model is None or self.rule is None:
            raise RuntimeError("no reference learned yet: nothing to track against")
        return self.model, self.rule

    def _restart(self, why: str) -> None:
        self.note = f"reference restarted: {why}"
        self.restarts += 1
        self._collector().restart()

    def _learn(self, t: float) -> None:
        ref = self._collector()
        model, why = ref.learn(t)
        if model is None:
            self.note = f"reference not learned yet: {why}"
            return
        if not np.isfinite(model.noise_mm) or model.noise_mm > self.s.ref_max_rms_mm:
            self._restart(f"the body did not keep still (model residual {model.noise_mm:.2f} mm)")
            return
        f = self.s.ref_max_move_fraction
        if model.pose_noise_mm > f * self.motion.alert_mm or model.pose_noise_deg > f * self.motion.alert_deg:
            # a rigid move fits the model at every instant; it shows in the pose's spread instead
            self._restart(f"the body moved ({model.pose_noise_mm:.2f} mm, {model.pose_noise_deg:.2f} deg RMS)")
            return
        self.model = model
        self.marker_names = [""] * model.n_markers
        for k, g in enumerate(model.bands):  # chest 1, abdomen 2: the roles' words (B1.1 where not told)
            name = model.band_names[k] if k < len(model.band_names) else ""
            for n, i in enumerate(g):
                self.marker_names[i] = f"{name} {n + 1}" if name in (CHEST, ABDOMEN) else f"B{k + 1}.{n + 1}"
        self.rule = AlertRule(
            self.motion.alert_mm,
            self.motion.alert_deg,
            self.motion.alert_after_s,
            self.s.onset_fraction,
            self.s.settle_s,
            model.pose_noise_mm,
            model.pose_noise_deg,
        )
        self.traces = [BreathingTrace(self.s.trace_window_s) for _ in model.bands]
        # one respiratory signal: its rate worked out on the band that breathes most (the model's: fixed)
        self.lead = int(np.argmax([self._band_mm(k) for k in range(len(model.bands))])) if model.bands else 0
        self.phase = "tracking"
        self.reference_note = self.note = (
            f"reference: {model.n_markers} markers in {len(model.bands)} band(s)"
            + ("" if model.breathes else " (no breathing seen: fitted rigidly)")
            + f", {ref.observed():.1f} s of frames over {t - (t if ref.t0 is None else ref.t0):.1f} s, model residual "
            f"{model.noise_mm:.2f} mm, still pose noise {model.pose_noise_mm:.2f} mm {model.pose_noise_deg:.3f} deg"
        )
        self.learned_at = t
        self._ref = None

    def _predicted(self) -> np.ndarray:
        m, f = self._tracked()[0], self.fit
        if f is None:
            return m.reference
        return m.positions(f.R[None], f.T[None], np.array([f.s]))[0]

    def _band_mm(self, k: int) -> float:
        """mm of band ``k``'s breathing per unit of the signal (its markers' mean vector length)."""
        m = self._tracked()[0]
        g = m.bands[k]
        return float(np.mean(np.linalg.norm(m.vectors[g], axis=1))) if g else 0.0

    def _track(self, t: float, pts: np.ndarray, cameras=None, frames: tuple = ()) -> Alert | None:
        m, r = self._tracked()
        i_m, i_p = assign(self._predicted(), pts, self.s.gate_mm)
        after_gap = self._fit_t is None or t - self._fit_t > self.s.gap_s
        fit = m.fit_instant(
            i_m, pts[i_p], self.fit, iterations=self.s.iterations_after_gap if after_gap else self.s.iterations
        )
        self._seen_idx, self._seen_x, self._seen_pts = i_m, pts[i_p], i_p
        self.observed = fit is not None
        if fit is None:
            self.note = f"{len(i_m)} of {m.n_markers} markers seen"
            return None
        self.note = ""
        self._fit_t = t
        self.fit = fit
        if m.breathes:
            for k, tr in enumerate(self.traces):
                tr.add(t, fit.s * self._band_mm(k))
        alert = r.update(t, fit.R, fit.T, m.centre)
        cams = float("nan")
        if cameras is not None:
            c = np.broadcast_to(np.asarray(cameras, float), (len(pts),))[i_p]
            cams = float(c.mean()) if len(c) else float("nan")
        self._cameras = cams
        self.poses.append(
            LivePose(
                t,
                fit.R,
                fit.T,
                fit.s,
                fit.rms_mm,
                fit.n_markers,
                cams,
                r.state,
                r.move_mm,
                r.turn_deg,
                frames=tuple(int(i) for i in frames),
                model_markers=m.n_markers,
            )
        )  # its health: worked out when kept (pose_log)
        return alert

    def health(self, age_s: float = 0.0):
        """The last pose's health with its frames ``age_s`` old (None: no pose yet)."""
        f = self.fit
        if f is None or self.model is None:
            return None
        cams = self._cameras
        return pose_health(f.n_markers, self.model.n_markers, f.rms_mm, None if np.isnan(cams) else cams, age_s)

    def seen_names(self) -> list[tuple[str, int]]:
        """The patient markers of the last estimate, named by the reference model: ``(name,
        index into that instant's points)``, the name ``chest <n>`` / ``abdomen <n>`` as the
        markers' identity names the bands (:mod:`vts_hw.vision.marker_roles`), ``B<band>.<n>`` where
        the bands are not told apart (markers counted from 1, in the model's order). Empty until
        the reference is learned."""
        if self.phase != "tracking":
            return []
        return [(self.marker_names[int(m)], int(p)) for m, p in zip(self._seen_idx, self._seen_pts)]

    def six_dof(self, rot: Rotation | None = None) -> np.ndarray:
        """The body's 6-DOF now (tx, ty, tz mm; rx, ry, rz deg), from the last pose; needs one
        (``rot``: its rotation, when the caller has it already)."""
        f = self.fit
        if f is None:
            raise RuntimeError("no pose yet: no 6-DOF")
        rot = Rotation.from_matrix(f.R) if rot is None else rot
        return np.concatenate([f.T, rot.as_euler("xyz", degrees=True)])

    # -- output --------------------------------------------------------------------------------
    def refresh(self) -> None:
        """Work the breathing figures out again where due (:meth:`BreathingTrace.refresh`): what
        :meth:`snapshot` does itself unless told ``fresh=False``; the live tracker calls it after
        a frame set's estimate is published, so that the once-a-second figures (a few ms) never
        hold up a set's markers."""
        if self.traces:
            self.traces[self.lead].refresh()

    def snapshot(self, stats: dict | None = None, fresh: bool = True) -> LiveEstimate:
        """The estimate now. ``fresh=False``: with the breathing figures last worked out
        (:meth:`refresh`), not worked out again here."""
        if self.phase != "tracking" or self.fit is None:
            note = self.note
            if (
                self.phase == "reference"
                and self._ref is not None
                and self._ref.t0 is not None
                and self.time is not None
            ):
                note = f"learning the reference: {self.time - self._ref.t0:.1f} of {self.s.reference_s:g} s" + (
                    f" ({self.note})" if self.note else ""
                )
            return LiveEstimate(self.phase, self.frame, self.time, note=note, stats=dict(stats or {}))
        (m, r), f = self._tracked(), self.fit
        bands = []
        band = m.band_of()
        # one respiratory signal: its rate worked out once, on the band that breathes most
        fig = self.traces[self.lead].figures(fresh) if self.traces else None
        rate, rate_range = float("nan"), None
        if fig is not None and fig.status in ("measured", "bounded") and fig.rate_per_min is not None:
            rate = float(fig.rate_per_min)
            if fig.status == "bounded" and fig.rate_range is not None:
                rate_range = tuple(float(x) for x in fig.rate_range)
        for k, g in enumerate(m.bands):
            sel = band[self._seen_idx] == k
            idx = self._seen_idx[sel]
            disp = (self._seen_x[sel].mean(axis=0) - m.reference[idx].mean(axis=0)) if len(idx) else np.full(3, np.nan)
            tr = self.traces[k]
            bands.append(
                BandEstimate(
                    k + 1,
                    len(g),
                    int(len(idx)),
                    (float(disp[0]), float(disp[1]), float(disp[2])),
                    float(tr.last()),
                    rate,
                    tuple(tr.recent()),
                    m.breathes,
                    rate_range,
                )
            )
        c = m.centre
        move = float(np.linalg.norm(f.R @ c + f.T - c))
        rot = Rotation.from_matrix(f.R)
        turn = float(np.degrees(np.linalg.norm(rot.as_rotvec())))
        h, cams = self.health(), self._cameras
        figures = (f.n_markers, m.n_markers, f.rms_mm, None if np.isnan(cams) else cams)
        return LiveEstimate(
            self.phase,
            self.frame,
            self.time,
            tuple(bands),
            tuple(float(x) for x in self.six_dof(rot)),
            move,
            turn,
            r.state,
            len(r.alerts),
            self.note,
            dict(stats or {}),
            health=h.state,
            health_why=h.why,
            confidence=h.confidence,
            fit_figures=figures,
        )
