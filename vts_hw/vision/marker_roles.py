"""What each marker in view is -- a wall marker, a phantom sphere, a patient marker (chest,
abdomen), or unknown -- each with the reason: the one identity the drift baseline, the daily QA,
aim, the console and the patient paths take (issue 33 §3, docs/decisions/0086-marker-roles.md).

The rules, in the order they are applied:

1. **Moved**: a marker whose centre ranges more than :data:`MOVE_FLOOR_PX` (pixels, one camera
   over its frames) or :data:`MOVE_FLOOR_MM` (mm, 3D over time) is never a wall marker: it is a
   patient marker (breathing or a body move).
2. **Where it lies**: a still marker seen by two calibrated cameras or more is placed in 3D and
   mapped to the SPECT frame (the VTS -> SPECT mapping); inside the table-and-gantry volume
   (:class:`TableSpace`) it is never a wall marker: a phantom sphere where the phantom's shape
   (kept in the mapping) fits, else unknown ("on the table"). Outside it, a wall marker.
3. Where no mapping or calibration exists, or a marker is seen by one camera only, the reason
   says so and rule 1 alone decides (a still marker is then taken for a wall marker).

Two entry points, one set of rules:

* pixels per camera over a few frames: :func:`follow` (tracks from each frame's detections),
  :func:`roles_of_tracks` (rule 1), :meth:`RoomGeometry.place` (rule 2, across cameras);
* 3D positions over time, for the live path and the offline motion analysis:
  :func:`roles_of_positions` (T x M x 3, the SPECT frame, or the VTS frame with the mapping):
  rules 1 and 2, and the patient's markers split into chest and abdomen along the table.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import linear_sum_assignment

from vts_hw.vision.aim_geometry import fov_centre
from vts_hw.vision.aim_settings import DEFAULT_AIM, AimSettings
from vts_hw.vision.camera_set import named_cameras
from vts_hw.vision.multiview import ViewGeometry, match_views

__all__ = [
    "WALL",
    "PHANTOM",
    "CHEST",
    "ABDOMEN",
    "PATIENT",
    "UNKNOWN",
    "ROLES",
    "PATIENT_ROLES",
    "Role",
    "Track",
    "TableSpace",
    "RoomGeometry",
    "follow",
    "motion_range",
    "roles_of_tracks",
    "roles_of_positions",
    "roles_by_reference",
    "match_markers",
    "GATE_PX",
    "MOVE_FLOOR_PX",
    "MOVE_FLOOR_MM",
    "BAND_GAP_MM",
    "BODY_HEIGHT_MM",
]

WALL, PHANTOM, CHEST, ABDOMEN, PATIENT, UNKNOWN = "wall", "phantom", "chest", "abdomen", "patient", "unknown"
ROLES = (WALL, PHANTOM, CHEST, ABDOMEN, PATIENT, UNKNOWN)
PATIENT_ROLES = (PATIENT, CHEST, ABDOMEN)  # the roles of a patient's marker

GATE_PX = 12.0  # a marker further than this from where it was is not that marker
MOVE_FLOOR_PX = 0.3  # a still marker's centre ranges ~0.1 px over a few frames (sensor noise, JPEG)
MOVE_FLOOR_MM = 1.0  # a still marker's triangulated centre ranges well under 1 mm
BODY_HEIGHT_MM = 350.0  # the table's space reaches this high above the table top (a patient, the phantom)
BAND_GAP_MM = 60.0  # the patient's markers are two bands when their axial positions part by this much
PLACE_MAX_PX = 3.0  # looser than tracking's 2 px: a still marker is placed to tens of mm, a camera drifts


@dataclass(frozen=True)
class Role:
    """What one marker is (one of :data:`ROLES`), why, and its name where it has one (``M3``:
    the baseline's wall marker; ``S2``: the phantom's sphere)."""

    role: str
    reason: str
    name: str = ""

    @property
    def is_wall(self) -> bool:
        return self.role == WALL

    def to_dict(self) -> dict:
        return {"role": self.role, "name": self.name, "reason": self.reason}


@dataclass
class Track:
    """One marker of one camera followed over ``frames`` frames: its mean centre (px), in how
    many frames it was seen, and how far its centre ranged (the diagonal of its extent, px)."""

    x: float
    y: float
    seen: int
    frames: int
    range_px: float
    points: list = field(default_factory=list, repr=False)


def match_markers(ref: np.ndarray, pts: np.ndarray, gate: float) -> list[tuple[int, int]]:
    """One-to-one nearest matching (Hungarian on distance), pairs further than ``gate`` dropped."""
    if len(ref) == 0 or len(pts) == 0:
        return []
    d = np.linalg.norm(ref[:, None, :] - pts[None, :, :], axis=2)
    rows, cols = linear_sum_assignment(np.minimum(d, 10 * gate))
    return [(int(i), int(j)) for i, j in zip(rows, cols) if d[i, j] <= gate]


def follow(per_frame: Sequence, gate: float = GATE_PX) -> list[Track]:
    """Each marker of one camera followed over its frames (``per_frame``: each frame's centres,
    N x 2 px): a detection joins the track whose latest centre is nearest within ``gate``, one
    to one; one that joins none starts a track."""
    tracks: list[Track] = []
    n = len(per_frame)
    for pts in per_frame:
        pts = np.asarray(pts, float).reshape(-1, 2)
        last = np.array([t.points[-1] for t in tracks]).reshape(-1, 2)
        taken = set()
        for i, j in match_markers(last, pts, gate):
            tracks[i].points.append(tuple(pts[j]))
            taken.add(j)
        tracks += [Track(0, 0, 0, n, 0, [tuple(pts[j])]) for j in range(len(pts)) if j not in taken]
    for t in tracks:
        p = np.array(t.points)
        t.x, t.y = (float(v) for v in p.mean(axis=0))
        t.seen = len(p)
        t.range_px = float(np.hypot(*np.ptp(p, axis=0)))
    return tracks


def roles_by_reference(reference, pts, shift=(0.0, 0.0), gate: float = GATE_PX) -> list[Role]:
    """One picture's markers (``pts``, N x 2 px) against where the drift baseline's wall markers
    were (``reference``, moved by ``shift``, px: a camera turned since): a wall marker where one
    was, within ``gate``; unknown otherwise (one picture shows no motion: never taken for a wall
    marker)."""
    ref = np.asarray(reference, float).reshape(-1, 2) + np.asarray(shift, float)
    p = np.asarray(pts, float).reshape(-1, 2)
    out = [Role(UNKNOWN, "not where a drift baseline's wall marker is") for _ in range(len(p))]
    for i, j in match_markers(ref, p, gate):
        out[j] = Role(WALL, "where the drift baseline's wall marker was", f"M{i + 1}")
    return out


def roles_of_tracks(tracks: Sequence[Track], floor_px: float = MOVE_FLOOR_PX) -> list[Role | None]:
    """Rule 1 on one camera's tracks: a :class:`Role` for each that moved or was not seen in
    every frame; None for a still one (rule 2, :meth:`RoomGeometry.place`, says where it lies)."""
    out: list[Role | None] = []
    for t in tracks:
        if t.seen >= 2 and t.range_px > floor_px:
            out.append(
                Role(
                    PATIENT,
                    f"moved {t.range_px:.1f} px over {t.seen} frames (a still marker: under "
                    f"{floor_px:g} px): breathing or a body; its band not known from one camera",
                )
            )
        elif t.seen < t.frames:
            out.append(Role(UNKNOWN, f"seen in {t.seen} of {t.frames} frames: not steady enough to be a wall marker"))
        else:
            out.append(None)
    return out


@dataclass(frozen=True)
class TableSpace:
    """The table-and-gantry volume in the SPECT frame (mm), where a patient or the phantom lies:
    the gantry's opening (a cylinder about the axis through the FOV centre, ``bore_radius`` and
    ``bore_half_depth`` either side of the centre) and the space over the table top
    (``table_half_width`` either side of the axis, from the top to ``body_height`` above it, over
    the table's extent along Z). From the room geometry of rig.yaml's ``aim:`` and the mapping's
    FOV centre (:meth:`from_settings`)."""

    centre: tuple[float, float, float]
    bore_radius: float
    bore_half_depth: float
    table_half_width: float
    table_top_y: float
    body_height: float
    table_z: tuple[float, float]

    @classmethod
    def from_settings(
        cls, settings: AimSettings = DEFAULT_AIM, mapping=None, body_height: float = BODY_HEIGHT_MM
    ) -> TableSpace:
        x, y, z = (float(v) for v in (fov_centre(mapping) if mapping is not None else np.zeros(3)))
        z0, z1 = settings.table_z_mm
        return cls(
            (x, y, z),
            settings.bore_diameter_mm / 2,
            settings.bore_depth_mm / 2,
            settings.table_width_mm / 2,
            settings.table_top_y_mm,
            float(body_height),
            (float(z0), float(z1)),
        )

    def inside(self, pts_spect) -> np.ndarray:
        """Whether each SPECT-frame point (N x 3, mm) lies in the volume."""
        p = np.asarray(pts_spect, float).reshape(-1, 3)
        cx, cy, cz = self.centre
        bore = (np.hypot(p[:, 0] - cx, p[:, 1] - cy) <= self.bore_radius) & (
            np.abs(p[:, 2] - cz) <= self.bore_half_depth
        )
        table = (
            (np.abs(p[:, 0] - cx) <= self.table_half_width)
            & (p[:, 1] >= self.table_top_y - 20.0)
            & (p[:, 1] <= self.table_top_y + self.body_height)
            & (p[:, 2] >= self.table_z[0])
            & (p[:, 2] <= self.table_z[1])
        )
        return bore | table


class RoomGeometry:
    """Rule 2: the calibrated ``cameras`` (``{name: camera}``, the VTS frame, mm), the VTS ->
    SPECT ``mapping`` (a RigidTransform), the :class:`TableSpace`, and optionally the phantom's
    ``locator`` (a :class:`~vts_hw.vision.phantom_locator.PhantomLocator`) to name its spheres."""

    def __init__(self, cameras: Mapping, mapping, space: TableSpace, locator=None):

        self.cameras = named_cameras(dict(cameras))
        self.mapping = mapping
        self.space = space
        self.locator = locator

    def place(self, still: Mapping[str, ArrayLike]) -> dict[str, list[Role | None]]:
        """Each camera's still markers (``{camera: N x 2 px}``, each seen in every frame) placed:
        a :class:`Role` for each that another camera confirms (wall, phantom, or unknown on the
        table), None for one seen by one camera only or not calibrated (rule 3: the caller keeps
        its motion-only role and says why)."""

        out: dict[str, list[Role | None]] = {n: [None] * len(np.asarray(p).reshape(-1, 2)) for n, p in still.items()}
        names = [n for n, p in still.items() if n in self.cameras and len(np.asarray(p).reshape(-1, 2))]
        if len(names) < 2:
            return out
        views = [np.asarray(still[n], float).reshape(-1, 2) for n in names]
        geo = ViewGeometry([self.cameras[n] for n in names], names)
        found = match_views(geo, views, max_px=PLACE_MAX_PX, max_rms_px=PLACE_MAX_PX)
        spheres = self._spheres(names, views)
        for p in found.points:
            xyz = self.mapping.apply(np.asarray(p.xyz, float).reshape(3))
            at = f"({xyz[0]:.0f}, {xyz[1]:.0f}, {xyz[2]:.0f}) mm in the SPECT frame"
            inside = bool(self.space.inside(xyz)[0])
            for c, d in enumerate(p.detections):
                if d < 0:
                    continue
                name = names[c]
                if not inside:
                    role = Role(WALL, f"still, and at {at}, outside the table-and-gantry volume")
                elif (name, d) in spheres:
                    role = Role(
                        PHANTOM,
                        f"still, at {at} inside the table-and-gantry volume, and the phantom's shape fits there",
                        spheres[(name, d)],
                    )
                else:
                    role = Role(
                        UNKNOWN,
                        f"still, but at {at}, inside the table-and-gantry volume: on the "
                        f"table (the phantom, a patient holding still), never a wall marker",
                    )
                out[name][d] = role
        return out

    def _spheres(self, names, views) -> dict[tuple[str, int], str]:
        """``{(camera, detection): "S3"}`` where the phantom's shape fits the still markers."""
        if self.locator is None:
            return {}
        try:
            seen = self.locator.locate(dict(zip(names, views)))
        except Exception:  # a phantom not found names nothing; it never stops the roles
            return {}
        out = {}
        for n, pts in seen.names.items():
            v = views[names.index(n)]
            for sphere, x, y in pts:
                d = int(np.argmin(np.hypot(v[:, 0] - x, v[:, 1] - y)))
                out[(n, d)] = sphere
        return out


def motion_range(p) -> float:
    """How far a marker's 3D centre ranged (mm): with 10 samples or more the 5th to 95th
    percentile of its positions along their main direction (a still marker's triangulation noise
    and the odd wrong match do not make it move; breathing does), else the extent of the box."""
    p = np.asarray(p, float).reshape(-1, 3)
    if len(p) < 10:
        return float(np.linalg.norm(np.ptp(p, axis=0))) if len(p) else 0.0
    c = p - p.mean(axis=0)
    proj = c @ np.linalg.svd(c, full_matrices=False)[2][0]
    return float(np.percentile(proj, 95) - np.percentile(proj, 5))


def roles_of_positions(
    xyz,
    *,
    frame: str = "spect",
    mapping=None,
    space: TableSpace | None = None,
    floor_mm: float = MOVE_FLOOR_MM,
    head_end_low_z: bool = True,
) -> list[Role]:
    """Rules 1 and 2 on 3D tracks, for the live path and the offline analysis: ``xyz`` is
    T x M x 3 (mm; NaN where marker ``m`` was not seen at sample ``t``), in the SPECT frame
    (``frame="spect"``) or the VTS frame (``frame="vts"``: ``mapping`` VTS -> SPECT needed for
    rule 2; without it the reason says so and motion alone decides). ``space``: the
    table-and-gantry volume (default: rig.yaml's default room). A marker that moved more than
    ``floor_mm`` (:func:`motion_range`) is the patient's; the patient's markers split into two bands along Z where a
    gap of :data:`BAND_GAP_MM` parts them, the chest at the head end (smaller Z: head first,
    ``head_end_low_z``). Returns one Role per marker."""
    X = np.asarray(xyz, float)
    if X.ndim != 3 or X.shape[2] != 3:
        raise ValueError("positions must be T x M x 3 (samples, markers, mm)")
    if frame not in ("spect", "vts"):
        raise ValueError(f"frame must be 'spect' or 'vts', not {frame!r}")
    why_not = ""
    if frame == "vts":
        if mapping is None:
            why_not = "no VTS -> SPECT mapping (calibration.mapping): where it lies is not known, motion alone decides"
        else:
            X = mapping.apply(X.reshape(-1, 3)).reshape(X.shape)
    space = space or TableSpace.from_settings(DEFAULT_AIM, mapping)
    out: list[Role] = []
    moved = []
    for m in range(X.shape[1]):
        p = X[:, m][np.all(np.isfinite(X[:, m]), axis=1)]
        if not len(p):
            out.append(Role(UNKNOWN, "never seen"))
            continue
        rng = motion_range(p)
        mean = p.mean(axis=0)
        if len(p) >= 2 and rng > floor_mm:
            out.append(Role(PATIENT, f"moved {rng:.1f} mm over {len(p)} samples: breathing or a body"))
            moved.append((m, mean))
        elif why_not:
            out.append(Role(WALL, f"still ({rng:.2f} mm over {len(p)} samples); {why_not}"))
        elif space.inside(mean)[0]:
            out.append(
                Role(
                    UNKNOWN,
                    f"still, inside the table-and-gantry volume at ({mean[0]:.0f}, {mean[1]:.0f}, "
                    f"{mean[2]:.0f}) mm SPECT: on the table, never a wall marker",
                )
            )
        else:
            out.append(
                Role(
                    WALL,
                    f"still, outside the table-and-gantry volume at ({mean[0]:.0f}, {mean[1]:.0f}, "
                    f"{mean[2]:.0f}) mm SPECT",
                )
            )
    if len(moved) >= 2 and not why_not:
        order = sorted(moved, key=lambda mv: mv[1][2] if head_end_low_z else -mv[1][2])
        z = np.array([mv[1][2] for mv in order])
        gaps = np.abs(np.diff(z))
        k = int(np.argmax(gaps))
        if gaps[k] >= BAND_GAP_MM:
            for i, (m, mean) in enumerate(order):
                band = CHEST if i <= k else ABDOMEN
                out[m] = Role(
                    band,
                    f"{out[m].reason}; the {'head' if band == CHEST else 'foot'}-end band "
                    f"(Z {mean[2]:.0f} mm, the bands {gaps[k]:.0f} mm apart along the table)",
                )
    return out
