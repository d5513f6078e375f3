"""The simulated room: cameras, markers, table, phantom, LEDs, camera clocks and drift.

One model with ground truth, in the SPECT frame (millimetres): origin at the centre of the
field of view (FOV) on the axis of rotation, X lateral, Y up, Z axial along the table.
Cameras follow the OpenCV convention (world -> camera: ``x_c = R @ x_w + t``; camera x right,
y down, z forward). :meth:`Scene.reference` builds the reference rig of docs/design.md.

Time-dependent parts take ``t`` (host UTC epoch seconds):

* camera drift, a slow rotation of each camera about its own centre (:class:`CameraDrift`,
  sim_devices/camera_motion.py), counted from ``Scene.start_epoch``;
* the warm-up drift of a camera after it starts, when one is declared (``Scene.warmups``,
  ``Scene.booted``: sim_devices/warmup.py);
* LED on/off, table position and the poses of bodies on the table, each a
  :class:`Schedule` of changes at given instants ("the latest command wins").

:meth:`Scene.truth` gives the projected centre of each visible marker: the projection of the
marker's 3D centre through the drifted camera, distortion included.
"""

from __future__ import annotations

import bisect
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar

import cv2
import numpy as np

from vts_hw.recording.axis_jpeg import AxisProduct
from vts_hw.sim_devices.camera_motion import DAY, CameraClock, CameraDrift  # noqa: F401  (re-exported)
from vts_hw.sim_devices.gantry import Gantry

if TYPE_CHECKING:  # they read and fill the scene's tables (each imports this module)
    from vts_hw.sim_devices.clock_warmup import ClockWarmup
    from vts_hw.sim_devices.optics import Optics
    from vts_hw.sim_devices.warmup import WarmupDrift

# Reference rig (docs/design.md, "The room"). Millimetres, pixels.
CAM_Y = 1100.0  # camera height above the table axis (2.1 m above a floor 1.0 m below the axis)
CAM_Z = -3530.0  # cameras over the patient's head, 3.7 m from the FOV centre
BASELINE = 1200.0  # X spread of the cameras
FOCAL_PX = 3370.0  # 3.75 m / 3370 px = about 1.11 mm/px at the FOV centre
K1 = -0.05
WALL_DISTANCE = 4160.0  # from the cameras' mid-point to the wall: about 1.25 mm/px
WALL_DIAMETER = 25.0
# Wall markers in the wall plane (mm; u along world X, v "up" in the plane), kept off the image
# centre where the phantom is seen, and asymmetric so that they can be told apart.
WALL_LAYOUT = {
    "W1": (-222.0, 150.0),
    "W2": (212.0, 170.0),
    "W3": (-232.0, -165.0),
    "W4": (202.0, -185.0),
    "W5": (15.0, -205.0),
}
SPHERE_DIAMETER = 13.0
# 7-sphere phantom: sphere centres relative to the base centre (mm, Y up): rods of different
# heights, spread over about 15 cm, not coplanar.
PHANTOM_LAYOUT = {
    "S1": (-54.0, 39.0, -72.0),
    "S2": (0.0, 30.0, -20.0),
    "S3": (58.0, 84.0, -71.0),
    "S4": (21.0, 122.0, -18.0),
    "S5": (75.0, 130.0, -47.0),
    "S6": (-58.0, 57.0, 35.0),
    "S7": (-40.0, 88.0, 73.0),
}  # chosen so no two overlap in the reference images
PHANTOM_PLACEMENT = (0.0, -80.0, 0.0)  # base centre on the table: the spheres straddle the FOV centre
AXIS_OUI = bytes.fromhex("ACCC8E")


def rotation_matrix(rvec) -> np.ndarray:
    """3x3 rotation matrix of a rotation vector (axis * angle in radians)."""
    return cv2.Rodrigues(np.asarray(rvec, dtype=float).reshape(3, 1))[0]


def _cross(a, b) -> np.ndarray:
    """Cross product of two 3-vectors (much cheaper than np.cross for single vectors)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


@dataclass(frozen=True, eq=False)
class CameraModel:
    """A pinhole camera with OpenCV distortion (k1, k2, p1, p2, k3) and a world->camera pose."""

    name: str
    K: np.ndarray
    dist: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int = 640
    height: int = 480

    @classmethod
    def from_rvec(cls, name, K, dist, rvec, tvec, width=640, height=480) -> CameraModel:
        return cls(
            name,
            np.asarray(K, float),
            np.asarray(dist, float).ravel(),
            rotation_matrix(rvec),
            np.asarray(tvec, float).ravel(),
            width,
            height,
        )

    @classmethod
    def look_at(
        cls, name, center, target, K, dist, roll_rad=0.0, up=(0.0, 1.0, 0.0), width=640, height=480
    ) -> CameraModel:
        """A camera at ``center`` whose optical axis passes through ``target``, image "up" ~ ``up``."""
        center = np.asarray(center, float)
        z = _unit(np.asarray(target, float) - center)
        x = _unit(_cross(z, up))
        y = _cross(z, x)
        R = rotation_matrix([0.0, 0.0, roll_rad]) @ np.vstack([x, y, z])
        return cls(name, np.asarray(K, float), np.asarray(dist, float).ravel(), R, -R @ center, width, height)

    @property
    def rvec(self) -> np.ndarray:
        return cv2.Rodrigues(self.R)[0].ravel()

    @property
    def tvec(self) -> np.ndarray:
        return self.t

    @property
    def center(self) -> np.ndarray:
        """The camera's optical centre in world coordinates."""
        return -self.R.T @ self.t

    @property
    def focal(self) -> float:
        """Mean focal length in pixels."""
        return float((self.K[0, 0] + self.K[1, 1]) / 2)

    def to_camera(self, points_world) -> np.ndarray:
        """World points (Nx3) in camera coordinates (Nx3); column 2 is the depth."""
        return np.asarray(points_world, float).reshape(-1, 3) @ self.R.T + self.t

    def project(self, points_world) -> np.ndarray:
        """Pixel coordinates (Nx2) of world points (Nx3), distortion included."""
        pts = np.asarray(points_world, float).reshape(-1, 1, 3)
        uv, _ = cv2.projectPoints(pts, self.rvec, self.t, self.K, self.dist)
        return uv.reshape(-1, 2)

    def rotated(self, rvec_camera) -> CameraModel:
        """This camera turned about its own centre by a rotation given in camera coordinates."""
        Rd = rotation_matrix(rvec_camera)
        return CameraModel(self.name, self.K, self.dist, Rd @ self.R, Rd @ self.t, self.width, self.height)


@dataclass(frozen=True, eq=False)
class Marker:
    """A retro-reflective marker: a flat ``"disk"`` (seen from the side its normal points to)
    or a ``"sphere"``. Centre and normal in world (or body) coordinates, mm."""

    id: str
    center: np.ndarray
    normal: np.ndarray
    diameter_mm: float
    kind: str = "disk"

    def moved(self, R: np.ndarray, t: np.ndarray) -> Marker:
        return Marker(self.id, R @ self.center + t, R @ self.normal, self.diameter_mm, self.kind)

    def faces(self, eye) -> bool:
        """Whether a camera at ``eye`` sees the reflective side."""
        return self.kind == "sphere" or float(np.dot(self.normal, np.asarray(eye) - self.center)) > 0

    def outline(self, eye, n_points: int = 96) -> np.ndarray:
        """The 3D circle whose projection is the marker's outline as seen from ``eye`` (n x 3).

        A disk: its rim. A sphere: the circle where the viewing cone touches it (centre moved
        r^2/d towards the eye, radius r*sqrt(1 - r^2/d^2)).
        """
        r = self.diameter_mm / 2.0
        c = self.center
        if self.kind == "sphere":
            view = c - np.asarray(eye, float)
            d = np.linalg.norm(view)
            n = view / d
            c = c - n * (r * r / d)
            r = r * np.sqrt(1.0 - (r / d) ** 2)
        else:
            n = _unit(self.normal)
        helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        e1 = _unit(_cross(n, helper))
        e2 = _cross(n, e1)
        a = np.linspace(0.0, 2 * np.pi, n_points, endpoint=False)
        return c + r * (np.outer(np.cos(a), e1) + np.outer(np.sin(a), e2))


class Schedule:
    """A value that changes at given instants (piecewise constant in time). Thread-safe.

    ``set(v, t)`` makes ``v`` the value from ``t`` on and cancels changes scheduled at or
    after ``t`` (the latest command wins); ``set(v)`` without a time makes ``v`` the value at
    all times. Old history beyond ``max_events`` changes is folded into the initial value.
    """

    def __init__(self, initial: Any, max_events: int = 4096):
        self._initial = initial
        self._times: list[float] = []
        self._values: list[Any] = []
        self._max = max_events
        self._lock = threading.Lock()

    def set(self, value: Any, t: float | None = None) -> None:
        with self._lock:
            if t is None:
                self._initial, self._times, self._values = value, [], []
                return
            i = bisect.bisect_left(self._times, t)
            del self._times[i:], self._values[i:]
            self._times.append(float(t))
            self._values.append(value)
            if len(self._times) > self._max:
                k = len(self._times) - self._max
                self._initial = self._values[k - 1]
                del self._times[:k], self._values[:k]

    def at(self, t: float) -> Any:
        with self._lock:
            i = bisect.bisect_right(self._times, t)
            return self._values[i - 1] if i else self._initial


Pose = tuple[tuple[float, float, float], tuple[float, float, float]]  # (rotvec, translation)


class Body(Protocol):
    """What the scene asks of a body on its table: a :class:`RigidBody`, or the simulated patient
    (sim_devices/patient.py), whose markers breathe and move."""

    name: str
    pose: Any  # RigidBody's: a Schedule of poses (set_body_pose); a patient's: a key for caches

    @property
    def markers(self) -> list[Marker]: ...

    def markers_at(self, t: float, table_offset: np.ndarray) -> list[Marker]: ...


B = TypeVar("B", bound=Body)


class RigidBody:
    """Markers fixed to one body carried by the table (the phantom, a patient band).

    ``markers`` are in body coordinates; the pose (rotation vector, translation in table
    coordinates, i.e. world coordinates at table position 0) is a :class:`Schedule`.
    """

    def __init__(self, name: str, markers: list[Marker], pose: Pose = ((0, 0, 0), (0, 0, 0))):
        self.name = name
        self.markers = list(markers)
        self.pose = Schedule(_pose(*pose))

    def markers_at(self, t: float, table_offset: np.ndarray) -> list[Marker]:
        rvec, trans = self.pose.at(t)
        R = rotation_matrix(rvec)
        shift = np.asarray(trans, float) + table_offset
        return [m.moved(R, shift) for m in self.markers]


def _pose(rvec, translation) -> Pose:
    rx, ry, rz = (float(x) for x in np.ravel(rvec))
    tx, ty, tz = (float(x) for x in np.ravel(translation))
    return (rx, ry, rz), (tx, ty, tz)


def camera_positions(n_cameras: int) -> list[tuple[float, float, float]]:
    """Centres (mm) of the reference rig's cameras: pairs alternating between the head end
    (Z < 0) and the foot end (Z > 0); see :meth:`Scene.reference`."""
    if n_cameras < 1:
        raise ValueError(f"a rig needs at least one camera, not {n_cameras}")
    if n_cameras == 1:
        return [(0.0, CAM_Y, CAM_Z)]
    out = []
    for i in range(n_cameras):
        pair, side = divmod(i, 2)
        end = -1.0 if pair % 2 == 0 else 1.0  # head end first
        half = BASELINE / 2 / 2 ** (pair // 2)
        alone = side == 0 and i == n_cameras - 1
        x = 0.0 if alone else (-half if side == 0 else half) * (-end)  # seen from its end, cam1 left
        out.append((x, CAM_Y + 300.0 * (pair // 2), -end * CAM_Z))
    return out


class Scene:
    """Cameras (base pose, clock, drift, product id), wall markers, the table and its bodies,
    and each camera's LED. Build the reference rig with :meth:`reference`."""

    def __init__(
        self,
        cameras: list[CameraModel],
        clocks: dict[str, CameraClock],
        drifts: dict[str, CameraDrift],
        products: dict[str, AxisProduct],
        wall_markers: list[Marker],
        start_epoch: float,
    ):
        self.cameras = {c.name: c for c in cameras}
        self.clocks = dict(clocks)
        self.drifts = dict(drifts)
        self.products = dict(products)
        self.wall_markers = list(wall_markers)
        self.start_epoch = float(start_epoch)
        self.table = Schedule((0.0, 0.0))  # (y, z) offsets of the table, mm
        self.bodies: dict[str, Body] = {}
        self._leds = {name: Schedule(False) for name in self.cameras}
        self.gantry: Gantry | None = None  # the SPECT heads (sim_devices/gantry.py), when the room has them
        # focus and mount; turned mounts' rvecs (sim_devices/optics.py)
        self.optics: dict[str, Optics] = {}
        self.mounts: dict[str, np.ndarray] = {}
        # warm-up declared (warmup.py, clock_warmup.py), and when each camera booted
        self.warmups: dict[str, WarmupDrift] = {}
        self.booted: dict[str, float] = {}
        self.clock_warmups: dict[str, ClockWarmup] = {}

    # ----------------------------------------------------------------- construction
    @classmethod
    def reference(
        cls,
        seed: int = 0,
        n_cameras: int = 2,
        start_epoch: float | None = None,
        drift_px_per_60_days: tuple[float, float] = (0.9, 1.3),
        gantry=None,
    ) -> Scene:
        """The reference rig: ``n_cameras`` cameras in pairs at the head and foot ends.

        Pair 1 (cam1, cam2) looks over the patient's head, as the 2-camera rig of
        docs/design.md; pair 2 (cam3, cam4) looks from the foot end; further pairs alternate
        ends, each 300 mm higher and half as wide as the pair before at its end; an odd last
        camera sits alone on the axis of its end (one camera: over the head). Each end's
        cameras see their own wall of 5 markers beyond the gantry (W1-W5 for the head end,
        W6-W10 for the foot end). Small per-camera differences (focal length, principal point,
        aim, roll, k1, clock offset and skew, drift) are drawn from ``seed`` camera by camera,
        so cam1 and cam2 are the same in every rig of a seed. ``gantry``: the SPECT heads
        (a :class:`~vts_hw.sim_devices.gantry.Gantry`; ``True`` for the reference one, parked).
        """
        start = time.time() if start_epoch is None else float(start_epoch)
        rng = np.random.default_rng(seed)
        cameras, clocks, drifts, products, macs = [], {}, {}, {}, set()
        for i, centre in enumerate(camera_positions(n_cameras)):
            name = f"cam{i + 1}"
            f = FOCAL_PX * (1 + rng.normal(0, 0.005))
            cx = 319.5 + float(np.clip(rng.normal(0, 4), -10, 10))
            cy = 239.5 + float(np.clip(rng.normal(0, 4), -10, 10))
            K = np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])
            dist = np.array([K1 + rng.normal(0, 0.005), 0.0, 0.0, 0.0, 0.0])
            aim = rng.normal(0, 15.0, 3)
            roll = np.deg2rad(rng.normal(0, 0.3))
            cameras.append(CameraModel.look_at(name, centre, aim, K, dist, roll))
            clocks[name] = CameraClock(float(rng.uniform(-3, 3)), float(rng.uniform(-50, 50)), start)
            px = float(rng.uniform(*drift_px_per_60_days))
            drifts[name] = CameraDrift.reference(f, seed * 1000 + 17 * i, start, px)
            mac = AXIS_OUI + bytes(rng.integers(0, 256, 3).tolist())
            while mac in macs:
                mac = AXIS_OUI + bytes(rng.integers(0, 256, 3).tolist())
            macs.add(mac)
            products[name] = AxisProduct(0x0241, (5, 55, 1), mac)
        head = [c for c in cameras if c.center[2] < 0]
        foot = [c for c in cameras if c.center[2] > 0]
        wall = cls._wall(head, WALL_LAYOUT) if head else []
        if foot:  # mirrored (about the layout's middle): each end's cameras see the same arrangement
            wall += cls._wall(
                foot, {f"W{int(k[1:]) + len(WALL_LAYOUT)}": (-u - 20.0, v) for k, (u, v) in WALL_LAYOUT.items()}
            )
        scene = cls(cameras, clocks, drifts, products, wall, start)
        if gantry:
            scene.gantry = gantry if isinstance(gantry, Gantry) else Gantry()
        return scene

    @staticmethod
    def _wall(cameras: list[CameraModel], layout=WALL_LAYOUT) -> list[Marker]:
        """Wall markers on a plane facing the cameras, WALL_DISTANCE beyond their mid-point."""
        mid = np.mean([c.center for c in cameras], axis=0)
        view = _unit(-mid)  # towards the FOV centre
        centre = mid + WALL_DISTANCE * view
        normal = -view
        e_u = _unit(np.array([1.0, 0, 0]) - normal[0] * normal)
        e_v = _cross(e_u, normal)
        return [
            Marker(marker_id, centre + u * e_u + v * e_v, normal, WALL_DIAMETER, "disk")
            for marker_id, (u, v) in layout.items()
        ]

    def add_body(self, body: B) -> B:
        self.bodies[body.name] = body
        return body

    def add_phantom(self, placement=PHANTOM_PLACEMENT, rvec=(0.0, 0.0, 0.0)) -> RigidBody:
        """Put the 7-sphere phantom (S1..S7, 13 mm spheres) on the table, base at ``placement``."""
        spheres = [
            Marker(k, np.array(v), np.array([0.0, 1.0, 0.0]), SPHERE_DIAMETER, "sphere")
            for k, v in PHANTOM_LAYOUT.items()
        ]
        return self.add_body(RigidBody("phantom", spheres, (rvec, placement)))

    # ----------------------------------------------------------------- state over time
    @property
    def camera_names(self) -> list[str]:
        return list(self.cameras)

    def move_table(self, y: float, z: float, t: float | None = None) -> None:
        """Table offsets (mm, vertical and axial) from ``t`` on (at all times when ``t`` is None)."""
        self.table.set((float(y), float(z)), t)

    def table_position(self, t: float) -> tuple[float, float]:
        return self.table.at(t)

    def set_body_pose(self, name: str, rvec, translation, t: float | None = None) -> None:
        """Pose of a body on the table (rotation vector, translation in table coordinates)."""
        self.bodies[name].pose.set(_pose(rvec, translation), t)

    def set_phantom_pose(self, rvec, translation=PHANTOM_PLACEMENT, t: float | None = None) -> None:
        self.set_body_pose("phantom", rvec, translation, t)

    def set_led(self, cam: str, on: bool, t: float | None = None) -> None:
        self._leds[cam].set(bool(on), t)

    def pulse_led(self, cam: str, t_start: float, duration_s: float) -> None:
        """LED on at ``t_start``, off ``duration_s`` later (cancels later scheduled changes)."""
        self._leds[cam].set(True, t_start)
        self._leds[cam].set(False, t_start + duration_s)

    def led_on(self, cam: str, t: float) -> bool:
        return self._leds[cam].at(t)

    def pose_key(self, t: float) -> tuple:
        """A hashable summary of everything on the table at ``t`` (for render caches)."""
        key = (self.table.at(t),) + tuple((n, b.pose.at(t)) for n, b in self.bodies.items())
        return key if self.gantry is None else key + (("gantry", self.gantry.key(t)),)

    # ----------------------------------------------------------------- ground truth
    def camera_at(self, cam: str, t: float) -> CameraModel:
        """Camera ``cam`` at time ``t``: the base pose turned by its drift, its warm-up drift
        (when declared) and its mount."""
        camera = self.cameras[cam].rotated(self.drifts[cam].rotation_at(t))
        warm = self.warmups.get(cam)
        if warm is not None and cam in self.booted:
            camera = camera.rotated(warm.rotation_at(t - self.booted[cam]))
        mount = self.mounts.get(cam)
        return camera if mount is None else camera.rotated(mount)

    def markers_world(self, t: float) -> list[Marker]:
        """Every marker in world coordinates at ``t`` (wall, then bodies on the table)."""
        y, z = self.table.at(t)
        offset = np.array([0.0, y, z])
        out = list(self.wall_markers)
        for body in self.bodies.values():
            out.extend(body.markers_at(t, offset))
        return out

    def project_markers(self, cam: str, t: float):
        """``(camera, markers, uv, visible)``: the drifted camera, all markers, their projected
        centres (Nx2) and whether each is visible (in front, facing, centre inside the image)."""
        camera = self.camera_at(cam, t)
        markers = self.markers_world(t)
        centres = np.array([m.center for m in markers])
        uv = camera.project(centres)
        eye = camera.center
        depth = camera.to_camera(centres)[:, 2]
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= camera.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= camera.height - 1)
        visible = inside & (depth > 0) & np.array([m.faces(eye) for m in markers])
        return camera, markers, uv, visible & ~self.hidden(eye, markers, t)

    def hidden(self, eye, markers: list[Marker], t: float) -> np.ndarray:
        """Whether each marker is hidden from ``eye`` at ``t`` by a SPECT head or by a body that
        is opaque (one with ``hides``, the patient's torso): bool array, all False when there
        is neither. A marker is hidden whole when any of it would be."""
        hidden = np.zeros(len(markers), bool)
        if not markers:
            return hidden
        centres = np.array([m.center for m in markers])
        radii = np.array([m.diameter_mm / 2 for m in markers])
        if self.gantry is not None:
            hidden |= self.gantry.hides(eye, centres, t, radii)
        y, z = self.table.at(t)
        for body in self.bodies.values():
            if hasattr(body, "hides"):
                hidden |= body.hides(eye, centres, t, radii, table_offset=(0.0, y, z))
        return hidden

    def truth(self, cam: str, t: float) -> list[tuple[str, float, float]]:
        """``(marker_id, u, v)`` for each marker visible in ``cam`` at ``t`` (drift and
        distortion applied; the projection of the marker's 3D centre)."""
        _, markers, uv, visible = self.project_markers(cam, t)
        return [(m.id, float(p[0]), float(p[1])) for m, p, v in zip(markers, uv, visible) if v]
