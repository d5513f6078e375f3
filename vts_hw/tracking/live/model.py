"""The reference of the patient's markers and the breathing-separated rigid fit.

Learned from the reference period (the first still period): each marker's mean position
``m_i``, its breathing direction ``d_i`` (the first principal direction of its positions,
unit, oriented towards ``toward``: the first camera) and its gain ``g_i`` (its breathing
spread relative to its band's mean). Markers are grouped into bands by their position along
``axis`` (a gap of more than ``band_gap_mm`` starts a new band).

The model of a marker at any time: ``x_i = R (m_i + beta_k g_i d_i) + T`` -- one rigid motion
of the whole body ``(R, T)`` and one breathing value ``beta_k`` (mm) per band ``k``.
:meth:`ReferenceModel.fit` solves it for the markers seen, alternating a Kabsch fit of the
breathing-corrected reference onto the seen positions with the least-squares breathing
value per band given the pose (a few iterations, started from the last solution). Breathing
that follows the learned directions is taken out of the pose; a rigid move is not, because
no common breathing value can mimic a translation or a turn of every marker of a band (the
directions differ from marker to marker: the band expands). A marker that does not breathe
(a still patient, a marker on the head: its range below the breathing floor) gets no breathing
term (gain 0): it is fitted rigidly, and a band of such markers has no breathing value. See 0036
and 0048.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vts_hw.vision.registration import kabsch

__all__ = ["ReferenceModel", "Fit", "bands_along", "breathing_range", "learn_reference"]


@dataclass
class Fit:
    """The pose and breathing at one instant: ``x -> R @ x + T`` from the reference; ``beta``
    per band (mm; NaN where the band had no marker seen); ``rms_mm`` the residual."""

    R: np.ndarray
    T: np.ndarray
    beta: np.ndarray
    rms_mm: float
    n_markers: int


@dataclass
class ReferenceModel:
    mean: np.ndarray        # (M, 3) reference positions
    direction: np.ndarray   # (M, 3) unit breathing directions
    gain: np.ndarray        # (M,) breathing spread relative to the band's mean
    band: np.ndarray        # (M,) band index per marker
    noise_mm: float = 0.0   # residual RMS of the model over the reference period (per marker)
    pose_noise_mm: float = 0.0    # RMS of the centre's move over the reference period (still body)
    pose_noise_deg: float = 0.0   # RMS of the turn over the reference period
    breathes: np.ndarray | None = None   # (M,) whether each marker breathes (None: all do)

    def band_breathes(self, k: int) -> bool:
        """Whether band ``k`` has a marker that breathes (else it has no breathing value)."""
        sel = self.band == k
        return bool(sel.any() and (self.breathes is None or self.breathes[sel].any()))

    @property
    def n_bands(self) -> int:
        return int(self.band.max()) + 1 if len(self.band) else 0

    @property
    def centre(self) -> np.ndarray:
        return self.mean.mean(axis=0)

    def fit(self, idx: np.ndarray, x: np.ndarray, beta0: np.ndarray | None = None,
            iterations: int = 4) -> Fit | None:
        """The pose and breathing from the positions ``x`` (K, 3) of markers ``idx`` (K,);
        None with fewer than three markers (or all on one line)."""
        idx = np.asarray(idx, int)
        x = np.asarray(x, float).reshape(-1, 3)
        if len(idx) < 3:
            return None
        nb = self.n_bands
        beta = np.zeros(nb) if beta0 is None else np.nan_to_num(np.asarray(beta0, float).copy())
        m, gd, band = self.mean[idx], self.gain[idx, None] * self.direction[idx], self.band[idx]
        seen = np.bincount(band, minlength=nb) > 0
        try:
            for _ in range(iterations):
                tr = kabsch(m + beta[band, None] * gd, x)
                local = (x - tr.t) @ tr.R - m           # R^T (x - T) - m: the breathing part
                num = np.bincount(band, np.einsum("ij,ij->i", local, gd), nb)
                den = np.bincount(band, np.einsum("ij,ij->i", gd, gd), nb)
                beta = np.where(den > 0, num / np.where(den > 0, den, 1.0), beta)
            tr = kabsch(m + beta[band, None] * gd, x)
        except ValueError:          # collinear markers: no turn can be told
            return None
        r = x - ((m + beta[band, None] * gd) @ tr.R.T + tr.t)
        rms = float(np.sqrt(np.mean(np.sum(r * r, axis=1))))
        return Fit(tr.R, tr.t, np.where(seen, beta, np.nan), rms, len(idx))


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


def bands_along(points: np.ndarray, axis: np.ndarray, gap_mm: float) -> np.ndarray:
    """Band index per point: sorted along ``axis``, a gap wider than ``gap_mm`` starts a band."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    s = np.asarray(points, float).reshape(-1, 3) @ axis
    order = np.argsort(s)
    band = np.zeros(len(s), int)
    if len(s):
        breaks = np.concatenate([[0], np.cumsum(np.diff(s[order]) > gap_mm)])
        band[order] = breaks
    return band


def learn_reference(samples: np.ndarray, axis, toward, gap_mm: float = 60.0,
                    iterations: int = 6, breathes=None) -> ReferenceModel:
    """The model from ``samples`` (S, M, 3): M markers over S instants of the reference period
    (NaN where a marker was not seen; each marker needs a few instants). ``axis``: the body's
    long axis (bands lie across it); ``toward``: a point the breathing directions face (the
    first camera's centre: markers on the front and flanks of a supine patient face it).
    ``breathes``: (M,) bool, the markers that breathe (default all); the others get gain 0."""
    samples = np.asarray(samples, float)
    breathes = np.ones(samples.shape[1], bool) if breathes is None else np.asarray(breathes, bool)
    mean = np.nanmean(samples, axis=0)
    M = mean.shape[0]
    direction = np.zeros((M, 3))
    spread = np.zeros(M)
    for i in range(M):
        p = samples[:, i]
        p = p[np.isfinite(p).all(axis=1)] - mean[i]
        _, s, vt = np.linalg.svd(p, full_matrices=False)
        d = vt[0]
        if d @ (np.asarray(toward, float) - mean[i]) < 0:
            d = -d
        direction[i] = d
        spread[i] = s[0] / np.sqrt(max(len(p), 1))
    band = bands_along(mean, axis, gap_mm)
    gain = np.ones(M)
    for k in range(band.max() + 1 if M else 0):
        sel = (band == k) & breathes
        if sel.any() and spread[sel].mean() > 0:
            gain[sel] = spread[sel] / spread[sel].mean()
    gain[~breathes] = 0.0          # no breathing term: fitted rigidly
    model = ReferenceModel(mean, direction, gain, band, breathes=breathes.copy())
    # the signs of one band's directions must agree with each other: each marker's breathing
    # is compared with its band's first marker (correlation), not only with the camera
    for k in range(model.n_bands):
        sel = np.flatnonzero(band == k)
        proj = np.einsum("sij,ij->si", samples[:, sel] - mean[sel], direction[sel])
        lead = sel[np.argmax(spread[sel])]
        ref = proj[:, list(sel).index(lead)]
        for j, i in enumerate(sel):
            ok = np.isfinite(proj[:, j]) & np.isfinite(ref)
            if ok.sum() > 2 and np.corrcoef(proj[ok, j], ref[ok])[0, 1] < 0:
                direction[i] = -direction[i]
    res, moves, turns = [], [], []
    c = model.centre
    beta = None
    for s in samples:   # in time order, each fit started from the last (as when tracking)
        ok = np.isfinite(s).all(axis=1)
        f = model.fit(np.flatnonzero(ok), s[ok], beta, iterations=iterations)
        if f is not None:
            beta = np.where(np.isfinite(f.beta), f.beta, 0.0)
            res.append(f.rms_mm)
            moves.append(np.linalg.norm(f.R @ c + f.T - c))
            turns.append(np.degrees(np.arccos(np.clip((np.trace(f.R) - 1) / 2, -1.0, 1.0))))
    rms = (lambda v: float(np.sqrt(np.mean(np.square(v)))) if v else float("nan"))
    model.noise_mm, model.pose_noise_mm, model.pose_noise_deg = rms(res), rms(moves), rms(turns)
    return model
