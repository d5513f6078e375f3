"""The simulated side of the 7-sphere step test: a table that moves, a SPECT that images.

:class:`SimTable` is the :class:`~vts_hw.procedures.steps.Positioner` of the simulated rig: it
moves the scene's table by a "1 cm" step that is really 9.5–10.5 mm (docs/design.md), and for the
``free`` position turns the phantom by a few degrees about a random axis and shifts it by a few
centimetres, as an operator's hand would. :class:`SimSpectSource` writes, for every position,
the reconstructed SPECT volume of the spheres where the scene has them at that moment
(:class:`~vts_hw.sim_devices.spect.SimSpect`: 10 mm FWHM, Poisson noise, 4.4 mm voxels).
Both keep the truth — the true sphere centres per position in the SPECT frame, which is the
scene's world frame — apart from anything the procedure reads.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from vts_hw.errors import DataError
from vts_hw.sim_devices.scene import PHANTOM_PLACEMENT, Scene
from vts_hw.sim_devices.spect import SimSpect

STEP_RANGE_MM = (9.5, 10.5)
FREE_ANGLE_DEG = (3.0, 8.0)
FREE_SHIFT_MM = (10.0, 30.0)
CLEAR_PX = 25.0  # a sphere's image is ~12 px across: keep blobs well apart
# A SPECT field of view long and tall enough for the phantom over 10 cm of steps each way.
SPECT_MATRIX = (96, 96, 64)  # (nz, ny, nx) of 4.4 mm voxels: 422 × 422 × 282 mm


def sphere_centres(scene: Scene, t: float) -> np.ndarray:
    """The phantom's sphere centres S1..S7 (7×3, mm, world = SPECT frame) at ``t``."""
    spheres = sorted((m for m in scene.markers_world(t) if m.id.startswith("S")), key=lambda m: m.id)
    return np.array([m.center for m in spheres], dtype=float)


class SimTable:
    """Moves the simulated table (and, for ``free``, the phantom on it)."""

    def __init__(
        self, scene: Scene, clock: Callable[[], float], seed: int = 0, settle: Callable[[], None] | None = None
    ):
        self.scene = scene
        self.clock = clock
        self.rng = np.random.default_rng(seed)
        self.settle = settle or (lambda: None)
        self.y = self.z = 0.0
        self.truth: dict[str, np.ndarray] = {}
        self.free_move: dict | None = None

    def move_to(self, pos) -> None:
        now = self.clock()
        if pos.kind == "vertical":
            self.y += self.rng.uniform(*STEP_RANGE_MM)
        elif pos.kind == "axial":
            self.z += self.rng.uniform(*STEP_RANGE_MM)
        elif pos.kind == "free":
            self._free_move(now)
        if pos.kind in ("vertical", "axial"):
            self.scene.move_table(self.y, self.z, now)
        self.settle()
        self.truth[pos.label] = sphere_centres(self.scene, self.clock())

    def _free_move(self, now: float) -> None:
        """A hand's turn and shift, drawn again until every sphere stays in view and clear of
        every other marker in both cameras (the operator watches the live view)."""
        for _ in range(200):
            axis = self.rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            rvec = axis * np.deg2rad(self.rng.uniform(*FREE_ANGLE_DEG))
            direction = self.rng.normal(size=3) * (1.0, 0.3, 1.0)  # mostly across the table
            shift = direction / np.linalg.norm(direction) * self.rng.uniform(*FREE_SHIFT_MM)
            self.scene.set_phantom_pose(rvec, tuple(np.add(PHANTOM_PLACEMENT, shift)), now)
            if all_spheres_clear(self.scene, now):
                self.free_move = {"rvec": rvec.tolist(), "shift_mm": shift.tolist()}
                return
        raise RuntimeError("no free move keeps every sphere in view")  # pragma: no cover


def all_spheres_clear(scene: Scene, t: float, min_px: float = CLEAR_PX) -> bool:
    """Every sphere visible in every camera, at least ``min_px`` from any other marker's image."""
    for cam in scene.cameras:
        _, markers, uv, visible = scene.project_markers(cam, t)
        spheres = [i for i, m in enumerate(markers) if m.id.startswith("S")]
        if not all(visible[i] for i in spheres):
            return False
        d = np.linalg.norm(uv[:, None, :] - uv[None, :, :], axis=-1)
        np.fill_diagonal(d, np.inf)
        if d[spheres].min() < min_px:
            return False
    return True


class SimSpectSource:
    """Writes a SimSpect volume of the spheres where they are when the VTS has seen them."""

    def __init__(self, scene: Scene, clock: Callable[[], float], folder, seed: int = 0, fmt: str = ".npz"):
        self.scene = scene
        self.clock = clock
        self.folder = Path(folder)
        self.seed = seed
        self.fmt = fmt
        self.paths: dict[str, Path] = {}
        self.truth: dict[str, np.ndarray] = {}

    def acquired(self, pos) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        centres = sphere_centres(self.scene, self.clock())
        self.truth[pos.label] = centres
        spect = SimSpect(matrix=SPECT_MATRIX, seed=self.seed * 1009 + len(self.paths))
        self.paths[pos.label] = spect.write(self.folder / f"{pos.label}{self.fmt}", centres)

    def volume(self, pos) -> Path:
        try:
            return self.paths[pos.label]
        except KeyError:
            raise DataError(f"the simulated SPECT did not image position {pos.label}.") from None
