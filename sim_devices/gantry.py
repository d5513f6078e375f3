"""The SPECT gantry of the simulated room: two detector heads that rotate about the table axis.

Each head is a box (docs/design.md, "SPECT heads"): a face of ``face_mm`` = (transaxial,
axial) = 540 x 400 mm, ``thickness_mm`` = 200 mm deep, its face ``radius_mm`` from the axis
of rotation (the world Z axis through the FOV centre), centred axially on ``z_mm``. Head k sits
at gantry angle ``angle + offsets_deg[k]`` (0 deg = straight above the axis, angles turning
from +Y towards +X); the heads are dark: they reflect nothing and hide what is behind them.

Motion is step-and-shoot (:meth:`Gantry.step_and_shoot`): ``step_deg`` turns, each taking
``move_s`` (the angle changes linearly), with ``dwell_s`` of acquisition between them. Before
and after an acquisition the heads are parked (:meth:`Gantry.park`): drawn back to
``park_radius_mm`` = 400 mm, where they hide no wall marker from any camera of the reference
rig at any angle, so the daily drift QA works with the gantry in the room.

Occlusion (:meth:`Gantry.hides`): a marker is hidden from a camera when the segment from the
camera's centre to the marker's centre passes through a head box grown by the marker's
radius -- a marker is drawn whole or not at all; a half-hidden marker counts as hidden
(docs/decisions/0031-n-camera-tracking.md says why).
"""

from __future__ import annotations

import bisect
import dataclasses
import threading
from dataclasses import dataclass

import numpy as np

__all__ = ["Gantry", "Acquisition"]

FACE_MM = (540.0, 400.0)  # transaxial x axial
THICKNESS_MM = 200.0
RADIUS_MM = 260.0  # body-contouring orbits run 20-30 cm from the axis
PARK_DEG = 0.0  # parked: heads above and below the table,
PARK_RADIUS_MM = 400.0  # drawn back (no wall marker hidden from any reference camera)


@dataclass(frozen=True)
class Acquisition:
    """One step-and-shoot acquisition: from ``t0`` (host s), ``n_steps`` turns of ``step_deg``
    starting at ``start_deg``; each stop lasts ``dwell_s``, each turn ``move_s``."""

    t0: float
    start_deg: float
    step_deg: float
    n_steps: int
    dwell_s: float
    move_s: float
    radius_mm: float = RADIUS_MM

    @property
    def end(self) -> float:
        return self.t0 + self.n_steps * (self.dwell_s + self.move_s) + self.dwell_s

    def angle_at(self, t: float) -> float:
        period = self.dwell_s + self.move_s
        u = max(0.0, t - self.t0)
        k = min(int(u // period), self.n_steps)
        frac = 0.0
        if k < self.n_steps:
            into = u - k * period - self.dwell_s
            frac = min(max(into / self.move_s, 0.0), 1.0) if self.move_s > 0 else float(into >= 0)
        return self.start_deg + self.step_deg * (k + frac)

    def rotating(self, t: float) -> bool:
        """Whether the heads are turning at ``t`` (between two stops)."""
        if t < self.t0 or t >= self.end:
            return False
        into = (t - self.t0) % (self.dwell_s + self.move_s)
        return into >= self.dwell_s and (t - self.t0) < self.n_steps * (self.dwell_s + self.move_s)


class Gantry:
    """Two (or more) detector heads about the world Z axis; their angle over host time."""

    def __init__(
        self,
        radius_mm: float = RADIUS_MM,
        face_mm=FACE_MM,
        thickness_mm: float = THICKNESS_MM,
        z_mm: float = 0.0,
        offsets_deg=(0.0, 180.0),
        park_deg: float = PARK_DEG,
        park_radius_mm: float = PARK_RADIUS_MM,
    ):
        self.radius_mm = float(radius_mm)  # the orbit of acquisitions
        self.park_radius_mm = float(park_radius_mm)
        self.face_mm = (float(face_mm[0]), float(face_mm[1]))
        self.thickness_mm = float(thickness_mm)
        self.z_mm = float(z_mm)
        self.offsets_deg = tuple(float(o) for o in offsets_deg)
        self.park_deg = float(park_deg)
        self._acq: list[Acquisition] = []
        self._lock = threading.Lock()

    # ----------------------------------------------------------------- motion
    def park(self, angle_deg: float | None = None, radius_mm: float | None = None) -> None:
        """Heads parked at ``angle_deg`` and ``radius_mm`` (default: as they were parked) at all
        times; acquisitions dropped."""
        with self._lock:
            self.park_deg = self.park_deg if angle_deg is None else float(angle_deg)
            self.park_radius_mm = self.park_radius_mm if radius_mm is None else float(radius_mm)
            self._acq = []

    def step_and_shoot(
        self,
        t0: float,
        step_deg: float = 3.0,
        n_steps: int = 60,
        dwell_s: float = 1.0,
        move_s: float = 0.5,
        start_deg: float | None = None,
        radius_mm: float | None = None,
    ) -> Acquisition:
        """Schedule an acquisition from ``t0`` (host s) on an orbit of ``radius_mm`` (default
        ``self.radius_mm``); returns it. The heads stay at its last angle and radius
        afterwards, until the next acquisition or :meth:`park`."""
        acq = Acquisition(
            float(t0),
            self.park_deg if start_deg is None else float(start_deg),
            float(step_deg),
            int(n_steps),
            float(dwell_s),
            float(move_s),
            self.radius_mm if radius_mm is None else float(radius_mm),
        )
        with self._lock:
            i = bisect.bisect_left([a.t0 for a in self._acq], acq.t0)
            self._acq = self._acq[:i] + [acq]
        return acq

    def shift(self, dt: float) -> None:
        """Every acquisition ``dt`` seconds later (frames made ahead of time start playing when
        a stream opens, and the heads' turning with them: sim_devices/frame_bank.py)."""
        with self._lock:
            self._acq = [dataclasses.replace(a, t0=a.t0 + dt) for a in self._acq]

    def _current(self, t: float) -> Acquisition | None:
        with self._lock:
            i = bisect.bisect_right([a.t0 for a in self._acq], t)
            return self._acq[i - 1] if i else None

    def angle_at(self, t: float) -> float:
        """Gantry angle (deg) at host time ``t``: of head 1; head k is ``offsets_deg[k]`` on."""
        acq = self._current(t)
        return self.park_deg if acq is None else acq.angle_at(t)

    def radius_at(self, t: float) -> float:
        """Distance (mm) of the heads' faces from the axis at ``t``."""
        acq = self._current(t)
        return self.park_radius_mm if acq is None else acq.radius_mm

    def rotating(self, t: float) -> bool:
        acq = self._current(t)
        return acq is not None and acq.rotating(t)

    # ----------------------------------------------------------------- geometry
    def boxes(self, t: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per head ``(centre, axes, half sizes)``: ``axes`` rows are the box's unit axes in the
        world (tangential, radial outwards, axial); half sizes along them (mm)."""
        out = []
        a0, r = self.angle_at(t), self.radius_at(t)
        half = np.array([self.face_mm[0] / 2, self.thickness_mm / 2, self.face_mm[1] / 2])
        for off in self.offsets_deg:
            a = np.deg2rad(a0 + off)
            radial = np.array([np.sin(a), np.cos(a), 0.0])
            tangential = np.array([np.cos(a), -np.sin(a), 0.0])
            centre = radial * (r + self.thickness_mm / 2) + np.array([0, 0, self.z_mm])
            out.append((centre, np.vstack([tangential, radial, [0.0, 0.0, 1.0]]), half))
        return out

    def corners(self, t: float) -> list[np.ndarray]:
        """The 8 corners (8x3, mm) of each head box at ``t``."""
        signs = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
        return [centre + (signs * half) @ axes for centre, axes, half in self.boxes(t)]

    def hides(self, eye, points, t: float, grow_mm=0.0) -> np.ndarray:
        """Whether the segment from ``eye`` (3,) to each point (Nx3) passes through a head at
        ``t`` (slab test), the boxes grown by ``grow_mm`` (scalar or per point). Bool (N,)."""
        eye = np.asarray(eye, float)
        pts = np.asarray(points, float).reshape(-1, 3)
        grow = np.broadcast_to(np.asarray(grow_mm, float), (len(pts),))[:, None]
        hidden = np.zeros(len(pts), bool)
        for centre, axes, half in self.boxes(t):
            o = axes @ (eye - centre)  # the eye in box coordinates
            d = (pts - eye) @ axes.T  # segment directions, box coordinates
            h = half[None, :] + grow
            with np.errstate(divide="ignore", invalid="ignore"):
                t1 = (-h - o) / d
                t2 = (h - o) / d
            lo = np.where(d == 0, np.where(np.abs(o) <= h, -np.inf, np.inf), np.minimum(t1, t2))
            hi = np.where(d == 0, np.where(np.abs(o) <= h, np.inf, -np.inf), np.maximum(t1, t2))
            enter = np.max(lo, axis=1)
            leave = np.min(hi, axis=1)
            hidden |= (enter <= leave) & (leave >= 0.0) & (enter <= 1.0)
        return hidden

    def key(self, t: float) -> tuple:
        """What the heads look like at ``t`` (for render caches): angle (rounded) and radius."""
        return round(self.angle_at(t), 6), self.radius_at(t)
