"""What the sync check needs from the simulated rig: its true calibration files and a move plan.

* :func:`true_stereo_calibration` / :func:`true_spect_mapping` — the scene's **true** cameras
  as a two-camera :class:`~vts_hw.vision.calibration_io.CameraCalibration` (VTS frame = camera 1's frame) and
  the true VTS → SPECT rigid transform (SPECT frame = the scene's world frame:
  ``RigidTransform(c1.R.T, −c1.R.T·c1.t)``). A perfect calibration: what the sync analysis
  measures is then timing, not calibration error. The mapping keeps, as a measured one does
  (procedures/spect_mapping.py), the phantom's sphere centres in the SPECT frame
  (``spheres_spect_mm``): the true ones at the phantom's placement, S1..S7 in the scene's
  order. :func:`write_true_calibration` writes both as ``calibration.json`` and
  ``spect_mapping.json``.
* :func:`plan_sync_moves` — move times for a source marker that keep clear of the simulated
  SPECT's head rotations (step-and-shoot: ``stop_s`` acquiring, then about ``rotate_s`` dead),
  so that every move is seen by the SPECT with live data on both sides.

Times are host UTC epoch seconds; positions mm.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vts_hw import __version__
from vts_hw.files import write_json_atomic
from vts_hw.sim_devices.scene import Scene
from vts_hw.sim_devices.source_marker import add_source_marker
from vts_hw.sim_devices.spect import phantom_centres
from vts_hw.vision.calibration_io import CameraCalibration, CameraFit
from vts_hw.vision.registration import RigidTransform
from vts_hw.vision.triangulate import PinholeCamera

__all__ = [
    "true_stereo_calibration",
    "true_spect_mapping",
    "write_true_calibration",
    "place_source_marker",
    "schedule_source_moves",
    "plan_sync_moves",
    "true_cameras",
    "write_true_cameras",
    "CALIBRATION_FILE",
    "MAPPING_FILE",
    "CAMERAS_FILE",
]

CALIBRATION_FILE = "calibration.json"
MAPPING_FILE = "spect_mapping.json"
CAMERAS_FILE = "cameras.json"
NOTE = "simulated rig: the scene's true cameras (not a measured calibration)"
# what a mapping keeps of its volume (vts_hw.spect.frame.volume_record), for the scene's world frame: the
# SPECT frame with its origin at the FOV centre, a head-first supine patient (sim_devices/patient.py)
SCENE_VOLUME = {
    "file": None,
    "format": "simulated scene",
    "shape": None,
    "voxel_size_mm": None,
    "centre_mm": [0.0, 0.0, 0.0],
    "patient_position": "HFS",
    "castor_image": False,
}


def _cams(scene: Scene, t: float | None, names=None):
    t = scene.start_epoch if t is None else float(t)
    names = list(names or scene.camera_names)[:2]
    return [scene.camera_at(n, t) for n in names]


def true_stereo_calibration(scene: Scene, t: float | None = None, names=None) -> CameraCalibration:
    """The first two cameras of ``scene`` (or of ``names``) at host time ``t`` (default its start;
    the drift over a scan is far below a pixel) as a calibration in mm in camera 1's frame,
    named as in the scene: x2 = R·x1 + T."""
    import datetime as _dt

    t = scene.start_epoch if t is None else float(t)
    names = list(names or scene.camera_names)[:2]
    c1, c2 = _cams(scene, t, names)
    R = c2.R @ c1.R.T
    size = (int(c1.width), int(c1.height))
    fits = [
        CameraFit(names[0], c1.K, c1.dist, np.eye(3), np.zeros(3), size),
        CameraFit(names[1], c2.K, c2.dist, R, c2.t - R @ c1.t, (int(c2.width), int(c2.height))),
    ]
    return CameraCalibration(
        fits,
        (9, 6),
        1.0,
        "mm",
        0.0,
        [],
        NOTE,
        method="truth",
        created=_dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        software=__version__,
    )


def true_spect_mapping(scene: Scene, t: float | None = None, names=None) -> RigidTransform:
    """VTS frame (camera 1's) → SPECT frame (the scene's world frame), the truth."""
    c1 = _cams(scene, t, names)[0]
    return RigidTransform(
        c1.R.T,
        -c1.R.T @ c1.t,
        {"note": NOTE, "spect_volume": SCENE_VOLUME, "spheres_spect_mm": phantom_centres().tolist()},
    )


def write_true_calibration(scene: Scene, folder, t: float | None = None) -> tuple[Path, Path]:
    """Write ``calibration.json`` (stereo) and ``spect_mapping.json`` (VTS → SPECT) of the
    scene's true cameras into ``folder``; returns both paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cal = true_stereo_calibration(scene, t).save(folder / CALIBRATION_FILE)
    mp = true_spect_mapping(scene, t).save(folder / MAPPING_FILE)
    return cal, mp


def true_cameras(scene: Scene, t: float | None = None, frame: str = "world") -> dict:
    """Every camera of ``scene`` at host time ``t`` (default its start), by name: the true
    N-camera calibration, in the scene's world frame (= the SPECT frame) or, with
    ``frame="cam1"``, in camera 1's frame as a calibration gives it (the VTS frame, which
    :func:`true_spect_mapping` maps to the SPECT frame)."""
    t = scene.start_epoch if t is None else float(t)
    cams = {n: scene.camera_at(n, t) for n in scene.camera_names}
    if frame == "world":
        return cams
    first = cams[scene.camera_names[0]]
    out = {}
    for n, c in cams.items():  # x_c = R x_w + t, x_w = R1^T (x_1 - t1)
        R = c.R @ first.R.T
        out[n] = PinholeCamera(c.K, c.dist, R, c.t - R @ first.t, n)
    return out


def write_true_cameras(scene: Scene, folder, t: float | None = None, frame: str = "cam1") -> Path:
    """``cameras.json``: every true camera (name, K, dist, R, t; mm), the N-camera form
    :func:`vts_hw.vision.camera_set.load_cameras` reads; by default in camera 1's frame, like
    ``calibration.json``, so that ``spect_mapping.json`` maps either to the SPECT frame."""

    Path(folder).mkdir(parents=True, exist_ok=True)
    path = Path(folder) / CAMERAS_FILE
    write_json_atomic(
        path,
        {
            "format": "vts-hw cameras",
            "unit": "mm",
            "note": NOTE,
            "frame": frame,
            "cameras": [
                {"name": n, "K": c.K.tolist(), "dist": c.dist.tolist(), "R": c.R.tolist(), "t": c.t.tolist()}
                for n, c in true_cameras(scene, t, frame).items()
            ],
        },
    )
    return path


def plan_sync_moves(
    t_fire: float,
    duration_s: float,
    n: int = 4,
    seed: int = 0,
    *,
    margin_s: float = 2.0,
    clear_s: float = 1.2,
    stop_s: float = 20.0,
    rotate_s: float = 2.0,
    max_start_delay_s: float = 0.4,
    min_mm: float = 10.0,
    max_mm: float = 30.0,
) -> tuple[list[float], list[float]]:
    """``n`` move start times (host s) and steps (mm, alternating sign) over a scan fired at
    ``t_fire`` lasting ``duration_s``: spread evenly over the time that is at least
    ``clear_s`` away from every possible head rotation (the k-th starts between
    ``k·stop_s + (k−1)·0.9·rotate_s`` and ``k·stop_s + (k−1)·1.1·rotate_s + max_start_delay_s``
    after the fire and lasts up to 1.1·``rotate_s``), at least ``margin_s`` from the scan's
    ends, jittered by ``seed``. ValueError when the moves cannot be at least 2 s apart."""
    lo, hi = t_fire + margin_s, t_fire + duration_s - margin_s - 0.3
    forbidden = []
    k = 1
    while k * stop_s < duration_s:
        a = t_fire + k * stop_s + (k - 1) * 0.9 * rotate_s
        b = t_fire + k * stop_s + (k - 1) * 1.1 * rotate_s + max_start_delay_s + 1.1 * rotate_s
        forbidden.append((a - clear_s - 0.3, b + clear_s))  # 0.3: the move itself
        k += 1
    allowed, cur = [], lo
    for a, b in forbidden:
        if a > cur:
            allowed.append((cur, min(a, hi)))
        cur = max(cur, b)
    if cur < hi:
        allowed.append((cur, hi))
    allowed = [(a, b) for a, b in allowed if b > a]
    total = sum(b - a for a, b in allowed)
    spacing = total / n if n else 0.0
    if n < 1 or spacing < 2.5:
        raise ValueError(f"{duration_s} s leaves {total:.1f} s clear of head rotations: too short for {n} moves")
    rng = np.random.default_rng(seed)
    u = (np.arange(n) + 0.5) * spacing + rng.uniform(-0.2, 0.2, n) * (spacing - 2.0)

    def place(x: float) -> float:
        for a, b in allowed:
            if x <= b - a:
                return a + x
            x -= b - a
        return allowed[-1][1]

    times = [place(float(x)) for x in u]
    steps = rng.uniform(min_mm, max_mm, n) * np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    return times, [float(s) for s in steps]


def place_source_marker(
    scene: Scene, *, name: str = "source", marker_id: str = "SRC", position=(10.0, -20.0, 5.0), rate_cps: float = 3000.0
):
    """Put a source marker at rest into a running scene (before a scan starts: adding a body
    while cameras render is not safe). Its moves come later, from :func:`schedule_source_moves`.
    Returns the truth so far (no moves)."""
    return add_source_marker(scene, [], [], name=name, marker_id=marker_id, position=position, rate_cps=rate_cps)


def schedule_source_moves(scene: Scene, marker, move_times, steps_mm, move_s: float = 0.3):
    """Schedule ``marker``'s moves (host s, mm) in a running scene, e.g. once the trigger's fire
    time is known: the moves are built on a scratch scene by
    :func:`~.source_marker.add_source_marker` and its pose schedule replaces the body's in one
    assignment (the rendering threads see either the old or the new one). Returns the truth."""
    scratch = Scene([], {}, {}, {}, [], scene.start_epoch)
    truth = add_source_marker(
        scratch,
        move_times,
        steps_mm,
        name=marker.body,
        marker_id=marker.marker_id,
        position=marker.position,
        move_s=move_s,
        rate_cps=marker.rate_cps,
    )
    scene.bodies[marker.body].pose = scratch.bodies[marker.body].pose
    return truth
