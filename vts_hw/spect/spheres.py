"""Centroids of the N hottest spheres in a reconstructed SPECT volume (mm, SPECT frame).

The algorithm (the choices were measured; see docs/decisions/0014-spect-inputs.md):

1. **Detection** on a copy smoothed by a Gaussian of ``smooth_sigma`` voxels: the background
   level ``b`` is the volume's median; voxels above ``b + threshold_fraction·(peak − b)``, with
   ``peak`` the smoothed maximum, are labelled (``scipy.ndimage.label``, 26-connectivity).
   Components smaller than ``min_voxels`` are dropped as noise. The ``n_expected`` components
   with the largest smoothed peak are kept; the count found is reported.
2. **Centroid** of each kept component, on the *unsmoothed* data: a spherical window of radius
   ``window_radius`` mm around the current estimate (first the smoothed peak); the local
   background is the median of a shell ``shell`` mm thick just outside the window; the
   centroid is Σ(I − B)·x / Σ(I − B) over the window (not clipped at zero: clipping biases
   it). The window is re-centred on the new centroid ``iterations`` times, so that the tails it
   cuts off are symmetric about the sphere.
3. Indices go to mm through the volume's affine (:meth:`Volume.index_to_mm`).

Order: by default ascending Z, then Y, then X of the centroid; with ``reference`` points
(e.g. the previous step or the VTS positions, in the same order as the phantom's spheres), the
centroids are put in the order of the reference by a minimum-total-distance assignment.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from vts_hw.errors import DataError
from vts_hw.spect.volume import Volume


@dataclass(frozen=True)
class SphereSettings:
    """Tuning of :func:`find_spheres` (defaults for 13 mm spheres, ~10 mm FWHM, ~4.4 mm voxels)."""

    smooth_sigma: float = 1.0  # voxels, detection only
    threshold_fraction: float = 0.15  # of (smoothed max − median)
    min_voxels: int = 4
    window_radius: float = 20.0  # mm: ball radius + ~1.5 FWHM
    shell: float = 8.0  # mm, background shell outside the window
    iterations: int = 3


@dataclass(frozen=True)
class SphereResult:
    """Centroids (n, 3, mm, SPECT frame) and what was seen."""

    centroids: np.ndarray
    peaks: np.ndarray  # smoothed peak value of each kept sphere
    sums: np.ndarray  # background-subtracted counts in each window
    n_expected: int
    n_blobs: int  # components above threshold (before keeping the hottest n_expected)
    problem: str | None = None  # None when exactly n_expected blobs were found
    order: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # reference index

    @property
    def ok(self) -> bool:
        return self.problem is None


def _centroid(data: np.ndarray, vox: np.ndarray, start: np.ndarray, s: SphereSettings):
    """Background-subtracted, windowed centre of mass (indices) around ``start`` (indices)."""
    reach = (s.window_radius + s.shell) / vox
    c = start.astype(float)
    total = 0.0
    for _ in range(max(1, s.iterations)):
        lo = np.maximum(np.floor(c - reach).astype(int), 0)
        hi = np.minimum(np.ceil(c + reach).astype(int) + 1, data.shape)
        box = data[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]].astype(float)
        grids = np.meshgrid(*[np.arange(a, b) for a, b in zip(lo, hi)], indexing="ij")
        dist = np.sqrt(sum(((g - ci) * v) ** 2 for g, ci, v in zip(grids, c, vox)))
        inside = dist <= s.window_radius
        shell = (dist > s.window_radius) & (dist <= s.window_radius + s.shell)
        bg = float(np.median(box[shell])) if shell.any() else 0.0
        w = (box - bg) * inside
        total = float(w.sum())
        if total <= 0:
            break
        c = np.array([(w * g).sum() / total for g in grids])
    return c, total


def find_spheres(
    volume: Volume, n_expected: int = 7, settings: SphereSettings | None = None, reference=None, strict: bool = False
) -> SphereResult:
    """Centroids of the ``n_expected`` hottest spheres of ``volume`` (mm, SPECT frame).

    ``reference`` (n_expected, 3) orders the result like it. With ``strict`` a count other than
    ``n_expected`` raises :class:`DataError` naming the volume's file; otherwise it is reported
    in ``result.problem`` (and fewer centroids are returned when fewer were found).
    """
    s = settings or SphereSettings()
    data = np.asarray(volume.data, dtype=np.float32)
    vox = np.asarray(volume.voxel_size)
    smooth = ndimage.gaussian_filter(data, s.smooth_sigma) if s.smooth_sigma > 0 else data
    bg = float(np.median(smooth))
    top = float(smooth.max())
    labels, n = ndimage.label(smooth > bg + s.threshold_fraction * (top - bg), structure=np.ones((3, 3, 3)))
    sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:] if n else np.zeros(0, int)
    keep_labels = [k + 1 for k in range(n) if sizes[k] >= s.min_voxels]
    peaks_at = ndimage.maximum_position(smooth, labels, keep_labels) if keep_labels else []
    peak_vals = [float(smooth[p]) for p in peaks_at]
    n_blobs = len(keep_labels)
    chosen = np.argsort(peak_vals)[::-1][:n_expected]
    cent_list, sum_list, peak_list = [], [], []
    for k in chosen:
        c, total = _centroid(data, vox, np.asarray(peaks_at[k]), s)
        cent_list.append(volume.index_to_mm(c))
        sum_list.append(total)
        peak_list.append(peak_vals[k])
    cents = np.asarray(cent_list, dtype=float).reshape(-1, 3)
    sums, peaks = np.asarray(sum_list), np.asarray(peak_list)

    problem = None
    where = volume.source or "volume"
    if n_blobs < n_expected:
        problem = f"{where}: found {n_blobs} spheres, expected {n_expected}"
    elif n_blobs > n_expected:
        problem = f"{where}: found {n_blobs} blobs, expected {n_expected} spheres (kept the {n_expected} hottest)"
    if problem and strict:
        raise DataError(problem)

    if reference is not None and len(cents):
        ref = np.asarray(reference, dtype=float).reshape(-1, 3)
        cost = np.linalg.norm(cents[:, None, :] - ref[None, :, :], axis=-1)
        rows, cols = linear_sum_assignment(cost)
        idx = rows[np.argsort(cols)]
        order = np.sort(cols)
    else:
        idx = np.lexsort((cents[:, 0], cents[:, 1], cents[:, 2])) if len(cents) else np.zeros(0, int)
        order = np.arange(len(idx))
    return SphereResult(cents[idx], peaks[idx], sums[idx], n_expected, n_blobs, problem, order)
