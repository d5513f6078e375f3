"""The respiratory signal and its cycles.

* :func:`principal_signal` — the first principal component of the markers' band-passed
  (0.08-1 Hz) displacements in the body's frame: the pattern the markers move in together at
  breathing rates. Its loading vector projects the unfiltered displacements, so that the slow
  part of breathing (a wandering baseline) is kept.
* :func:`breathing_vectors` — per marker, the displacement per unit of the signal, regressed
  over still periods only (each period detrended on its own: a body move or a slow creep does
  not leak in; a high-pass filter would ring for seconds after every move).
* :class:`Respiration` — the signal, phase and rate per frame, the breaths seen whole and
  the figures resting on them (the cycles' rules: :mod:`.cycles`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vts_hw.motion.cycles import BreathingFigures
from vts_hw.motion.signal import bandpass, fill_gaps, sample_rate

__all__ = ["principal_signal", "breathing_vectors", "Respiration"]


def principal_signal(t, D, lo=0.08, hi=1.0):
    """``(s, u)``: the signal (F,) and the loading (M*3,) of the first principal component of
    ``D`` (F, M, 3) band-passed; ``s`` = the centred, unfiltered ``D`` projected on ``u``."""
    F = len(t)
    X = fill_gaps(t, D.reshape(F, -1))
    bp = bandpass(t, X, lo, hi)
    good = np.isfinite(bp).all(axis=0)
    bp = np.where(good, bp, 0.0)
    _, sv, vt = np.linalg.svd(bp - bp.mean(axis=0), full_matrices=False)
    u = vt[0]
    s = (X - np.median(X, axis=0)) @ u
    return s, u, sv


def breathing_vectors(t, Dbody, s, still, min_len_s: float = 3.0):
    """(M, 3): per marker, mm per unit of ``s``, regressed over the ``still`` frames. Each
    still run is detrended (offset and slope removed from the displacements and the signal)
    before the runs are pooled. ``Dbody``: positions in the reference body frame with the
    segment's pose taken out (F, M, 3), NaN when unseen."""
    F, M, _ = Dbody.shape
    fs = sample_rate(t)
    num = np.zeros((M, 3))
    den = np.zeros(M)
    runs = _runs(still)
    for a, b in runs:
        if (b - a) / fs < min_len_s:
            continue
        tt = t[a:b] - t[a:b].mean()
        A = np.column_stack([np.ones(b - a), tt])
        ss = s[a:b]
        okS = np.isfinite(ss)
        for m in range(M):
            ok = okS & np.isfinite(Dbody[a:b, m, 0])
            if ok.sum() < 10:
                continue
            Am = A[ok]
            ps = ss[ok] - Am @ np.linalg.lstsq(Am, ss[ok], rcond=None)[0]
            pd = Dbody[a:b, m][ok]
            pd = pd - Am @ np.linalg.lstsq(Am, pd, rcond=None)[0]
            num[m] += ps @ pd
            den[m] += ps @ ps
    return np.where(den[:, None] > 0, num / np.maximum(den, 1e-12)[:, None], 0.0)


def _runs(mask):
    """[(start, stop)) index runs where ``mask`` is True."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(int))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


@dataclass
class Respiration:
    """``amplitude`` (F,) mm of the marker that breathes most (0 at the reference's mean
    breath, positive = inhaled; NaN without a pose, 0 where no breathing was found); ``phase``
    (F,) 0-1 from the start of inhalation and ``rate`` (F,) breaths/min, inside whole breaths
    only; ``cycles`` the breaths seen whole; ``vectors`` (M, 3) mm of each marker per mm of
    ``amplitude``; ``figures``: status, rate, amplitude and what they rest on
    (:class:`~vts_hw.motion.cycles.BreathingFigures`)."""

    t: np.ndarray
    amplitude: np.ndarray
    phase: np.ndarray
    rate: np.ndarray
    cycles: list
    vectors: np.ndarray
    figures: BreathingFigures | None = None

    @property
    def mean_rate_per_min(self) -> float | None:
        """The rate when it is known (measured or bounded), else None."""
        f = self.figures
        return f.rate_per_min if f is not None and f.status in ("measured", "bounded") else None
