"""Which tracked markers are the patient's, and in which band.

Marker ids are whatever the tracker gave, so the patient's markers are found by behaviour, by
the one identity of every marker in view (:func:`vts_hw.vision.marker_roles.roles_of_positions`,
the same the live path, the daily QA and the console use): a marker seen in at least
``min_seen`` of the frames whose position (low-passed at 1 Hz) **moved** -- breathing or a body
move -- is the patient's. Wall markers, the table's and anything else still are left out, and
every marker's reason is kept (with its breathing RMS at 0.08-1 Hz and its slow range). The patient's markers are then grouped into bands by geometry: sorted
along the line they spread most on, split at the largest gap when it is over ``band_gap_mm``
(the chest and abdomen bands are ~20 cm apart, the markers of one band ~5-15 cm).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vts_hw.errors import DataError
from vts_hw.motion.signal import bandpass, lowpass, sample_rate
from vts_hw.vision.marker_roles import PATIENT_ROLES, roles_of_positions

__all__ = ["Bands", "find_bands", "band_names", "split_bands"]

#: the head end of the table in the SPECT frame: -Z (docs/design.md's room: the patient supine, head
#: first, towards the cameras over the head end)
HEAD_DIRECTION = np.array([0.0, 0.0, -1.0])
SMOOTH_HZ = 1.0  # positions low-passed at this before the identity is asked (breathing is under 1 Hz)
NAME_MIN_MM = 50.0  # two bands are told apart when their centres are this far apart along the body


@dataclass
class Bands:
    """``patient``: column indices (into the series) of the patient's markers; ``groups``: the
    bands, lists of those columns in order along the body; ``breath_rms_mm``, ``range_mm``,
    ``seen_fraction`` per column of the series; ``why``: per column, the reason it is in or out."""

    patient: list
    groups: list
    breath_rms_mm: np.ndarray
    range_mm: np.ndarray
    seen_fraction: np.ndarray
    why: list = field(default_factory=list)


def _fs(t) -> int:
    return max(1, int(round(sample_rate(t))))


def find_bands(
    series, *, breath_mm: float = 0.25, min_seen: float = 0.3, band_gap_mm: float = 60.0, frames=None
) -> Bands:
    """``frames``: (F,) the rows that had frames (a marker is seen in a share of those: time
    without frames is no marker's fault); None: every row."""
    t, P = series.t, series.P
    seen = series.seen
    rows = np.ones(len(t), bool) if frames is None else np.asarray(frames, bool)
    frac = seen[rows].mean(axis=0) if rows.any() else np.zeros(P.shape[1])
    M = P.shape[1]
    rms = np.zeros(M)
    rng = np.zeros(M)
    why = [""] * M
    patient, candidates = [], []
    X = np.full(P.shape, np.nan)
    for m in range(M):
        if frac[m] < min_seen:
            why[m] = f"seen in {100 * frac[m]:.0f} % of the frames (< {100 * min_seen:.0f} %)"
            continue
        ok = seen[:, m]
        first, last = np.flatnonzero(ok)[[0, -1]]
        sl = slice(first, last + 1)
        bp = bandpass(t[sl], P[sl, m])
        e2 = np.where(ok[sl], np.sum(bp**2, axis=1), np.nan)
        # the median over 10 s windows: a body move rings in the filter for a few seconds only
        win = [e2[k : k + 10 * _fs(t)] for k in range(0, len(e2), 10 * _fs(t))]
        rms[m] = float(np.sqrt(np.nanmedian([float(np.nanmean(w)) for w in win if np.isfinite(w).sum() > 10] or [0.0])))
        slow = lowpass(t[sl], P[sl, m], 0.1)[ok[sl]]
        rng[m] = float(np.max(np.linalg.norm(slow - np.median(slow, axis=0), axis=1)))
        X[sl, m] = np.where(ok[sl, None], lowpass(t[sl], P[sl, m], SMOOTH_HZ), np.nan)
        candidates.append(m)
    # what each marker is: the one identity (vision.marker_roles), on positions smoothed at 1 Hz
    # (breathing and moves kept, a far marker's triangulation jitter not taken for motion)
    roles = roles_of_positions(X, frame=series.frame) if candidates else []
    for m in candidates:
        r = roles[m]
        if r.role in PATIENT_ROLES:
            patient.append(m)
            why[m] = (
                f"breathes ({rms[m]:.2f} mm RMS at 0.08-1 Hz)"
                if rms[m] >= breath_mm
                else f"moved ({rng[m]:.1f} mm) without breathing"
            ) + f": {r.reason}"
        else:
            why[m] = f"{r.role}: {r.reason}: not the patient's"
    if len(patient) < 3:
        raise DataError(
            f"only {len(patient)} marker(s) breathe or move: the patient's band markers need "
            f"at least 3 seen in {100 * min_seen:.0f} % of the frames (markers: "
            + "; ".join(f"{series.label(m)} {why[m]}" for m in range(M))
            + ")"
        )
    mean = np.array([np.nanmedian(P[:, m], axis=0) for m in patient])
    groups = [[patient[i] for i in g] for g in split_bands(mean, band_gap_mm)]
    return Bands(patient, groups, rms, rng, frac, why)


def split_bands(mean, band_gap_mm: float = 60.0) -> list[list[int]]:
    """The bands of markers at ``mean`` (K, 3): indices, one band or two split at the largest gap
    (over ``band_gap_mm``, two or more markers each side) along any direction in the markers'
    main plane, in order along that direction. The one band finder of the live path and the
    offline analysis (issue 33)."""
    mean = np.asarray(mean, float).reshape(-1, 3)
    K = len(mean)
    if K < 4:
        return [list(range(K))]
    c = mean - mean.mean(axis=0)
    best: tuple[float, np.ndarray, int] = (0.0, np.zeros(0, int), 0)
    vt = np.linalg.svd(c, full_matrices=False)[2]
    ang = np.radians(np.arange(0.0, 180.0, 2.0))
    dirs = np.concatenate([vt, np.cos(ang)[:, None] * vt[0] + np.sin(ang)[:, None] * vt[1]])
    for axis in dirs:  # the largest gap along any direction in the markers' main plane
        pos = c @ axis
        order = np.argsort(pos)
        gaps = np.diff(pos[order])
        if gaps.size and gaps.max() > best[0]:
            best = (float(gaps.max()), order, int(gaps.argmax()) + 1)
    if best[0] > band_gap_mm and min(best[2], K - best[2]) >= 2:
        order, k = best[1], best[2]
        return [[int(i) for i in order[:k]], [int(i) for i in order[k:]]]
    return [list(range(K))]


def band_names(centres, frame: str) -> tuple[list[str], str]:
    """A name per band (``centres``: each band's centre, mm, in ``frame``) and how they were
    told apart. With two bands in the SPECT frame, the one nearer the head end
    (:data:`HEAD_DIRECTION`) is the ``chest``, the other the ``abdomen``; where the geometry
    does not say (the VTS frame, one band or three, bands side by side) ``band 1``, ``band 2``
    ... in order along the body."""
    generic = [f"band {k}" for k in range(1, len(centres) + 1)]
    if frame != "spect":
        return generic, (
            "positions in the VTS frame, where the head end is not known (with a VTS -> SPECT "
            "mapping the bands are named chest and abdomen)"
        )
    if len(centres) != 2:
        return generic, f"{len(centres)} band(s): chest and abdomen are told apart with two"
    along = [float(np.dot(np.asarray(c, float), HEAD_DIRECTION)) for c in centres]
    if not all(np.isfinite(along)) or abs(along[0] - along[1]) < NAME_MIN_MM:
        return generic, (
            f"the bands' centres are less than {NAME_MIN_MM:g} mm apart along the table: which is "
            "nearer the head is not clear"
        )
    chest = int(np.argmax(along))
    return (
        ["chest" if k == chest else "abdomen" for k in range(2)],
        "the band nearer the head end of the table (-Z in the SPECT frame; the patient supine, head first) "
        "is the chest",
    )
