"""The reference period of the live estimate: the patient's markers found by how they behave
while the body keeps still, despite frames lost, and whether or not they breathe.

Every instant with points is kept (time, marker identities, positions). Identities come from
:class:`~vts_hw.tracking.live.marker_tracks.MarkerTracks` with **no track end**: a marker unseen during
a gap (frames a busy host or network dropped, a camera reconnecting) keeps its identity when
it is seen again near where it was, so a gap never splits a marker into several that are
each seen too rarely. "Seen often enough" counts the *instants* that have points (frame sets),
not the time: a gap takes instants away from every marker alike.

The reference is tried once it spans ``reference_s`` and its instants cover at least
``min_observed`` of that time (time between instants more than ``step_s`` apart is not
covered); until then it keeps collecting, over at most ``max_span`` times ``reference_s``
(older instants are let go).

The patient's markers, from what they do over the reference:

* markers that **breathe** (a range of at least ``min_breath_mm`` along their main direction)
  and, in the SPECT frame, lie inside the field of view: the wall, the table and a phantom are
  still and left out -- as long as three or more breathe;
* otherwise, in the SPECT frame, **every marker inside the bore** (a patient who holds still,
  markers on the head): within ``bore_radius_mm`` of the axis and ``bore_half_length_mm`` of
  the FOV centre along it, the space the detector heads turn around, where nothing but the
  patient (and the table) is during a scan -- the wall behind the gantry is not (in the
  reference room its markers are 0.38 m or more behind the FOV centre, the patient's within
  0.25 m of it); they are fitted rigidly, with no breathing term;
* otherwise (no SPECT mapping: still markers cannot be told from the wall's) no reference.

See docs/decisions/0036-live-motion.md and 0048-live-tracking-when-frames-are-lost.md.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from vts_hw.errors import DataError
from vts_hw.motion.bands import band_names, split_bands
from vts_hw.motion.patient_model import PatientModel, learn_model
from vts_hw.tracking.live.marker_tracks import MarkerTracks

__all__ = ["ReferenceCollector", "observed_s", "breathing_range"]


def breathing_range(samples: np.ndarray) -> np.ndarray:
    """Per marker of ``samples`` (S, M, 3; NaN: not seen) the range (5th to 95th percentile, mm)
    of its positions along their first principal direction."""
    out = np.zeros(samples.shape[1])
    for i in range(samples.shape[1]):
        p = samples[:, i]
        p = p[np.isfinite(p).all(axis=1)]
        if len(p) < 3:
            continue
        p = p - p.mean(axis=0)
        proj = p @ np.linalg.svd(p, full_matrices=False)[2][0]
        out[i] = np.percentile(proj, 95) - np.percentile(proj, 5)
    return out


def observed_s(times, step_s: float) -> float:
    """The time covered by instants at ``times`` (s, in order): the sum of the steps between
    consecutive instants that are at most ``step_s`` apart."""
    d = np.diff(np.asarray(times, float))
    return float(d[d <= step_s].sum())


class ReferenceCollector:
    def __init__(self, settings, frame: str, axis, toward):
        self.s = settings
        self.frame = frame
        self.axis, self.toward = axis, toward
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
            return None, (f"{covered:.1f} s of the last {t - self.instants[0][0]:.1f} s had frames "
                          f"(at least {self.s.ref_min_observed * self.s.reference_s:.1f} s needed)")
        samples = self._samples()
        if samples.shape[1] == 0:
            return None, "no marker seen often enough"
        breathes = breathing_range(samples) >= self.s.min_breath_mm
        inside = np.ones(samples.shape[1], bool)
        if self.frame == "spect":
            mean = np.nanmean(samples, axis=0)
            inside = ((np.linalg.norm(mean[:, :2], axis=1) <= self.s.fov_radius_mm)
                      & (np.abs(mean[:, 2]) <= self.s.fov_half_length_mm))
        bore = np.zeros(samples.shape[1], bool)
        if self.frame == "spect":
            bore = ((np.linalg.norm(mean[:, :2], axis=1) <= self.s.bore_radius_mm)
                    & (np.abs(mean[:, 2]) <= self.s.bore_half_length_mm))
        if (breathes & inside).sum() >= 3:
            patient = breathes & inside
        elif bore.sum() >= 3:
            patient = bore                   # a patient holding still, markers on the head
        elif self.frame == "spect":
            return None, (f"fewer than three markers breathe ({int((breathes & inside).sum())}) and fewer than "
                          f"three are still inside the bore ({int(bore.sum())})")
        else:
            return None, (f"fewer than three markers breathe ({int(breathes.sum())}); without a SPECT mapping "
                          f"(calibration.spect) still markers cannot be told from the wall's")
        mine = samples[:, patient]
        mean = np.nanmean(mine, axis=0)
        bands = split_bands(mean, self.s.band_gap_mm)
        # bands in order along the body's axis (the table), as the offline analysis names them
        bands.sort(key=lambda g: float(np.mean(mean[g] @ self.axis)))
        names, _ = band_names([mean[g].mean(axis=0) for g in bands], self.frame)
        try:
            model = learn_model(self._times(), mine, frame=self.frame, bands=bands, band_names=names,
                                min_breath_mm=self.s.min_breath_mm)
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
