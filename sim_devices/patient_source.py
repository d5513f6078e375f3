"""The activity inside the simulated patient: a "heart" the simulated SPECT counts.

A point source in the torso (body coordinates ``HEART_MM``: anterior-left of the body axis, at
the FOV centre when the body is at rest, see ``patient.PLACEMENT``) that moves with the body
-- :meth:`~vts_hw.sim_devices.patient.Patient.body_transform`, turns included -- and a little
with the breathing, mostly head-foot as the diaphragm pushes it: ``b(t) * breath_mm`` with
``breath_mm`` half the chest's anterior-posterior amplitude up and half the abdomen's towards
the feet. The list-mode simulation (:func:`vts_hw.sim_devices.spect_listmode.write_sim_listmode`)
takes it like any source and asks it for its positions (:meth:`PatientSource.positions`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vts_hw.sim_devices.patient import Patient

__all__ = ["HEART_MM", "PatientSource", "heart_source"]

HEART_MM = (20.0, 30.0, -60.0)  # body coordinates (X lateral, Y anterior, Z towards the feet): at rest
# (20, 0, 0) in the SPECT frame
POSE_GRID_S = 0.01  # the body's pose is evaluated this often and interpolated


@dataclass(frozen=True, eq=False)
class PatientSource:
    """A point of activity in ``patient`` (body coordinates ``point_mm``), ``rate_cps``
    detected counts per second, moving ``breath_mm`` (body coordinates, mm per unit of
    ``b(t)``) with the breathing."""

    patient: Patient
    rate_cps: float = 3000.0
    point_mm: tuple[float, float, float] = HEART_MM
    breath_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)
    name: str = "heart"

    @property
    def body(self) -> str:
        return self.patient.name

    @property
    def marker_id(self) -> str:
        return self.name

    def at(self, t: float, table_offset=(0.0, 0.0, 0.0)) -> np.ndarray:
        """Where the source is at host time ``t`` (SPECT frame, mm), the table at ``table_offset``."""
        R, tr = self.patient.body_transform(t)
        rest = self.patient.placement + np.asarray(self.point_mm, float)
        b = float(self.patient.breathing.value(t))
        return R @ (rest + b * np.asarray(self.breath_mm, float)) + tr + np.asarray(table_offset, float)

    def positions(self, scene, times) -> np.ndarray:
        """``(n, 3)`` positions at host ``times`` (sorted), the scene's table included: exact on
        a 10 ms grid, linear in between (a body move takes 0.4 s or more)."""
        times = np.asarray(times, float)
        if times.size == 0:
            return np.empty((0, 3))
        t0 = float(times[0])
        grid = t0 + POSE_GRID_S * np.arange(int(np.ceil((times[-1] - t0) / POSE_GRID_S)) + 2)
        pts = np.array([self.at(float(t), (0.0, *scene.table.at(float(t)))) for t in grid])
        return np.column_stack([np.interp(times, grid, pts[:, k]) for k in range(3)])

    def to_json(self) -> dict:
        """What the list-mode truth file says of this source."""
        return {
            "body": self.body,
            "marker": self.marker_id,
            "kind": "patient point source",
            "point_mm": list(self.point_mm),
            "breath_mm": list(self.breath_mm),
            "rate_cps": self.rate_cps,
            "moves": [
                {
                    "t_start": m.t_start,
                    "t_end": m.t_end,
                    "rotation_deg": list(m.rotation_deg),
                    "translation_mm": list(m.translation_mm),
                }
                for m in self.patient.motion.moves
            ],
        }


def heart_source(patient: Patient, rate_cps: float = 3000.0) -> PatientSource:
    """The patient's heart: at ``HEART_MM``, moved by breathing half the chest's amplitude
    anterior-posterior and half the abdomen's head-foot (towards the feet on inhaling)."""
    chest, abdomen = patient.breath_mm["chest"], patient.breath_mm["abdomen"]
    return PatientSource(patient, float(rate_cps), HEART_MM, (0.0, 0.5 * chest, 0.5 * abdomen))
