"""A marker carrying a radioactive source, moved a few times along the table axis (Z).

The sync check's moving target: one retro-reflective sphere that the cameras see and that
holds a drop of activity that the SPECT sees. :func:`add_source_marker` puts it on the
scene's table as a :class:`~vts_hw.sim_devices.scene.RigidBody` and schedules quick moves
along Z at given host times (UTC epoch seconds); it returns the truth (:class:`SourceMarker`).

Each move follows a smooth minimum-jerk profile over ``move_s`` (about 0.3 s), written into
the body's pose schedule in ``step_s`` steps (each step holds the profile's value at its
middle, so the staircase has no lag). The truth of a move is its start, end and **middle**
(half the displacement, the instant both systems should agree on), and the positions before
and after. Positions are table coordinates in mm (the table's own moves add to them).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vts_hw.sim_devices.scene import SPHERE_DIAMETER, Marker, RigidBody, Scene


@dataclass(frozen=True)
class Move:
    """One move along Z: host times (UTC epoch s) and table-frame Z before and after (mm)."""

    t_start: float
    t_end: float
    z_from: float
    z_to: float

    @property
    def t_mid(self) -> float:
        """When half the displacement is done (the profile is symmetric)."""
        return 0.5 * (self.t_start + self.t_end)

    @property
    def step_mm(self) -> float:
        return self.z_to - self.z_from


@dataclass
class SourceMarker:
    """The truth about a source marker: where it is, how active, and how it moved."""

    body: str
    marker_id: str
    position: tuple[float, float, float]  # start position, table coordinates, mm
    rate_cps: float  # detected counts per second
    moves: list[Move] = field(default_factory=list)

    def z_at(self, t) -> np.ndarray:
        """Table-frame Z (mm) at host times ``t``, the exact smooth profile."""
        t = np.asarray(t, dtype=float)
        z = np.full(t.shape, self.position[2], dtype=float)
        for m in self.moves:
            s = np.clip((t - m.t_start) / (m.t_end - m.t_start), 0.0, 1.0)
            z = np.where(t >= m.t_start, m.z_from + m.step_mm * min_jerk(s), z)
        return z

    def to_json(self) -> dict:
        return {
            "body": self.body,
            "marker": self.marker_id,
            "position_mm": list(self.position),
            "rate_cps": self.rate_cps,
            "moves": [
                {"t_start": m.t_start, "t_mid": m.t_mid, "t_end": m.t_end, "z_from_mm": m.z_from, "z_to_mm": m.z_to}
                for m in self.moves
            ],
        }


def source_marker_from_json(scene: Scene, data: dict) -> SourceMarker:
    """Put a source marker described by :meth:`SourceMarker.to_json` (e.g. from a truth
    file) into another scene with the same moves, so that another process can rebuild it."""
    moves = data["moves"]
    move_s = moves[0]["t_end"] - moves[0]["t_start"] if moves else 0.3
    return add_source_marker(
        scene,
        [m["t_start"] for m in moves],
        [m["z_to_mm"] - m["z_from_mm"] for m in moves],
        name=data["body"],
        marker_id=data["marker"],
        position=tuple(data["position_mm"]),
        move_s=move_s,
        rate_cps=data["rate_cps"],
    )


def min_jerk(s):
    """The minimum-jerk profile 10s³ − 15s⁴ + 6s⁵ on [0, 1] (0 → 1, symmetric about ½)."""
    s = np.asarray(s, dtype=float)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


def add_source_marker(
    scene: Scene,
    move_times,
    steps_mm,
    *,
    name: str = "source",
    marker_id: str = "SRC",
    position=(0.0, 0.0, 0.0),
    move_s: float = 0.3,
    step_s: float = 0.005,
    rate_cps: float = 3000.0,
    diameter_mm: float = SPHERE_DIAMETER,
) -> SourceMarker:
    """Add a source-carrying sphere at ``position`` (table coordinates, mm) and move it by
    ``steps_mm[i]`` along Z starting at host time ``move_times[i]``, each move taking
    ``move_s``. Returns the truth. Moves must not overlap."""
    move_times = [float(t) for t in move_times]
    steps_mm = [float(s) for s in steps_mm]
    if len(move_times) != len(steps_mm):
        raise ValueError("give one step (mm) per move time")
    if any(b < a + move_s for a, b in zip(move_times, move_times[1:])):
        raise ValueError("moves must be in time order and must not overlap")
    x, y, z = (float(v) for v in position)
    body = RigidBody(
        name,
        [Marker(marker_id, np.zeros(3), np.array([0.0, 1.0, 0.0]), diameter_mm, "sphere")],
        ((0.0, 0.0, 0.0), (x, y, z)),
    )
    scene.add_body(body)
    truth = SourceMarker(name, marker_id, (x, y, z), float(rate_cps))
    n = max(1, int(round(move_s / step_s)))
    for t0, dz in zip(move_times, steps_mm):
        for k in range(n):
            s_mid = (k + 0.5) / n
            scene.set_body_pose(name, (0.0, 0.0, 0.0), (x, y, z + dz * float(min_jerk(s_mid))), t0 + k * move_s / n)
        scene.set_body_pose(name, (0.0, 0.0, 0.0), (x, y, z + dz), t0 + move_s)
        truth.moves.append(Move(t0, t0 + move_s, z, z + dz))
        z += dz
    return truth


def plan_moves(
    t_start: float,
    duration_s: float,
    n: int = 4,
    seed: int = 0,
    min_mm: float = 10.0,
    max_mm: float = 30.0,
    margin_s: float = 2.0,
):
    """``n`` move times spread over [t_start + margin, t_start + duration − margin] (jittered,
    at least 2 s apart) and steps of ``min_mm``–``max_mm`` with alternating sign, so the
    source stays near where it started. Returns (times, steps)."""
    rng = np.random.default_rng(seed)
    span = duration_s - 2 * margin_s
    if span <= 2.0 * n:
        raise ValueError(f"{duration_s} s is too short for {n} moves")
    slots = t_start + margin_s + (np.arange(n) + 0.5) * span / n
    times = slots + rng.uniform(-0.25, 0.25, n) * (span / n - 2.0)
    steps = rng.uniform(min_mm, max_mm, n) * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    return [float(t) for t in times], [float(s) for s in steps]
