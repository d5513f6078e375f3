"""Where an operator holds the checkerboard so that N simulated cameras can be calibrated,
whatever the cameras' layout.

Each view is held towards one pair of cameras: the board faces the bisector of the two
directions to them from the point where their optical axes pass closest, turned and moved at
random, and is kept only if the whole board is inside both images and faces both cameras at no
more than ``max_obliquity_deg``. The pairs are chosen so that they connect every camera
(:func:`plan_views`: the easiest pairs first — the smallest angle between the two cameras seen
from the board — until the pairs connect all cameras and each camera is in two pairs where it
can be), so no view needs every camera. The views are rendered in the two cameras they are
held for (:mod:`vts_hw.sim_devices.scenarios.calibration_views`).
"""

from __future__ import annotations

import itertools

import numpy as np

from vts_hw.sim_devices.checkerboard import (IMAGE_MARGIN_PX, PATTERN, SQUARE_MM, EDGE_SEGMENTS, Pose,
                                             _edge_points, _to_world, board_outline)
from vts_hw.sim_devices.scene import Scene, rotation_matrix

MAX_OBLIQUITY_DEG = 78.0   # a 9 x 6 board is still found at this angle (cos 0.21)
TRIES = 600


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def meeting_point(scene: Scene, a: str, b: str) -> np.ndarray:
    """The mid-point of the shortest segment between the two cameras' optical axes."""
    ca, cb = scene.cameras[a], scene.cameras[b]
    pa, pb = ca.center, cb.center
    da, db = ca.R[2], cb.R[2]          # optical axes in the world
    w = pa - pb
    A, B, C, D, E = da @ da, da @ db, db @ db, da @ w, db @ w
    den = A * C - B * B
    if den < 1e-9:                    # parallel axes: in front of both, at the mean distance
        return (pa + pb) / 2 + da * float(np.linalg.norm(pa))
    s, t = (B * E - C * D) / den, (A * E - B * D) / den
    return (pa + s * da + pb + t * db) / 2


def pair_angle_deg(scene: Scene, a: str, b: str) -> float:
    """Angle between the two cameras as seen from where their axes meet."""
    p = meeting_point(scene, a, b)
    u, v = _unit(scene.cameras[a].center - p), _unit(scene.cameras[b].center - p)
    return float(np.degrees(np.arccos(np.clip(u @ v, -1, 1))))


def sees_board(scene: Scene, cam: str, pose: Pose, pattern=PATTERN, square_mm=SQUARE_MM,
               margin_px: float = IMAGE_MARGIN_PX, max_obliquity_deg: float = MAX_OBLIQUITY_DEG) -> bool:
    """The whole board (margin included) is in camera ``cam``'s image, facing it at no more than
    ``max_obliquity_deg`` from square on."""
    camera = scene.cameras[cam]
    R, t = pose
    front = -np.asarray(R)[:, 2]                      # the printed side faces -z of the board
    centre = _to_world(pose, np.array([[(pattern[0] - 1) / 2 * square_mm, (pattern[1] - 1) / 2 * square_mm, 0]]))[0]
    if float(front @ _unit(camera.center - centre)) < np.cos(np.radians(max_obliquity_deg)):
        return False
    world = _to_world(pose, _edge_points(board_outline(pattern, square_mm), 4 * EDGE_SEGMENTS))
    if np.any(camera.to_camera(world)[:, 2] <= 0):
        return False
    uv = camera.project(world)
    return bool(uv.min() >= margin_px and np.all(uv[:, 0] <= camera.width - 1 - margin_px)
                and np.all(uv[:, 1] <= camera.height - 1 - margin_px))


def pair_poses(scene: Scene, a: str, b: str, n: int, seed: int = 0, pattern=PATTERN,
               square_mm: float = SQUARE_MM, max_tilt_deg: float = 25.0, max_roll_deg: float = 10.0,
               shift_mm: float = 120.0, depth_mm: float = 150.0) -> list[Pose]:
    """``n`` board poses (board → world) that cameras ``a`` and ``b`` both see whole (fewer if
    the pair cannot see the board together: an empty list then)."""
    rng = np.random.default_rng(seed)
    p = meeting_point(scene, a, b)
    ua, ub = _unit(scene.cameras[a].center - p), _unit(scene.cameras[b].center - p)
    z = -_unit(ua + ub)                         # board z points away from both cameras
    across = scene.cameras[b].center - scene.cameras[a].center
    x = across - (across @ z) * z
    x = _unit(x if np.linalg.norm(x) > 1e-6 else np.cross(z, [0.0, 1.0, 0.0]))
    if x[0] < 0:                                # keep the board's rows running left to right
        x = -x
    base = np.column_stack([x, np.cross(z, x), z])
    # cameras far apart see the board obliquely already: tilt it less
    half = float(np.degrees(np.arccos(np.clip(ua @ ub, -1, 1)))) / 2
    max_tilt_deg = min(max_tilt_deg, max(2.0, MAX_OBLIQUITY_DEG - 2.0 - half))
    centre_b = np.array([(pattern[0] - 1) / 2.0, (pattern[1] - 1) / 2.0, 0.0]) * square_mm
    quadrants = [(1, 1), (-1, 1), (-1, -1), (1, -1)]
    poses: list[Pose] = []
    for k in range(n):
        sx, sy = quadrants[k % 4]
        for _ in range(TRIES):
            ang = [sx * rng.uniform(0.2, 1.0) * max_tilt_deg, sy * rng.uniform(0.2, 1.0) * max_tilt_deg,
                   rng.uniform(-1.0, 1.0) * max_roll_deg]
            R = base @ rotation_matrix(np.deg2rad(ang))
            t = p + base @ np.array([rng.uniform(-shift_mm, shift_mm), rng.uniform(-shift_mm, shift_mm),
                                     rng.uniform(-depth_mm, depth_mm)]) - R @ centre_b
            if all(sees_board(scene, c, (R, t), pattern, square_mm) for c in (a, b)):
                poses.append((R, t))
                break
        else:
            return poses if len(poses) >= 3 else []
    return poses


def plan_views(scene: Scene, per_pair: int, seed: int = 0, cameras=None, pattern=PATTERN,
               square_mm: float = SQUARE_MM) -> list[tuple[tuple[str, str], list[Pose]]]:
    """The pairs of cameras to hold the board towards, each with its ``per_pair`` poses: the
    easiest pairs first while they join cameras not yet joined, then a second pair for each
    camera in only one (see the module docstring). Pairs that cannot see the board together are
    passed over; whether the result connects every camera is for the calibration to say."""
    cams = list(cameras or scene.camera_names)
    order = sorted(itertools.combinations(cams, 2), key=lambda ab: pair_angle_deg(scene, *ab))
    group = {c: c for c in cams}

    def root(c):
        while group[c] != c:
            c = group[c]
        return c

    chosen: list[tuple[tuple[str, str], list[Pose]]] = []
    tried = set()
    for k, (a, b) in enumerate(order):              # a spanning tree of the easiest pairs
        if root(a) != root(b):
            tried.add((a, b))
            poses = pair_poses(scene, a, b, per_pair, seed * 1009 + k, pattern, square_mm)
            if poses:
                group[root(a)] = root(b)
                chosen.append(((a, b), poses))
    degree = {c: sum(c in p for p, _ in chosen) for c in cams}
    for k, (a, b) in enumerate(order):              # then a second pair where a camera has one
        if len(cams) > 2 and (a, b) not in tried and (degree[a] < 2 or degree[b] < 2):
            poses = pair_poses(scene, a, b, per_pair, seed * 1009 + k, pattern, square_mm)
            if poses:
                chosen.append(((a, b), poses))
                degree[a] += 1
                degree[b] += 1
    return chosen
