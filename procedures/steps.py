"""The 7-sphere step test, as a script: VTS against SPECT over known table moves.

Positions (:func:`step_plan`): the baseline, ``n_vertical`` steps of about 1 cm up, ``n_axial``
steps of about 1 cm along the table, then an arbitrary rotation and translation of the phantom
by hand. A :class:`Positioner` gets the phantom there: on the real rig
:class:`OperatorPositioner` tells the operator what to do and waits for Enter; on the simulated
rig :class:`vts_hw.sim_devices.step_table.SimTable` moves the simulated table.

At each position (:meth:`StepSession.acquire`):

1. ``frames`` snapshots per camera with the LED on; the markers are detected and their
   centroids averaged over the frames;
2. the :class:`SpectSource` is told the position is ready (the simulated SPECT writes its
   reconstructed volume now; a real one is acquired and reconstructed by the SPECT system).

Everything seen is saved to ``<out>/positions.json`` as soon as it is seen, so a failure later
loses nothing, and ``vts qa steps --analyze OUT`` can finish the job when the volumes arrive.

Then (:meth:`StepSession.analyze`), per position: the SPECT centroids from the volume (ordered
like the baseline's spheres), the same spheres found among the VTS's hypotheses by their
shape (:func:`vts_hw.vision.body_finder.locate_body_views`: with two cameras every
epipolar-allowed pairing, shape settling what the epipolar constraint alone leaves ambiguous;
with more, the points matched across every view), triangulated with the calibration and
mapped into the SPECT frame with the VTS → SPECT transform. :class:`StepAnalysis` does the
rest.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from vts_hw.bounded import SMALL, read_bytes
from vts_hw.camera_led import light
from vts_hw.catalog import STEPS
from vts_hw.errors import DataError
from vts_hw.files import ensure_dir, write_atomic, write_json_atomic
from vts_hw.procedures.spect_mapping import correspond
from vts_hw.procedures.steps_analysis import StepAnalysis
from vts_hw.spect import find_spheres, read_volume
from vts_hw.vision.body_finder import locate_body_views
from vts_hw.vision.camera_set import named_cameras
from vts_hw.vision.detect import detect_jpeg

N_SPHERES = 7
LED_SETTLE_S = 0.2
# VAPIX compression of the QA snapshots (JPEG quality about 90): asked per request, so the
# cameras' configured stream (compression 25, quality about 75) is untouched. At the stream's
# compression the JPEG's block artefacts bias each centroid by a few hundredths of a pixel, the
# same in every frame, so averaging frames cannot remove them (docs/decisions/0015).
SNAPSHOT_COMPRESSION = 10
POSITIONS_FILE = "positions.json"


@dataclass(frozen=True)
class StepPosition:
    """One position of the plan. ``table_y_mm``/``table_z_mm``: nominal table offset from
    the baseline (the real step is what the SPECT measures, not this)."""

    label: str
    kind: str  # baseline | vertical | axial | free
    table_y_mm: float
    table_z_mm: float
    instruction: str


def step_plan(n_vertical: int = 10, n_axial: int = 10, step_mm: float = 10.0) -> list[StepPosition]:
    """The positions in order: baseline, Vnn (up), Ann (along the table), then ``free``."""
    out = [
        StepPosition(
            "baseline",
            "baseline",
            0.0,
            0.0,
            "Place the 7-sphere phantom at the centre of the field of view, LED ring on.",
        )
    ]
    y = z = 0.0
    for i in range(1, n_vertical + 1):
        y += step_mm
        out.append(
            StepPosition(
                f"V{i:02d}", "vertical", y, z, f"Raise the table {step_mm:g} mm (vertical step {i} of {n_vertical})."
            )
        )
    for i in range(1, n_axial + 1):
        z += step_mm
        out.append(
            StepPosition(
                f"A{i:02d}",
                "axial",
                y,
                z,
                f"Move the table {step_mm:g} mm into the gantry (axial step {i} of {n_axial}).",
            )
        )
    out.append(
        StepPosition(
            "free",
            "free",
            y,
            z,
            "Turn the phantom by hand (a few degrees about any axis) and shift it by a "
            "few centimetres; keep every sphere in view.",
        )
    )
    return out


@runtime_checkable
class Positioner(Protocol):
    """Gets the phantom to a position of the plan (returns when it is there and still)."""

    def move_to(self, pos: StepPosition) -> None: ...


@runtime_checkable
class SpectSource(Protocol):
    """Where the SPECT's reconstructed volume of each position comes from."""

    def acquired(self, pos: StepPosition) -> None: ...  # the VTS has seen this position
    def volume(self, pos: StepPosition) -> Path: ...  # its volume (DataError if none)


class OperatorPositioner:
    """The real rig: tell the operator and wait for Enter (``ask`` shows a prompt and waits)."""

    def __init__(self, ask: Callable[[str], object]):
        self.ask = ask

    def move_to(self, pos: StepPosition) -> None:
        self.ask(f"[{pos.label}] {pos.instruction} Press Enter when the table has stopped.")


class VolumeFolder:
    """Volumes exported by the SPECT system into one folder, one per position, named after
    the position: ``baseline.*``, ``V01.*``, ... (any format ``read_volume`` reads; an
    Interfile's ``.h33`` header is the file to name)."""

    SKIP = (".img", ".raw", ".v")  # Interfile data files: the header is the volume

    def __init__(self, folder):
        self.folder = Path(folder)

    def acquired(self, pos: StepPosition) -> None:
        pass

    def volume(self, pos: StepPosition) -> Path:
        if not self.folder.is_dir():
            raise DataError(f"{self.folder}: no such folder of SPECT volumes.")
        hits = sorted(
            p
            for p in self.folder.iterdir()
            if p.stem.lower() == pos.label.lower() and p.suffix.lower() not in self.SKIP
        )
        if not hits:
            raise DataError(
                f"{self.folder}: no SPECT volume for position {pos.label} (expected {pos.label}.dcm, .h33 or .npz)."
            )
        return hits[0]


def average_centroids(detections) -> np.ndarray:
    """Blob centres (N×2 px) averaged over several frames: each blob of the first frame with
    the nearest blob (within 1 px) of every other frame; blobs not seen in every frame are
    dropped."""
    first = np.array([(b.x, b.y) for b in detections[0].blobs], dtype=float).reshape(-1, 2)
    sums, counts = first.copy(), np.ones(len(first))
    for det in detections[1:]:
        pts = np.array([(b.x, b.y) for b in det.blobs], dtype=float).reshape(-1, 2)
        if len(pts) == 0 or len(first) == 0:
            continue
        d = np.linalg.norm(first[:, None, :] - pts[None, :, :], axis=-1)
        near = np.argmin(d, axis=1)
        ok = d[np.arange(len(first)), near] < 1.0
        sums[ok] += pts[near[ok]]
        counts[ok] += 1
    keep = counts == len(detections)
    return sums[keep] / counts[keep, None]


@dataclass
class SeenPosition:
    """What the VTS saw at one position: averaged centroids per camera (px), and when."""

    label: str
    kind: str
    host_time: float
    points_px: dict[str, list[list[float]]]
    volume: str | None = None


class StepSession:
    """Acquire the step test on two or more cameras and analyse it.

    ``cameras``: cameras (their LED rings switched on where they have one) (two: left = the
    calibration's camera 1, right = camera 2); ``calibration``: the cameras in mm, any form
    :func:`vts_hw.vision.camera_set.named_cameras` reads (a calibration of two or more cameras,
    a dict of named cameras); ``mapping``: the VTS → SPECT RigidTransform.
    """

    def __init__(
        self,
        cameras: Sequence,
        calibration,
        mapping,
        positioner: Positioner,
        spect: SpectSource,
        out_dir,
        plan: list[StepPosition] | None = None,
        frames: int = 10,
        tol_mm: float = 3.0,
        progress: Callable[[str], None] | None = None,
        clock: Callable[[], float] = time.time,
        compression: int | None = SNAPSHOT_COMPRESSION,
    ):
        if len(cameras) < 2:
            raise DataError(f"the step test needs two cameras or more, got {len(cameras)}.")
        if getattr(calibration, "unit", "mm") != "mm":
            raise DataError(
                "the stereo calibration is in squares: calibrate with the square size "
                "in mm (--square) so that the VTS measures millimetres."
            )
        self.cameras = list(cameras)
        self.calibration = calibration
        self.mapping = mapping
        self.positioner = positioner
        self.spect = spect
        self.out = Path(out_dir)
        self.plan_ = plan or step_plan()
        self.frames = frames
        self.tol_mm = tol_mm
        self.progress = progress or (lambda m: None)
        self.clock = clock
        self.compression = compression
        self.seen: list[SeenPosition] = []

    def plan(self) -> list[str]:
        names = [getattr(c, "name", f"camera {i + 1}") for i, c in enumerate(self.cameras)]
        out = [f"LED on: {', '.join(names)}"]
        for p in self.plan_:
            out.append(
                f"{p.label}: {p.instruction} Then {self.frames} snapshots per camera (compression "
                f"{self.compression}); the SPECT acquires and reconstructs this position"
            )
        out.append(f"save what the VTS saw to {self.out / POSITIONS_FILE} after each position")
        out.append(
            "per position: SPECT sphere centroids, the same spheres in the VTS (stereo), mapped "
            "to the SPECT frame; regression, differences, 6-DOF move; store the run"
        )
        return out

    # ------------------------------------------------------------------ acquisition
    def acquire(self) -> list[SeenPosition]:
        ensure_dir(self.out, "step test folder")
        for cam in self.cameras:
            light(cam)  # a camera without an LED (a replay) shows its frames as they are
        time.sleep(LED_SETTLE_S)
        for i, pos in enumerate(self.plan_, 1):
            self.positioner.move_to(pos)
            self.progress(f"[{i}/{len(self.plan_)}] {pos.label}: {self.frames} snapshots per camera")
            pts = {}
            for k, cam in enumerate(self.cameras):
                name = getattr(cam, "name", f"cam{k + 1}")
                snaps = [cam.snapshot(self.compression) for _ in range(self.frames)]
                write_atomic(self.out / f"{pos.label}-{name}.jpg", snaps[0].jpeg, kept=self._kept())
                pts[name] = average_centroids([detect_jpeg(s.jpeg) for s in snaps]).tolist()
            self.spect.acquired(pos)
            self.seen.append(SeenPosition(pos.label, pos.kind, self.clock(), pts))
            self._save()
        return self.seen

    def _save(self) -> None:
        data = {
            "format": "vts-hw steps positions",
            "format_version": 1,
            "cameras": [getattr(c, "name", f"cam{i + 1}") for i, c in enumerate(self.cameras)],
            "plan": [asdict(p) for p in self.plan_],
            "positions": [asdict(s) for s in self.seen],
        }
        write_json_atomic(self.out / POSITIONS_FILE, data, indent=1, kept=self._kept(len(self.seen) - 1))

    def _kept(self, n: int | None = None) -> str:
        """What a full disk leaves of the session: positions.json as it was (``n`` positions)."""
        n = len(self.seen) if n is None else n
        return (
            f"{self.out / POSITIONS_FILE} keeps the {n} position(s) acquired before it"
            if n > 0
            else "no position was saved yet"
        )

    # ------------------------------------------------------------------ analysis
    def analyze(self, tolerances=None) -> StepAnalysis:
        return analyze_positions(
            self.seen, self.plan_, self.calibration, self.mapping, self.spect, tolerances, self.tol_mm, self.progress
        )


def load_positions(folder) -> tuple[list[SeenPosition], list[StepPosition]]:
    """What a step session saved (``positions.json``), to analyse again or finish."""
    path = Path(folder) / POSITIONS_FILE
    if not path.is_file():
        raise DataError(f"{path}: no such file; give the folder of a step session.")
    try:
        data = json.loads(read_bytes(path, SMALL, "step session").decode("utf-8"))
        plan = [StepPosition(**p) for p in data["plan"]]
        seen = [SeenPosition(**s) for s in data["positions"]]
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({exc.strerror or exc}).") from None
    except (ValueError, KeyError, TypeError, RecursionError) as exc:  # JSON, UTF-8, shape
        raise DataError(f"{path}: not a step-session file ({str(exc)[:120] or type(exc).__name__}).") from None
    return seen, plan


def analyze_positions(
    seen: list[SeenPosition],
    plan: list[StepPosition],
    calibration,
    mapping,
    spect: SpectSource,
    tolerances=None,
    tol_mm: float = 3.0,
    progress: Callable[[str], None] | None = None,
) -> StepAnalysis:
    """SPECT centroids and VTS spheres per position, then :class:`StepAnalysis`."""
    say = progress or (lambda m: None)
    if len(seen) < 2:
        raise DataError(
            f"only {len(seen)} position(s) acquired; the step test needs the baseline and at least one more."
        )
    by_label = {p.label: p for p in plan}
    vts_all, spect_all, labels, kinds = [], [], [], []
    reference = None
    for s in seen:
        pos = by_label.get(s.label) or StepPosition(s.label, s.kind, 0.0, 0.0, "")
        vol_path = spect.volume(pos)
        s.volume = str(vol_path)
        cents = find_spheres(read_volume(vol_path), n_expected=N_SPHERES, strict=True).centroids
        if reference is None:
            reference = cents
        else:
            cents = cents[correspond(reference, cents)]
        names = list(s.points_px)
        cams = named_cameras(calibration, names)  # a stereo pair takes the names seen
        missing = [n for n in names if n not in cams]
        if missing:
            raise DataError(
                f"position {s.label}: camera(s) {', '.join(missing)} not in the calibration (it has {', '.join(cams)})."
            )
        try:
            fit = locate_body_views(
                [cams[n] for n in names], [np.array(s.points_px[n]).reshape(-1, 2) for n in names], cents, tol_mm=tol_mm
            )
        except DataError as exc:
            raise DataError(f"position {s.label}: {exc}") from None
        vts_all.append(mapping.apply(fit.points))
        spect_all.append(cents)
        labels.append(s.label)
        kinds.append(s.kind)
        say(f"{s.label}: spheres found (shape RMS {fit.rms_mm:.2f} mm)")
    kept = ("fre_mm", "tre_rms_mm", "tre_max_mm")
    meta = {
        "calibration_created": getattr(calibration, "created", ""),
        "mapping": {k: v for k, v in (getattr(mapping, "meta", None) or {}).items() if k in kept},
        "volumes": [s.volume for s in seen],
    }
    return StepAnalysis(labels, np.array(vts_all), np.array(spect_all), kinds, meta).analyze(tolerances)


PROCEDURE = STEPS.name
