"""The simulated patient: a torso on the table with a chest band and an abdomen band of 4
markers each, breathing as people breathe and moving as patients move, with its truth.

Geometry (docs/design.md, "patient bands"): supine, head first -- the head towards the
cameras over the head end (world Z < 0). Body coordinates: origin at the middle of the torso
on its long axis, X lateral, Y anterior (up), Z towards the feet (world axes when the body is
at rest). The torso is an elliptic cylinder ``TORSO_HALF_WIDTH`` x ``TORSO_HALF_DEPTH`` mm,
its axis along Z; it is opaque (:meth:`Patient.hides`). Each band goes round it at a Z of
its own; its 4 markers (``C1..C4`` chest, ``A1..A4`` abdomen; 15 mm spheres on the band)
sit at angles ``BAND_ANGLES`` from straight up, the outer ones on the flanks.

Motion, all of it truth:

* **Breathing** (:class:`Breathing`): a dimensionless signal ``b(t)`` (0 at the end of a
  normal exhalation, about 1 at the top of a normal breath) made cycle by cycle: period 3-6 s
  varying from cycle to cycle, inhalation about 40 % of it, the amplitude varying, now and
  then a deep breath (about twice as deep) or a pause (breath held after exhaling), and a
  baseline that wanders slowly. Each marker moves by ``b(t) * d_i`` in body coordinates:
  mostly anterior-posterior along the torso's outward normal (2-5 mm on the chest, 5-15 mm on
  the abdomen, drawn per seed) with a smaller head-foot part.
* **Body motion** (:class:`BodyMotion`): rigid moves of the whole torso (and both bands):
  sudden shifts and turns (2-20 mm, 1-5 deg, over 0.4-1.5 s, minimum-jerk profile) about the
  body origin, slow creep (a few mm over minutes, constant speed), still periods between.

:meth:`Patient.body_transform` gives the body's pose at ``t`` as the rigid transform that
takes where the markers were at rest (the pose at ``t0``: the reference) to where they are
now, in the SPECT frame, breathing excluded -- the 6-DOF that the motion analysis must find.
The truth is written by :func:`write_truth` (the simulator's ``DIR/truth/``), never into a
session.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vts_hw.files import write_atomic
from vts_hw.sim_devices.scene import Marker, Scene

__all__ = ["Breathing", "BodyMove", "Creep", "BodyMotion", "Patient", "add_patient", "write_truth", "BAND_MARKERS"]

TORSO_HALF_WIDTH = 170.0  # mm, lateral
TORSO_HALF_DEPTH = 110.0  # mm, anterior-posterior
TORSO_HALF_LENGTH = 330.0  # mm, shoulders to hips
PLACEMENT = (0.0, -30.0, 60.0)  # body origin in table coordinates: the heart near the FOV centre
CHEST_Z, ABDOMEN_Z = -90.0, 150.0  # band positions along the body
BAND_ANGLES_DEG = (-48.0, -16.0, 19.0, 51.0)  # chest markers, from straight up, towards +X
# the abdomen's closer together: further from the cameras over the head, they are seen higher in
# the image, where the flanks' would come near the wall markers. At rest, in every camera of the
# 4-camera reference rig (seeds 0-7), each band marker is >= 35 px from every wall marker and
# >= 35 px from every other band marker, also at the top of a 15 mm breath (so only body moves
# may merge two blobs, for a while)
BAND_ANGLES = {"chest": BAND_ANGLES_DEG, "abdomen": (-42.0, -14.0, 17.0, 45.0)}
# each band goes round the body a little askew (mm along Z per mm along X), as a band put on
# by hand does, and the markers sit off-centre: side by side and level they would lie on one
# epipolar line of a camera pair. At rest, in both stereo pairs of the reference rig (head end
# cam1-cam2, foot end cam3-cam4), every marker is >= 6 mm (~5 px) off the epipolar plane of
# every other (tests/unit/test_sim_patient.py); a turn of a few degrees can still bring two onto one
# line for a while (ambiguities the matching must report, not guess).
BAND_TILT = {"chest": 0.3, "abdomen": -0.3}
MARKER_DIAMETER = 15.0
BAND_MARKERS = {"chest": ("C1", "C2", "C3", "C4"), "abdomen": ("A1", "A2", "A3", "A4")}
GRID_S = 0.01  # the breathing signal is tabulated every 10 ms


def min_jerk(s):
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


# ------------------------------------------------------------------------------ breathing


@dataclass
class Cycle:
    t_start: float  # host s
    period_s: float
    amplitude: float  # top of the breath (1: a normal breath)
    kind: str = "normal"  # normal | deep | pause (a pause holds the end of exhalation)


@dataclass
class Breathing:
    """The breathing signal ``b(t)`` from ``t0`` for ``duration_s`` (plus a margin), cycle by
    cycle (:attr:`cycles`, the truth), tabulated on a 10 ms grid and interpolated."""

    t0: float
    duration_s: float
    seed: int = 0
    mean_period_s: float = 4.2
    deep_every: float = 0.05  # chance that a cycle is a deep breath
    pause_every: float = 0.03  # chance that a pause follows a cycle
    wander: float = 0.12  # baseline wander (fraction of a normal breath)
    enabled: bool = True
    cycles: list[Cycle] = field(default_factory=list)

    def __post_init__(self) -> None:
        rng = np.random.default_rng([self.seed, 71])
        end = self.t0 + self.duration_s + 10.0
        self._t = np.arange(self.t0 - 10.0, end + GRID_S, GRID_S)
        b = np.zeros_like(self._t)
        if not self.enabled:
            self._b, self._phase = b, np.zeros_like(b)
            return
        phase = np.zeros_like(self._t)
        t = self.t0 - 10.0 + rng.uniform(0, self.mean_period_s)
        mean_p = self.mean_period_s * (1 + rng.uniform(-0.12, 0.12))
        while t < end:
            deep = rng.random() < self.deep_every
            period = float(np.clip(rng.normal(mean_p, 0.1 * mean_p), 3.0, 6.0)) * (1.3 if deep else 1.0)
            amp = float(np.clip(rng.normal(1.0, 0.12), 0.6, 1.4)) * (rng.uniform(1.8, 2.2) if deep else 1.0)
            c = Cycle(t, period, amp, "deep" if deep else "normal")
            self.cycles.append(c)
            sel = (self._t >= t) & (self._t < t + period)
            s = (self._t[sel] - t) / period
            insp = 0.4
            # inhale over the first 40 %, exhale over the rest: 0 -> amp -> 0, smooth
            b[sel] = np.where(s < insp, amp * min_jerk(s / insp), amp * (1.0 - min_jerk((s - insp) / (1 - insp))))
            phase[sel] = s
            t += period
            if rng.random() < self.pause_every:
                hold = float(rng.uniform(2.0, 5.0))
                self.cycles.append(Cycle(t, hold, 0.0, "pause"))
                t += hold
        # the wandering baseline: a few slow sinusoids (periods 30-150 s)
        for _ in range(3):
            per, ph = rng.uniform(30.0, 150.0), rng.uniform(0, 2 * np.pi)
            b += self.wander / 3 * np.sin(2 * np.pi * (self._t - self.t0) / per + ph)
        self._b, self._phase = b, phase

    def shift(self, dt: float) -> None:
        """Move the whole signal ``dt`` seconds later (the cycles with it)."""
        self._t = self._t + dt
        self.t0 += dt
        for c in self.cycles:
            c.t_start += dt

    def value(self, t):
        """``b(t)`` (dimensionless) at host times ``t``."""
        return np.interp(np.asarray(t, dtype=float), self._t, self._b)

    def phase(self, t):
        """Phase within the breath at ``t``, 0-1 from the start of inhalation (0 in a pause)."""
        return np.interp(np.asarray(t, dtype=float), self._t, self._phase)

    def rate_per_min(self, t) -> float:
        """Breaths per minute of the cycle under way at ``t`` (pauses excluded)."""
        for c in self.cycles:
            if c.t_start <= t < c.t_start + c.period_s and c.kind != "pause":
                return 60.0 / c.period_s
        return float("nan")


# ------------------------------------------------------------------------------ body motion


def _three(v) -> tuple[float, float, float]:
    """Three numbers (a vector of 3) as a tuple of floats."""
    x, y, z = (float(c) for c in v)
    return x, y, z


@dataclass
class BodyMove:
    """A sudden shift and turn of the whole body over [t_start, t_end]: a rotation (deg, a
    rotation vector in the SPECT frame's axes) about the body origin where it is at the time,
    and a translation of that origin (mm, SPECT frame). Moves compose in time order."""

    t_start: float
    t_end: float
    rotation_deg: tuple[float, float, float]
    translation_mm: tuple[float, float, float]


@dataclass
class Creep:
    """A slow drift of the body: translation (mm) spread evenly over [t_start, t_end]."""

    t_start: float
    t_end: float
    translation_mm: tuple[float, float, float]


@dataclass
class BodyMotion:
    moves: list[BodyMove] = field(default_factory=list)
    creeps: list[Creep] = field(default_factory=list)

    @classmethod
    def plan(
        cls, t0: float, duration_s: float, seed: int = 0, n_moves: int = 2, creep_mm: float = 0.0, still_s: float = 15.0
    ) -> BodyMotion:
        """``n_moves`` sudden moves spread over the scan after a still period of ``still_s``
        (the reference), each 2-20 mm and 1-5 deg in random directions, at least 8 s apart;
        ``creep_mm``: a slow drift of that size over the whole scan (mostly along the table)."""
        rng = np.random.default_rng([seed, 29])
        moves = []
        span = duration_s - still_s - 5.0
        if n_moves > 0 and span < 8.0 * n_moves:
            raise ValueError(f"{duration_s:g} s is too short for {n_moves} body moves after {still_s:g} s still")
        starts = np.sort(rng.uniform(0, span - 8.0 * (n_moves - 1), n_moves)) + 8.0 * np.arange(n_moves)
        for ts in starts:
            size_mm = rng.uniform(2.0, 20.0)
            angle = rng.uniform(1.0, 5.0)
            d = rng.normal(size=3)
            axis = rng.normal(size=3)
            rot = angle * axis / np.linalg.norm(axis)
            trans = size_mm * d / np.linalg.norm(d)
            dur = rng.uniform(0.4, 1.5)
            t = t0 + still_s + float(ts)
            moves.append(BodyMove(t, t + dur, _three(rot), _three(trans)))
        creeps = []
        if creep_mm:
            d = np.array([rng.normal(0, 0.3), rng.normal(0, 0.3), 1.0])
            creeps.append(Creep(t0 + still_s, t0 + duration_s, _three(creep_mm * d / np.linalg.norm(d))))
        return cls(moves, creeps)

    def shift(self, dt: float) -> None:
        """Every move and creep ``dt`` seconds later (the same objects: whoever holds one sees it)."""
        shifted: list[BodyMove | Creep] = [*self.moves, *self.creeps]
        for m in shifted:
            vars(m).update(t_start=m.t_start + dt, t_end=m.t_end + dt)  # both at once

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(R, T)`` of the body at ``t``: marker at body point p (rest pose at the origin) is
        at ``R @ p + T`` relative to the body's rest placement. Moves compose in time order."""
        R = np.eye(3)
        T = np.zeros(3)
        for m in self.moves:
            if t <= m.t_start:
                break
            s = float(min_jerk((t - m.t_start) / (m.t_end - m.t_start)))
            dR = Rotation.from_rotvec(np.deg2rad(np.array(m.rotation_deg)) * s).as_matrix()
            R = dR @ R  # turned about the body's origin where it is now:
            T = T + s * np.asarray(m.translation_mm, float)  # the origin only translates
        for c in self.creeps:
            s = float(np.clip((t - c.t_start) / (c.t_end - c.t_start), 0.0, 1.0))
            T = T + s * np.asarray(c.translation_mm, float)
        return R, T


# ------------------------------------------------------------------------------ the body


def _band_markers() -> tuple[list[Marker], dict[str, np.ndarray]]:
    """The 8 markers at rest (body coordinates) and each one's unit breathing direction."""
    markers, outward = [], {}
    for band, z in (("chest", CHEST_Z), ("abdomen", ABDOMEN_Z)):
        for mid, a in zip(BAND_MARKERS[band], np.deg2rad(BAND_ANGLES[band])):
            x = TORSO_HALF_WIDTH * np.sin(a)
            surface = np.array([x, TORSO_HALF_DEPTH * np.cos(a), z + BAND_TILT[band] * x])
            n = np.array([np.sin(a) / TORSO_HALF_WIDTH, np.cos(a) / TORSO_HALF_DEPTH, 0.0])
            n /= np.linalg.norm(n)
            centre = surface + n * (MARKER_DIAMETER / 2 + 3.0)  # a sphere on a band over clothing
            markers.append(Marker(mid, centre, n, MARKER_DIAMETER, "sphere"))
            outward[mid] = n
    return markers, outward


class _PoseKey:
    """What the scene's render cache asks of a body's pose: the patient changes at every
    instant, so its key is the time itself (to 0.1 ms)."""

    def at(self, t: float):
        return round(float(t), 4)


class Patient:
    """The patient as a body on the scene's table (duck-typed like a ``RigidBody``): markers
    at ``t`` with breathing and body motion, the torso as an occluder, and the truth."""

    def __init__(
        self, breathing: Breathing, motion: BodyMotion, seed: int = 0, name: str = "patient", placement=PLACEMENT
    ):
        rng = np.random.default_rng([seed, 43])
        self.name = name
        self.breathing = breathing
        self.motion = motion
        self.placement = np.asarray(placement, float)
        self.rest, outward = _band_markers()
        chest_ap = rng.uniform(2.0, 5.0)  # mm of a normal breath, anterior-posterior
        abd_ap = rng.uniform(5.0, 15.0)
        hf = rng.uniform(0.15, 0.3)  # head-foot part, as a share of the AP amplitude
        self.breath_mm = {"chest": float(chest_ap), "abdomen": float(abd_ap)}
        self.breath_dir: dict[str, np.ndarray] = {}
        for band, ids in BAND_MARKERS.items():
            # along the outward normal, the flanks less: the band's most anterior-moving marker
            # moves breath_mm[band] anterior-posterior in a normal breath (b = 1)
            w = {i: (0.7 + 0.3 * abs(outward[i][1])) * outward[i] for i in ids}
            top = max(v[1] for v in w.values())
            foot = np.array([0.0, 0.0, hf * self.breath_mm[band] * (1.0 if band == "abdomen" else -0.5)])
            for i in ids:
                self.breath_dir[i] = self.breath_mm[band] * w[i] / top + foot
        self.pose = _PoseKey()

    def shift(self, dt: float) -> None:
        """The patient's whole plan (breathing, moves, creep) ``dt`` seconds later: frames
        rendered ahead of time (sim_devices/frame_bank.py) start playing when a stream opens,
        and the patient with them."""
        self.breathing.shift(dt)
        self.motion.shift(dt)

    # ------------------------------------------------------------------ scene interface
    @property
    def markers(self) -> list[Marker]:
        return list(self.rest)

    def markers_at(self, t: float, table_offset: np.ndarray) -> list[Marker]:
        b = float(self.breathing.value(t))
        R, T = self.motion.pose(t)
        shift = self.placement + T + np.asarray(table_offset, float)
        out = []
        for m in self.rest:
            p = m.center + b * self.breath_dir[m.id]
            out.append(Marker(m.id, R @ p + shift, R @ m.normal, m.diameter_mm, m.kind))
        return out

    def hides(self, eye, points, t: float, grow_mm=0.0, table_offset=(0.0, 0.0, 0.0)) -> np.ndarray:
        """Whether the torso (a closed elliptic cylinder, its ends included: a camera over the
        head looks in through the shoulders) lies between ``eye`` and each point; the last
        ``grow_mm`` + 2 mm before each point and 1 mm of the torso's skin do not count, so that
        a marker on it does not hide itself. Bool (N,)."""
        R, T = self.motion.pose(t)
        origin = self.placement + T + np.asarray(table_offset, float)
        e = R.T @ (np.asarray(eye, float) - origin)
        pts = (np.asarray(points, float).reshape(-1, 3) - origin) @ R
        d = pts - e
        grow = np.broadcast_to(np.asarray(grow_mm, float), (len(pts),))
        a, c = TORSO_HALF_WIDTH - 1.0, TORSO_HALF_DEPTH - 1.0
        # inside the elliptic cylinder where A s^2 + B s + C < 0 along eye + s d
        A = d[:, 0] ** 2 / a**2 + d[:, 1] ** 2 / c**2
        B = 2 * (e[0] * d[:, 0] / a**2 + e[1] * d[:, 1] / c**2)
        C = e[0] ** 2 / a**2 + e[1] ** 2 / c**2 - 1.0
        disc = B * B - 4 * A * C
        sq = np.sqrt(np.maximum(disc, 0.0))
        along = A <= 1e-12  # parallel to the axis: inside all along, or never
        A_ = np.where(along, 1.0, A)
        lo = np.where(along, np.where(C < 0, -np.inf, np.inf), (-B - sq) / (2 * A_))
        hi = np.where(along, np.where(C < 0, np.inf, -np.inf), (-B + sq) / (2 * A_))
        lo = np.where(~along & (disc <= 0), np.inf, lo)
        # ... and between the two ends, |z| < half length
        L = TORSO_HALF_LENGTH - 1.0
        dz = np.where(np.abs(d[:, 2]) < 1e-12, 1e-12, d[:, 2])
        z1, z2 = (-L - e[2]) / dz, (L - e[2]) / dz
        lo = np.maximum(lo, np.minimum(z1, z2))
        hi = np.minimum(hi, np.maximum(z1, z2))
        s_end = 1.0 - (grow + 2.0) / np.maximum(np.linalg.norm(d, axis=1), 1e-9)
        return np.maximum(lo, 0.0) < np.minimum(hi, s_end)

    # ------------------------------------------------------------------ truth
    def body_transform(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """``(R, t)``: the rigid transform (SPECT frame, table at rest) taking each marker's
        reference position (the rest pose, no breath) to its position at ``t`` with the
        breathing taken out: ``x -> R @ x + t``."""
        R, T = self.motion.pose(t)
        return R, self.placement + T - R @ self.placement

    def six_dof(self, t: float) -> np.ndarray:
        """``[tx, ty, tz (mm), rx, ry, rz (deg, extrinsic x-y-z)]`` of :meth:`body_transform`."""
        R, tr = self.body_transform(t)
        return np.concatenate([tr, Rotation.from_matrix(R).as_euler("xyz", degrees=True)])

    def marker_truth(self, t: float, table_offset=(0.0, 0.0, 0.0)) -> dict[str, np.ndarray]:
        return {m.id: m.center for m in self.markers_at(t, np.asarray(table_offset, float))}


def add_patient(
    scene: Scene,
    t0: float,
    duration_s: float,
    seed: int = 0,
    *,
    n_moves: int = 2,
    creep_mm: float = 0.0,
    breathing: bool = True,
    still_s: float = 15.0,
    moves: list[BodyMove] | None = None,
) -> Patient:
    """Put a breathing (``breathing``) patient on the scene's table from ``t0`` for
    ``duration_s``: ``n_moves`` random body moves after ``still_s`` still (or the ``moves``
    given) and a creep of ``creep_mm``. Returns the patient (its truth)."""
    motion = (
        BodyMotion(list(moves))
        if moves is not None
        else BodyMotion.plan(t0, duration_s, seed, n_moves=n_moves, creep_mm=creep_mm, still_s=still_s)
    )
    if moves is not None and creep_mm:
        motion.creeps = BodyMotion.plan(t0, duration_s, seed, n_moves=0, creep_mm=creep_mm, still_s=still_s).creeps
    patient = Patient(Breathing(t0, duration_s, seed, enabled=breathing), motion, seed)
    scene.add_body(patient)
    return patient


def write_truth(patient: Patient, folder, t0: float, t1: float, rate_hz: float = 100.0) -> list[Path]:
    """The patient's truth into ``folder`` (the simulator's ``DIR/truth/``): ``patient.json``
    (bands, breathing amplitudes, cycles, body moves, creep) and ``patient_motion.csv`` at
    ``rate_hz``: time, the body's 6-DOF, breathing value and phase, every marker's position."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    meta = {
        "format": "vts-hw sim patient truth",
        "format_version": 1,
        "frame": "SPECT frame, table at rest, mm; rotations deg, extrinsic x-y-z",
        "bands": {k: list(v) for k, v in BAND_MARKERS.items()},
        "breath_mm": patient.breath_mm,
        "placement_mm": patient.placement.tolist(),
        "cycles": [asdict(c) for c in patient.breathing.cycles if t0 - 10 <= c.t_start <= t1],
        "moves": [asdict(m) for m in patient.motion.moves],
        "creeps": [asdict(c) for c in patient.motion.creeps],
    }
    js = folder / "patient.json"
    write_atomic(js, json.dumps(meta, indent=1))
    ids = [m.id for m in patient.rest]
    cols = ["t", "tx_mm", "ty_mm", "tz_mm", "rx_deg", "ry_deg", "rz_deg", "breath", "phase"] + [
        f"{i}_{a}" for i in ids for a in "xyz"
    ]
    # t0 + k / rate, not np.arange(t0, t1, step): at epoch seconds the step itself is off by
    # ~1e-7 s and the error grows along the file
    ts = t0 + np.arange(int(np.ceil((t1 - t0) * rate_hz - 1e-9))) / rate_hz
    b = patient.breathing.value(ts)
    table = np.empty((ts.size, len(cols)))
    table[:, 0], table[:, 7], table[:, 8] = ts, b, patient.breathing.phase(ts)
    rest = np.array([m.center for m in patient.rest])
    drift = np.array([patient.breath_dir[i] for i in ids])
    last_R, euler = None, None
    for k, t in enumerate(ts):  # as six_dof and marker_truth, the rotation's angles once per pose
        R, T = patient.motion.pose(float(t))
        if last_R is None or not np.array_equal(R, last_R):
            last_R, euler = R, Rotation.from_matrix(R).as_euler("xyz", degrees=True)
        table[k, 1:4] = patient.placement + T - R @ patient.placement
        table[k, 4:7] = euler
        table[k, 9:] = ((rest + b[k] * drift) @ R.T + patient.placement + T).ravel()
    lines = [",".join(cols)] + [f"{row[0]:.3f}," + ",".join(f"{v:.4f}" for v in row[1:]) for row in table]
    csv = folder / "patient_motion.csv"
    write_atomic(csv, "\n".join(lines) + "\n")
    return [js, csv]
