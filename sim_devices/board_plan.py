"""Where an operator holds the checkerboard so that N simulated cameras can be calibrated,
whatever the cameras' layout.

Each view is held towards one pair of cameras: the board faces the bisector of the two
directions to them from the point where their optical axes pass closest, turned and moved at
random, and is kept only if the whole board is inside both images and faces both cameras at no
more than ``max_obliquity_deg``. The pairs are chosen so that they connect every camera
(:func:`plan_views`: each camera's easiest pair first — the smallest angle between the two
cameras seen from the board, its neighbour at the same end — then the easiest pairs until they
connect all cameras, and each camera in two pairs where it can be), so no view needs every
camera. A head and a foot camera face each other: the board held for them lies about flat,
turned 45 deg in its plane, seen by both at no more than ``WIDE_GOOD_OBLIQUITY_DEG``
(:func:`_wide_pair_poses`; docs/decisions/0030-n-camera-calibration.md). The views are rendered
in the two cameras they are held for (:mod:`vts_hw.sim_devices.scenarios.calibration_views`).
"""

from __future__ import annotations

import itertools

import numpy as np

from vts_hw.sim_devices.checkerboard import (
    EDGE_SEGMENTS,
    IMAGE_MARGIN_PX,
    PATTERN,
    SQUARE_MM,
    Pose,
    _edge_points,
    _to_world,
    board_outline,
)
from vts_hw.sim_devices.scene import Scene, rotation_matrix

MAX_OBLIQUITY_DEG = 78.0  # a 9 x 6 board is still found at this angle (cos 0.21)
TRIES = 600


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def meeting_point(scene: Scene, a: str, b: str) -> np.ndarray:
    """The mid-point of the shortest segment between the two cameras' optical axes."""
    ca, cb = scene.cameras[a], scene.cameras[b]
    pa, pb = ca.center, cb.center
    da, db = ca.R[2], cb.R[2]  # optical axes in the world
    w = pa - pb
    A, B, C, D, E = da @ da, da @ db, db @ db, da @ w, db @ w
    den = A * C - B * B
    if den < 1e-9:  # parallel axes: in front of both, at the mean distance
        return (pa + pb) / 2 + da * float(np.linalg.norm(pa))
    s, t = (B * E - C * D) / den, (A * E - B * D) / den
    return (pa + s * da + pb + t * db) / 2


def pair_angle_deg(scene: Scene, a: str, b: str) -> float:
    """Angle between the two cameras as seen from where their axes meet."""
    p = meeting_point(scene, a, b)
    u, v = _unit(scene.cameras[a].center - p), _unit(scene.cameras[b].center - p)
    return float(np.degrees(np.arccos(np.clip(u @ v, -1, 1))))


def sees_board(
    scene: Scene,
    cam: str,
    pose: Pose,
    pattern=PATTERN,
    square_mm=SQUARE_MM,
    margin_px: float = IMAGE_MARGIN_PX,
    max_obliquity_deg: float = MAX_OBLIQUITY_DEG,
) -> bool:
    """The whole board (margin included) is in camera ``cam``'s image, facing it at no more than
    ``max_obliquity_deg`` from square on."""
    camera = scene.cameras[cam]
    R, t = pose
    front = -np.asarray(R)[:, 2]  # the printed side faces -z of the board
    centre = _to_world(pose, np.array([[(pattern[0] - 1) / 2 * square_mm, (pattern[1] - 1) / 2 * square_mm, 0]]))[0]
    if float(front @ _unit(camera.center - centre)) < np.cos(np.radians(max_obliquity_deg)):
        return False
    world = _to_world(pose, _edge_points(board_outline(pattern, square_mm), 4 * EDGE_SEGMENTS))
    if np.any(camera.to_camera(world)[:, 2] <= 0):
        return False
    uv = camera.project(world)
    return bool(
        uv.min() >= margin_px
        and np.all(uv[:, 0] <= camera.width - 1 - margin_px)
        and np.all(uv[:, 1] <= camera.height - 1 - margin_px)
    )


WIDE_PAIR_DEG = 90.0  # cameras further apart than this (seen from the board) face each other
WIDE_GOOD_OBLIQUITY_DEG = 72.5  # such a pair sees a board lying about flat at 70-73 deg each: its corners
WIDE_MAX_OBLIQUITY_DEG = 73.5  # are found well (< 0.2 px) only up to about 73.5 deg, and only with the
# board turned 45 deg in its plane (squares seen edge-on shrink to 13 px
# and the corner finder's window takes the neighbours in); poses up to
# the max are kept only where too few are found within the good limit
WIDE_TILT_DEG = 12.0  # how far such a board is tilted from the bisector either way
WIDE_CANDIDATES = 4  # poses found per pose kept for such a pair, the best spread kept
WIDE_TRIES = 40000


def obliquity_deg(scene: Scene, cam: str, pose: Pose, pattern=PATTERN, square_mm=SQUARE_MM) -> float:
    """Angle between the board's printed side (its normal) and the direction to camera ``cam``."""
    R, _ = pose
    centre = _to_world(pose, np.array([[(pattern[0] - 1) / 2 * square_mm, (pattern[1] - 1) / 2 * square_mm, 0]]))[0]
    c = float(-np.asarray(R)[:, 2] @ _unit(scene.cameras[cam].center - centre))
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


def _spread(normals: np.ndarray, n: int) -> list[int]:
    """``n`` indices of ``normals`` chosen one by one, each the farthest from those chosen
    (the first: the one nearest the mean), so that the kept boards face as many ways as possible."""
    first = int(np.argmax(normals @ _unit(normals.mean(axis=0))))
    chosen = [first]
    gap = 1.0 - normals @ normals[first]
    while len(chosen) < n:
        k = int(np.argmax(gap))
        chosen.append(k)
        gap = np.minimum(gap, 1.0 - normals @ normals[k])
    return chosen


def _wide_pair_poses(scene: Scene, a: str, b: str, n: int, rng, base, p, centre_b, pattern, square_mm) -> list[Pose]:
    """Poses for two cameras that face each other (a head and a foot camera): the board lies about
    flat between them, its printed side up towards the bisector, turned 45 deg (± 10) in its plane
    and tilted by up to ``WIDE_TILT_DEG`` either way. Poses both cameras see whole at no more than
    ``WIDE_MAX_OBLIQUITY_DEG`` are drawn (until ``WIDE_CANDIDATES`` per pose wanted are within
    ``WIDE_GOOD_OBLIQUITY_DEG``), the least oblique of them kept as candidates, and of those the
    ``n`` that face the most different ways."""
    found: list[tuple[float, Pose]] = []
    want = WIDE_CANDIDATES * n
    for _ in range(WIDE_TRIES):
        if sum(w <= WIDE_GOOD_OBLIQUITY_DEG for w, _ in found) >= want:
            break
        ang = [
            rng.uniform(-1.0, 1.0) * WIDE_TILT_DEG,
            rng.uniform(-1.0, 1.0) * WIDE_TILT_DEG,
            rng.choice([-45.0, 45.0]) + rng.uniform(-10.0, 10.0),
        ]
        R = base @ rotation_matrix(np.deg2rad(ang))
        t = (
            p
            + base @ np.array([rng.uniform(-100.0, 100.0), rng.uniform(-100.0, 100.0), rng.uniform(-150.0, 150.0)])
            - R @ centre_b
        )
        if all(
            sees_board(scene, c, (R, t), pattern, square_mm, max_obliquity_deg=WIDE_MAX_OBLIQUITY_DEG) for c in (a, b)
        ):
            found.append((max(obliquity_deg(scene, c, (R, t), pattern, square_mm) for c in (a, b)), (R, t)))
    if len(found) < 3:
        return []
    pool = [pose for _, pose in sorted(found, key=lambda wp: wp[0])[:want]]
    normals = np.array([-np.asarray(R)[:, 2] for R, _ in pool])
    return [pool[k] for k in _spread(normals, min(n, len(pool)))]


def pair_poses(
    scene: Scene,
    a: str,
    b: str,
    n: int,
    seed: int = 0,
    pattern=PATTERN,
    square_mm: float = SQUARE_MM,
    max_tilt_deg: float = 25.0,
    max_roll_deg: float = 10.0,
    shift_mm: float = 120.0,
    depth_mm: float = 150.0,
) -> list[Pose]:
    """``n`` board poses (board → world) that cameras ``a`` and ``b`` both see whole (fewer if
    the pair cannot see the board together: an empty list then). Cameras more than
    ``WIDE_PAIR_DEG`` apart (a head and a foot camera facing each other) get boards lying about
    flat between them, turned as far as both still see the printed side (:func:`_wide_pair_poses`)."""
    rng = np.random.default_rng(seed)
    p = meeting_point(scene, a, b)
    ua, ub = _unit(scene.cameras[a].center - p), _unit(scene.cameras[b].center - p)
    z = -_unit(ua + ub)  # board z points away from both cameras
    across = scene.cameras[b].center - scene.cameras[a].center
    x = across - (across @ z) * z
    x = _unit(x if np.linalg.norm(x) > 1e-6 else np.cross(z, [0.0, 1.0, 0.0]))
    if x[0] < 0:  # keep the board's rows running left to right
        x = -x
    base = np.column_stack([x, np.cross(z, x), z])
    centre_b = np.array([(pattern[0] - 1) / 2.0, (pattern[1] - 1) / 2.0, 0.0]) * square_mm
    half = float(np.degrees(np.arccos(np.clip(ua @ ub, -1, 1)))) / 2
    if 2 * half > WIDE_PAIR_DEG:
        return _wide_pair_poses(scene, a, b, n, rng, base, p, centre_b, pattern, square_mm)
    # cameras far apart see the board obliquely already: tilt it less
    max_tilt_deg = min(max_tilt_deg, max(2.0, MAX_OBLIQUITY_DEG - 2.0 - half))
    quadrants = [(1, 1), (-1, 1), (-1, -1), (1, -1)]
    poses: list[Pose] = []
    for k in range(2 * n):  # a turn no pose is found for is passed over
        if len(poses) == n:
            break
        sx, sy = quadrants[k % 4]
        for _ in range(TRIES):
            ang = [
                sx * rng.uniform(0.2, 1.0) * max_tilt_deg,
                sy * rng.uniform(0.2, 1.0) * max_tilt_deg,
                rng.uniform(-1.0, 1.0) * max_roll_deg,
            ]
            R = base @ rotation_matrix(np.deg2rad(ang))
            t = (
                p
                + base
                @ np.array(
                    [
                        rng.uniform(-shift_mm, shift_mm),
                        rng.uniform(-shift_mm, shift_mm),
                        rng.uniform(-depth_mm, depth_mm),
                    ]
                )
                - R @ centre_b
            )
            if all(sees_board(scene, c, (R, t), pattern, square_mm) for c in (a, b)):
                poses.append((R, t))
                break
    return poses if len(poses) >= 3 else []


def plan_views(
    scene: Scene, per_pair: int, seed: int = 0, cameras=None, pattern=PATTERN, square_mm: float = SQUARE_MM
) -> list[tuple[tuple[str, str], list[Pose]]]:
    """The pairs of cameras to hold the board towards, each with its ``per_pair`` poses: first
    each camera's easiest pair (so that every camera has views turned every way for its
    intrinsics: its neighbour at the same end where it has one), then the easiest pairs that join
    cameras not yet joined (between the head and the foot end: boards lying about flat), then a
    second pair for each camera in only one (see the module docstring). Pairs that cannot see
    the board together are passed over; whether the result connects every camera is for the
    calibration to say."""
    cams = list(cameras or scene.camera_names)
    order = sorted(itertools.combinations(cams, 2), key=lambda ab: pair_angle_deg(scene, *ab))
    group = {c: c for c in cams}

    def root(c):
        while group[c] != c:
            c = group[c]
        return c

    chosen: list[tuple[tuple[str, str], list[Pose]]] = []
    tried: dict[tuple[str, str], list[Pose]] = {}

    def poses_of(k, ab):
        if ab not in tried:
            tried[ab] = pair_poses(scene, *ab, per_pair, seed * 1009 + k, pattern, square_mm)
        return tried[ab]

    def take(ab):
        chosen.append((ab, tried[ab]))
        group[root(ab[0])] = root(ab[1])

    for c in cams:  # each camera's easiest pair
        if any(c in ab for ab, _ in chosen):
            continue
        for k, ab in enumerate(order):
            if c in ab and poses_of(k, ab):
                take(ab)
                break
    for k, (a, b) in enumerate(order):  # a spanning tree of the easiest pairs
        if root(a) != root(b) and poses_of(k, (a, b)):
            take((a, b))
    degree = {c: sum(c in p for p, _ in chosen) for c in cams}
    done = {ab for ab, _ in chosen}
    for k, (a, b) in enumerate(order):  # then a second pair where a camera has one
        if len(cams) > 2 and (a, b) not in done and (degree[a] < 2 or degree[b] < 2) and poses_of(k, (a, b)):
            take((a, b))
            done.add((a, b))
            degree[a] += 1
            degree[b] += 1
    return chosen
