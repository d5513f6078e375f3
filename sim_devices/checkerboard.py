"""What each simulated camera sees of a planar checkerboard held up by an operator.

The board lies in its own plane z = 0 (millimetres): inner corner (i, j) of a ``pattern``
(cols, rows) board sits at ``(i * square, j * square, 0)``, the order of
:func:`vts_hw.vision.checkerboard.board_points`. Around the inner corners are (cols + 1) x (rows + 1)
squares, the square at the board's (-1, -1) corner black, and around them a white margin one
square wide.

:func:`board_poses` draws poses (board -> world, ``x_w = R @ x_b + t``) near the centre of the
field of view, each fully visible in both cameras; :func:`render_board` rasterises the board
through the full camera model (distortion included): each edge of each square is cut into short
segments whose ends go through :meth:`CameraModel.project`, and the convex polygon they form is
filled with the exact-in-x, supersampled-in-y coverage of :func:`render.polygon_coverage`.
:func:`truth_corners` gives the projected inner corners to check a corner finder against.
"""

from __future__ import annotations

import cv2
import numpy as np

from vts_hw.sim_devices.render import Renderer, encode, polygon_coverage
from vts_hw.sim_devices.scene import CameraModel, Scene, rotation_matrix

PATTERN = (9, 6)
SQUARE_MM = 50.0  # a 9 x 6 board of 50 mm squares (about 550 x 400 mm): see docs/decisions/0015
BOARD_WHITE = 200.0  # grey level of the white paper under the LEDs' and room light
BOARD_BLACK = 35.0  # grey level of the printed black squares
BACKGROUND = 20.0  # the dim room behind the board (as in render.Renderer)
EDGE_SEGMENTS = 8  # segments per square edge (distortion bends the projected edges)
IMAGE_MARGIN_PX = 10.0  # every part of the board stays this far inside both images

Pose = tuple[np.ndarray, np.ndarray]  # (R 3x3, t 3) board -> world


def board_outline(pattern: tuple[int, int] = PATTERN, square_mm: float = SQUARE_MM) -> np.ndarray:
    """The four corners of the whole board (white margin included) in the board plane (4 x 3)."""
    cols, rows = pattern
    lo, hx, hy = -2.0 * square_mm, (cols + 1) * square_mm, (rows + 1) * square_mm
    return np.array([[lo, lo, 0.0], [hx, lo, 0.0], [hx, hy, 0.0], [lo, hy, 0.0]])


def _camera(scene: Scene, cam: str | CameraModel) -> CameraModel:
    return cam if isinstance(cam, CameraModel) else scene.cameras[cam]


def _to_world(pose: Pose, pts: np.ndarray) -> np.ndarray:
    R, t = pose
    return np.asarray(pts, float).reshape(-1, 3) @ np.asarray(R, float).T + np.asarray(t, float)


def _base_rotation(scene: Scene) -> np.ndarray:
    """Board -> world rotation of a board squarely facing the cameras: the board's x and y run
    along the image's right and down, its z points away from the cameras."""
    centres = np.array([c.center for c in scene.cameras.values()])
    view = -centres.mean(axis=0)  # from the cameras' mid-point to the FOV centre
    z = view / np.linalg.norm(view)
    x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def fully_visible(
    scene: Scene,
    pose: Pose,
    pattern: tuple[int, int] = PATTERN,
    square_mm: float = SQUARE_MM,
    margin_px: float = IMAGE_MARGIN_PX,
) -> bool:
    """Whether the whole board (white margin included) is in front of every camera and at
    least ``margin_px`` inside its image."""
    outline = _edge_points(board_outline(pattern, square_mm), 4 * EDGE_SEGMENTS)
    world = _to_world(pose, outline)
    for camera in scene.cameras.values():
        if np.any(camera.to_camera(world)[:, 2] <= 0):
            return False
        uv = camera.project(world)
        if (
            uv.min() < margin_px
            or np.any(uv[:, 0] > camera.width - 1 - margin_px)
            or np.any(uv[:, 1] > camera.height - 1 - margin_px)
        ):
            return False
    return True


def board_poses(
    scene: Scene,
    n: int = 18,
    seed: int = 0,
    pattern: tuple[int, int] = PATTERN,
    square_mm: float = SQUARE_MM,
    max_tilt_deg: float = 30.0,
    max_roll_deg: float = 10.0,
    depth_mm: float = 200.0,
    margin_px: float = IMAGE_MARGIN_PX,
) -> list[Pose]:
    """``n`` board poses (R, t board -> world) spread over the common field of view.

    Each pose turns the board from facing the cameras by up to ``max_tilt_deg`` about its two
    in-plane axes and ``max_roll_deg`` about its normal, moves it up to ``depth_mm`` nearer or
    farther along the viewing direction and across the field as far as the view allows; the
    tilts cycle through the four quadrants so that every direction of tilt is covered. Poses
    that would leave any part of the board closer than ``margin_px`` to an image edge of
    either camera are drawn again. Deterministic for a given ``seed``.
    """
    if n < 1:
        raise ValueError("n must be at least 1")
    rng = np.random.default_rng(seed)
    base = _base_rotation(scene)
    cols, rows = pattern
    centre_b = np.array([(cols - 1) / 2.0, (rows - 1) / 2.0, 0.0]) * square_mm
    quadrants = [(1, 1), (-1, 1), (-1, -1), (1, -1)]
    poses: list[Pose] = []
    for k in range(n):
        sx, sy = quadrants[k % 4]
        for _ in range(2000):
            # Tilt magnitudes mostly large (they constrain the focal length), signs by quadrant.
            ax = sx * rng.uniform(0.2, 1.0) * max_tilt_deg
            ay = sy * rng.uniform(0.2, 1.0) * max_tilt_deg
            az = rng.uniform(-1.0, 1.0) * max_roll_deg
            R = base @ rotation_matrix(np.deg2rad([ax, ay, az]))
            # Position: across the field (in the board-facing plane) and along the view.
            shift = base @ np.array([rng.uniform(-180, 180), rng.uniform(-130, 130), rng.uniform(-depth_mm, depth_mm)])
            t = shift - R @ centre_b
            if fully_visible(scene, (R, t), pattern, square_mm, margin_px):
                poses.append((R, t))
                break
        else:  # pragma: no cover - the reference rig always has room
            raise RuntimeError("no board pose fits in both cameras' images")
    return poses


def truth_corners(
    scene: Scene, cam: str | CameraModel, pose: Pose, pattern: tuple[int, int] = PATTERN, square_mm: float = SQUARE_MM
) -> np.ndarray:
    """Pixel coordinates (N x 2) of the inner corners in camera ``cam`` (distortion included),
    row by row as :func:`vts_hw.vision.checkerboard.board_points` orders them."""
    cols, rows = pattern
    pts = np.zeros((cols * rows, 3))
    pts[:, :2] = np.mgrid[0:cols, 0:rows].T.reshape(-1, 2) * square_mm
    return _camera(scene, cam).project(_to_world(pose, pts))


def _edge_points(corners: np.ndarray, segments: int) -> np.ndarray:
    """Points along the closed polygon ``corners`` (k x 3), ``segments`` per edge, no repeats."""
    a = np.linspace(0.0, 1.0, segments, endpoint=False)[:, None]
    out = [c0 + a * (c1 - c0) for c0, c1 in zip(corners, np.roll(corners, -1, axis=0))]
    return np.vstack(out)


def _add_polygon(img: np.ndarray, poly: np.ndarray, amount: float, supersample: int) -> None:
    """Add ``amount`` x the coverage of the convex polygon ``poly`` (pixel coords) to ``img``."""
    h, w = img.shape
    x0, y0 = np.maximum(np.floor(poly.min(axis=0) + 0.5).astype(int) - 1, 0)
    x1, y1 = np.minimum(np.floor(poly.max(axis=0) + 0.5).astype(int) + 2, (w, h))
    if x1 <= x0 or y1 <= y0:
        return
    cover = polygon_coverage(poly, int(x0), int(y0), int(x1 - x0), int(y1 - y0), supersample)
    img[y0:y1, x0:x1] += amount * cover


def render_clean(
    scene: Scene,
    cam: str | CameraModel,
    pose: Pose,
    pattern: tuple[int, int] = PATTERN,
    square_mm: float = SQUARE_MM,
    supersample: int = 8,
    white: float = BOARD_WHITE,
    black: float = BOARD_BLACK,
    background: float = BACKGROUND,
    seed: int = 0,
) -> np.ndarray:
    """The noise-free float32 (H, W) image of the board in camera ``cam`` (not quantised)."""
    camera = _camera(scene, cam)
    names = list(scene.cameras)
    bg_seed = seed * 101 + (names.index(camera.name) if camera.name in names else 0)
    img = Renderer._make_background(camera.width, camera.height, background, bg_seed).copy()
    # Make room for the paper, then lay the black squares on it (their coverages only add up:
    # neighbouring squares touch at their corners).
    outline = camera.project(_to_world(pose, _edge_points(board_outline(pattern, square_mm), 4 * EDGE_SEGMENTS)))
    paper = np.zeros_like(img)
    _add_polygon(paper, outline, 1.0, supersample)
    img += paper * (white - img)
    cols, rows = pattern
    s = float(square_mm)
    squares = []
    for j in range(-1, rows):
        for i in range(-1, cols):
            if (i + j) % 2 == 0:  # the square at (-1, -1) is black
                x, y = i * s, j * s
                squares.append(np.array([[x, y, 0.0], [x + s, y, 0.0], [x + s, y + s, 0.0], [x, y + s, 0.0]]))
    pts = np.vstack([_edge_points(q, EDGE_SEGMENTS) for q in squares])
    uv = camera.project(_to_world(pose, pts)).reshape(len(squares), -1, 2)
    for poly in uv:
        _add_polygon(img, poly, black - white, supersample)
    return img


def render_board(
    scene: Scene,
    cam: str | CameraModel,
    pose: Pose,
    pattern: tuple[int, int] = PATTERN,
    square_mm: float = SQUARE_MM,
    noise_sigma: float = 2.0,
    quality: int = 75,
    seed: int = 0,
) -> bytes:
    """JPEG bytes (grey, ``quality``) of what camera ``cam`` sees of the board at ``pose``,
    with Gaussian sensor noise of ``noise_sigma`` grey levels (0: none) drawn from ``seed``,
    added before the image is rounded to 8 bits."""
    img = render_clean(scene, cam, pose, pattern, square_mm, seed=seed)
    if noise_sigma > 0:
        img = img + np.random.default_rng(seed).normal(0.0, noise_sigma, img.shape)
    return encode(np.clip(np.rint(img), 0, 255).astype(np.uint8), quality)


def decode(jpeg: bytes) -> np.ndarray:
    """The grey uint8 image of a JPEG made by :func:`render_board`."""
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise ValueError("not a JPEG image")
    return img


def render_pairs(
    scene: Scene,
    n: int = 18,
    seed: int = 0,
    pattern: tuple[int, int] = PATTERN,
    square_mm: float = SQUARE_MM,
    cams: tuple[str, str] = ("cam1", "cam2"),
    t: float | None = None,
):
    """``n`` stereo views of the board as an operator would hold it (:func:`board_poses`):
    a list of (left, right) grey images and their names ``sim01``…, each image with its own
    noise. With ``t`` the cameras are as they are at ``t`` (drift included), else as mounted."""
    seen_by: tuple[str | CameraModel, ...] = tuple(scene.camera_at(c, t) for c in cams) if t is not None else cams
    pairs, names = [], []
    for k, pose in enumerate(board_poses(scene, n=n, seed=seed, pattern=pattern, square_mm=square_mm)):
        pairs.append(
            tuple(
                decode(render_board(scene, cam, pose, pattern, square_mm, seed=seed * 10007 + 2 * k + i))
                for i, cam in enumerate(seen_by)
            )
        )
        names.append(f"sim{k + 1:02d}")
    return pairs, names
