"""The reference period of the live estimate: the patient's markers found by how they behave
while the body keeps still, despite frames lost, and whether or not they breathe.

Every instant with points is kept (time, marker identities, positions). Identities come from
:class:`~vts_hw.tracking.identities.MarkerTracks` with **no track end**: a marker unseen during
a gap (frames a busy host or network dropped, a camera reconnecting) keeps its identity when
it is seen again near where it was, so a gap never splits a marker into several that are
each seen too rarely. "Seen often enough" counts the *instants* that have points (frame sets),
not the time: a gap takes instants away from every marker alike.

The reference is tried once it spans ``reference_s`` and its instants cover at least
``min_observed`` of that time (time between instants more than ``step_s`` apart is not
covered); until then it keeps collecting, over at most ``max_span`` times ``reference_s``
(older instants are let go).

The patient's markers are those the one identity of every marker in view
(:func:`vts_hw.vision.marker_roles.roles_of_positions`, the same the daily QA, the drift baseline,
aim and the console use) calls the patient's: they **moved** over the reference (breathing) --
the wall, the table and a phantom are still and left out -- as long as three or more did;
otherwise, in the SPECT frame, every still marker **inside the table-and-gantry volume** (a
patient who holds still, markers on the head), fitted rigidly, with no breathing term; otherwise
(no SPECT mapping: still markers cannot be told from the wall's) no reference.

See docs/decisions/0036-live-motion.md and 0048-live-tracking-when-frames-are-lost.md.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from vts_hw.errors import DataError
from vts_hw.motion.bands import band_names, split_bands
from vts_hw.motion.patient_model import PatientModel, learn_model
from vts_hw.tracking.identities import MarkerTracks
from vts_hw.vision.marker_roles import PATIENT_ROLES, TableSpace, roles_of_positions

__all__ = ["ReferenceCollector", "observed_s"]


def observed_s(times, step_s: float) -> float:
    """The time covered by instants at ``times`` (s, in order): the sum of the steps between
    consecutive instants that are at most ``step_s`` apart."""
    d = np.diff(np.asarray(times, float))
    return float(d[d <= step_s].sum())


class ReferenceCollector:
    def __init__(self, settings, frame: str, axis, space: TableSpace | None = None):
        self.s = settings
        self.frame = frame
        self.space = space or TableSpace.from_settings()
        self.roles: list = []  # what each marker of the last try was (vision.marker_roles)
        self.axis = axis
        self.instants: deque[tuple[float, np.ndarray, np.ndarray]] = deque()
        self._tracks = MarkerTracks(settings.gate_mm, float("inf"))
        self._next_try = -np.inf

    @property
    def t0(self) -> float | None:
        return self.instants[0][0] if self.instants else None

    def observed(self) -> float:
        return observed_s([i[0] for i in self.instants], self.s.step_s)

    def add(self, t: float, pts: np.ndarray) -> None:
        self.instants.append((t, self._tracks.update(t, pts), pts))
        while t - self.instants[0][0] > self.s.ref_max_span * self.s.reference_s:
            self.instants.popleft()

    def due(self, t: float) -> bool:
        """Whether to try learning now: the span reached and, at most once a second, retried."""
        return bool(self.instants) and t - self.instants[0][0] >= self.s.reference_s and t >= self._next_try

    def restart(self) -> None:
        """Keep only the last half of the reference (the body did not keep still before it)."""
        last = self.instants[-1][0]
        while self.instants and self.instants[0][0] <= last - self.s.reference_s / 2:
            self.instants.popleft()

    def learn(self, t: float) -> tuple[PatientModel | None, str]:
        """``(model, why not)``: the model of the patient's markers, or why there is none yet
        (the reference goes on collecting; whether the body kept still is the caller's check)."""
        self._next_try = t + 1.0
        covered = self.observed()
        if covered < self.s.ref_min_observed * self.s.reference_s:
            return None, (
                f"{covered:.1f} s of the last {t - self.instants[0][0]:.1f} s had frames "
                f"(at least {self.s.ref_min_observed * self.s.reference_s:.1f} s needed)"
            )
        samples = self._samples()
        if samples.shape[1] == 0:
            return None, "no marker seen often enough"
        roles = roles_of_positions(samples, frame=self.frame, space=self.space)
        patient = np.array([r.role in PATIENT_ROLES for r in roles])
        still_in = np.zeros(len(roles), bool)
        if self.frame == "spect":
            still_in = ~patient & self.space.inside(np.nanmean(samples, axis=0))
        if patient.sum() >= 3:
            pass
        elif still_in.sum() >= 3:
            patient = still_in  # a patient holding still (markers on the head): on the table
        elif self.frame == "spect":
            return None, (
                f"fewer than three markers move ({int(patient.sum())}) and fewer than three are still "
                f"inside the table-and-gantry volume ({int(still_in.sum())})"
            )
        else:
            return None, (
                f"fewer than three markers move ({int(patient.sum())}); without a SPECT mapping "
                f"(calibration.mapping) still markers cannot be told from the wall's"
            )
        self.roles = roles
        mine = samples[:, patient]
        mean = np.nanmean(mine, axis=0)
        bands = split_bands(mean, self.s.band_gap_mm)
        # bands in order along the body's axis (the table), as the offline analysis names them
        bands.sort(key=lambda g: float(np.mean(mean[g] @ self.axis)))
        names, _ = band_names([mean[g].mean(axis=0) for g in bands], self.frame)
        try:
            model = learn_model(
                self._times(), mine, frame=self.frame, bands=bands, band_names=names, min_breath_mm=self.s.min_breath_mm
            )
        except DataError as exc:
            return None, str(exc)
        return model, ""

    def _times(self) -> np.ndarray:
        return np.array([i[0] for i in self.instants], float)

    def _samples(self) -> np.ndarray:
        """(S, M, 3): the markers seen in at least ``min_seen_fraction`` of the instants."""
        n = len(self.instants)
        counts: dict[int, int] = {}
        for _, ids, _ in self.instants:
            for i in ids.tolist():
                counts[i] = counts.get(i, 0) + 1
        keep = sorted(i for i, c in counts.items() if c >= self.s.min_seen_fraction * n)
        col = {i: k for k, i in enumerate(keep)}
        samples = np.full((n, len(keep), 3), np.nan)
        for s, (_, ids, pts) in enumerate(self.instants):
            for j, i in enumerate(ids.tolist()):
                if i in col:
                    samples[s, col[i]] = pts[j]
        return samples
