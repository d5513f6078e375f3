"""A simulated SPECT: reconstructed volumes of hot spheres, with known truth.

Each sphere is a uniform ball of the given diameter blurred by an isotropic Gaussian PSF (the
system resolution, ``fwhm``), evaluated in closed form and averaged over each voxel
(``supersample``³ points), scaled to ``counts_per_sphere`` (the drops differ:
``activity_spread``), on a flat ``background``, then Poisson-sampled (seeded). The truth —
sphere centres in the SPECT frame, mm — is what the caller passed; it is never written into the
file.

Closed form of a ball of radius R convolved with a Gaussian of s.d. σ, at distance r::

    ½[erf((R+r)/(σ√2)) + erf((R−r)/(σ√2))] − σ/(r√(2π)) [e^{−(r−R)²/2σ²} − e^{−(r+R)²/2σ²}]
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.special import erf

from vts_hw.sim_devices.scene import PHANTOM_LAYOUT, PHANTOM_PLACEMENT, SPHERE_DIAMETER, rotation_matrix
from vts_hw.spect.dicom_nm import write_dicom_nm
from vts_hw.spect.interfile import write_interfile
from vts_hw.spect.npz import write_npz
from vts_hw.spect.volume import Volume, triple

FWHM_TO_SIGMA = 1.0 / (2.0 * np.sqrt(2.0 * np.log(2.0)))


def phantom_centres(translation=(0.0, 0.0, 0.0), rvec=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The 7-sphere phantom's centres (7, 3) in the SPECT frame, S1..S7, as in the sim scene.

    ``rvec`` (Rodrigues, radians) rotates the phantom about its base centre, then
    ``translation`` (mm) moves it.
    """
    layout = np.array([PHANTOM_LAYOUT[f"S{k}"] for k in range(1, 8)], dtype=float)
    r = rotation_matrix(np.asarray(rvec, dtype=float))
    return layout @ r.T + np.asarray(PHANTOM_PLACEMENT) + np.asarray(translation, dtype=float)


def blurred_ball(r: np.ndarray, radius: float, sigma: float) -> np.ndarray:
    """Value of a unit-density ball (``radius``) convolved with a Gaussian (``sigma``) at ``r``."""
    r = np.maximum(np.asarray(r, dtype=float), 1e-6 * sigma)
    s2 = sigma * np.sqrt(2.0)
    term = 0.5 * (erf((radius + r) / s2) + erf((radius - r) / s2))
    gauss = np.exp(-((r - radius) ** 2) / (2 * sigma**2)) - np.exp(-((r + radius) ** 2) / (2 * sigma**2))
    return term - sigma / (r * np.sqrt(2 * np.pi)) * gauss


@dataclass
class SimSpect:
    """Settings of the simulated acquisition + reconstruction (defaults: a clinical system)."""

    matrix: tuple[int, int, int] = (64, 64, 64)  # (nz, ny, nx), canonical layout
    voxel_size: float = 4.4  # mm, isotropic
    fwhm: float = 10.0  # mm, system resolution in the reconstruction
    counts_per_sphere: float = 5.0e4  # mean total counts in one sphere's blob
    activity_spread: float = 0.3  # drops differ: counts × U(1 − spread, 1 + spread)
    background: float = 2.0  # counts per voxel
    supersample: int = 3  # points per voxel edge for the voxel average
    seed: int = 0

    def _grid(self) -> Volume:
        n = np.asarray(self.matrix)
        origin_zyx = -(n - 1) / 2.0 * self.voxel_size  # FOV centred on the SPECT origin
        return Volume(np.zeros(self.matrix, np.float32), triple((self.voxel_size,) * 3), triple(origin_zyx[::-1]))

    def expected(self, centres, diameter: float = SPHERE_DIAMETER, rng=None) -> Volume:
        """The noise-free volume (mean counts per voxel)."""
        grid = self._grid()
        sigma = self.fwhm * FWHM_TO_SIGMA
        radius = diameter / 2.0
        rng = rng if rng is not None else np.random.default_rng(self.seed)
        ss = self.supersample
        sub = (np.arange(ss) + 0.5) / ss - 0.5  # sub-voxel offsets, in voxels
        out = np.full(self.matrix, float(self.background))
        ball_volume = 4.0 / 3.0 * np.pi * radius**3
        reach = radius + 5.0 * sigma
        for c in np.atleast_2d(np.asarray(centres, dtype=float)):
            scale = self.counts_per_sphere * rng.uniform(1 - self.activity_spread, 1 + self.activity_spread)
            density = scale / ball_volume * self.voxel_size**3  # counts per voxel at unit value
            ci = grid.mm_to_index(c)
            lo = np.maximum(np.floor(ci - reach / self.voxel_size).astype(int), 0)
            hi = np.minimum(np.ceil(ci + reach / self.voxel_size).astype(int) + 1, self.matrix)
            if np.any(hi <= lo):
                continue
            idx = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in zip(lo, hi)], indexing="ij"), -1).astype(float)
            acc = np.zeros(idx.shape[:3])
            for dz in sub:
                for dy in sub:
                    for dx in sub:
                        p = grid.index_to_mm(idx + (dz, dy, dx))
                        acc += blurred_ball(np.linalg.norm(p - c, axis=-1), radius, sigma)
            out[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] += density * acc / ss**3
        return Volume(out.astype(np.float32), grid.voxel_size, grid.origin)

    def volume(self, centres, diameter: float = SPHERE_DIAMETER) -> Volume:
        """A noisy reconstructed volume (Poisson counts, seeded) of spheres at ``centres`` (mm)."""
        rng = np.random.default_rng(self.seed)
        mean = self.expected(centres, diameter, rng)
        counts = rng.poisson(mean.data).astype(np.float32)
        return Volume(counts, mean.voxel_size, mean.origin)

    def write(self, path, centres, diameter: float = SPHERE_DIAMETER) -> Path:
        """Write the noisy volume to ``path``; the format follows the extension
        (``.h33``/``.hdr`` Interfile, ``.dcm`` DICOM NM, ``.npz``). Returns the path (the
        Interfile header)."""
        return write_volume(self.volume(centres, diameter), path)


def write_volume(volume: Volume, path) -> Path:
    """Write ``volume`` in the format its extension names."""
    path = Path(path)
    ext = path.suffix.lower()
    if ext in (".h33", ".hdr"):
        return write_interfile(volume, path, "unsigned integer")
    if ext in (".dcm", ".dicom"):
        return write_dicom_nm(volume, path)
    if ext == ".npz":
        return write_npz(volume, path)
    raise ValueError(f"unknown volume extension {ext!r} (.h33, .hdr, .dcm, .npz)")
