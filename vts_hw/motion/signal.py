"""Small signal helpers shared by the motion analysis: gap filling and zero-phase filters."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.signal import butter, sosfiltfilt

__all__ = ["fill_gaps", "bandpass", "highpass", "lowpass", "sample_rate"]


def sample_rate(t) -> float:
    d = np.diff(np.asarray(t, float))
    d = d[np.isfinite(d) & (d > 0)]
    return 1.0 / float(np.median(d)) if d.size else 25.0


def fill_gaps(t, x):
    """``x`` (F, ...) with NaN rows filled by linear interpolation in time (ends held)."""
    x = np.array(x, float)
    flat = x.reshape(len(x), -1)
    for k in range(flat.shape[1]):
        ok = np.isfinite(flat[:, k])
        if ok.all() or not ok.any():
            if not ok.any():
                flat[:, k] = 0.0
            continue
        flat[~ok, k] = np.interp(t[~ok], t[ok], flat[ok, k])
    return flat.reshape(x.shape)


@lru_cache(maxsize=64)
def _design(order: int, wn: tuple, btype: str) -> np.ndarray:
    """The Butterworth sections (designing them is half a live rate's cost: the keys repeat)."""
    return butter(order, wn[0] if len(wn) == 1 else list(wn), btype=btype, output="sos")


def _filt(t, x, btype, cut, order=2):
    fs = sample_rate(t)
    nyq = fs / 2.0
    wn = np.clip(np.atleast_1d(np.asarray(cut, float)) / nyq, 1e-4, 0.99)
    sos = _design(order, tuple(float(w) for w in wn), btype).copy()  # (the filter wants its own)
    x = fill_gaps(t, x)
    if len(x) < 15:
        return x - x.mean(axis=0) if btype != "lowpass" else x
    return sosfiltfilt(sos, x, axis=0, padlen=min(len(x) - 1, int(3 * fs / max(float(np.min(cut)), 0.05))))


def bandpass(t, x, lo=0.08, hi=1.0):
    """Zero-phase Butterworth band-pass (Hz) along axis 0; gaps filled first."""
    return _filt(t, x, "bandpass", [lo, hi])


def highpass(t, x, cut=0.08):
    return _filt(t, x, "highpass", cut)


def lowpass(t, x, cut=1.0):
    return _filt(t, x, "lowpass", cut)
