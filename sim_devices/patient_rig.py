"""The simulated patient on the simulated rig's table (``vts sim up --patient``).

:class:`PatientOptions` says what patient to simulate; ``SimRig(patient=PatientOptions(...))``
puts it on the table as the rig is built (before any camera serves), planned from that instant
for ``minutes`` (:func:`put_patient`): still for ``still_s``, then ``moves`` sudden body moves
spread over the plan, breathing throughout. After the plan the patient lies still and no
longer breathes (give ``minutes`` longer than the scans it should cover).

:func:`write_patient_truth` writes the truth of the whole plan into ``DIR/truth/`` of the
simulator's folder (``patient.json`` and ``patient_motion.csv`` at 25 Hz, see
:func:`~vts_hw.sim_devices.patient.write_truth`): never into a recording or a session, where a
procedure reads.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from vts_hw.sim_devices.patient import BodyMotion, BodyMove, Patient, add_patient, write_truth

__all__ = ["PatientOptions", "put_patient", "write_patient_truth", "TRUTH_DIR", "TRUTH_RATE_HZ"]

TRUTH_DIR = "truth"
TRUTH_RATE_HZ = 25.0  # a camera's frame rate: 10 minutes are 15 000 rows (about 4 MB)


@dataclass(frozen=True)
class PatientOptions:
    """The simulated patient: ``seed`` (breathing, amplitudes, moves), ``moves`` sudden body
    moves, planned over ``minutes`` after ``still_s`` still, ``breathing`` on or off,
    ``creep_mm`` a slow drift over the plan (0: none). ``move_at_s``: when the moves start, in
    seconds after the plan's start (then ``moves`` is their number; sizes and directions still
    drawn from ``seed``), for a scan that must see them."""

    seed: int = 0
    moves: int = 2
    minutes: float = 10.0
    breathing: bool = True
    still_s: float = 15.0
    creep_mm: float = 0.0
    move_at_s: tuple[float, ...] = ()

    def check(self) -> None:
        """ValueError naming what is wrong (a plan too short for its moves, numbers out of range)."""
        if self.moves < 0:
            raise ValueError(f"the number of body moves must be 0 or more, not {self.moves}")
        if not self.minutes > 0:
            raise ValueError(f"the plan must last more than 0 minutes, not {self.minutes:g}")
        if self.move_at_s:
            at = list(self.move_at_s)
            if len(at) != self.moves:
                raise ValueError(f"give one start time per body move ({self.moves}), not {len(at)}")
            if (
                at != sorted(at)
                or at[0] < 0
                or any(b - a < 2.0 for a, b in zip(at, at[1:]))
                or at[-1] + 2.0 > self.minutes * 60.0
            ):
                raise ValueError(
                    f"body moves at {at} s: in order, at least 2 s apart, inside the "
                    f"{self.minutes:g} minutes of the plan"
                )
            return
        need_s = self.still_s + 5.0 + 8.0 * self.moves
        if self.moves and self.minutes * 60.0 < need_s:
            raise ValueError(
                f"{self.minutes:g} minutes are too short for {self.moves} body moves "
                f"(they need {need_s / 60.0:.2f} minutes or more: {self.still_s:g} s still, "
                f"then 8 s between moves)"
            )

    # the detached rig gets its options on its command line
    def to_arg(self) -> str:
        return (
            f"patient={self.seed}:{self.moves}:{self.minutes!r}:{int(self.breathing)}:"
            f"{self.still_s!r}:{self.creep_mm!r}:{','.join(repr(float(x)) for x in self.move_at_s)}"
        )

    @classmethod
    def from_arg(cls, arg: str) -> PatientOptions:
        seed, moves, minutes, breathing, still, creep, at = arg.split("=", 1)[1].split(":")
        return cls(
            int(seed),
            int(moves),
            float(minutes),
            breathing == "1",
            float(still),
            float(creep),
            tuple(float(x) for x in at.split(",") if x),
        )


def put_patient(scene, options: PatientOptions, t0: float) -> Patient:
    """Put the patient of ``options`` on ``scene``'s table, planned from host time ``t0``."""
    options.check()
    duration = options.minutes * 60.0
    moves = None
    if options.move_at_s:  # the planned sizes and directions (a plan long enough for them), at these times
        drawn = BodyMotion.plan(
            t0,
            max(duration, options.still_s + 5.0 + 8.0 * options.moves),
            options.seed,
            n_moves=options.moves,
            still_s=options.still_s,
        ).moves
        moves = []
        for m, at in zip(drawn, options.move_at_s):
            length = min(m.t_end - m.t_start, 1.5)
            moves.append(BodyMove(t0 + at, t0 + at + length, m.rotation_deg, m.translation_mm))
    return add_patient(
        scene,
        t0,
        duration,
        options.seed,
        n_moves=options.moves,
        creep_mm=options.creep_mm,
        breathing=options.breathing,
        still_s=options.still_s,
        moves=moves,
    )


def write_patient_truth(patient: Patient, folder, rate_hz: float = TRUTH_RATE_HZ) -> list[Path]:
    """The truth of the patient's whole plan into ``folder/truth/``; returns the files."""
    t0 = patient.breathing.t0
    return write_truth(patient, Path(folder) / TRUTH_DIR, t0, t0 + patient.breathing.duration_s, rate_hz)
