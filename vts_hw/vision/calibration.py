"""The calibration of N ≥ 2 cameras into one frame from checkerboard views; the stereo pair is its
two-camera case.

:func:`calibrate_cameras` runs, in order:

1. the view graph (:class:`~vts_hw.vision.view_graph.ViewGraph`): every camera must share a view
   with another and the shared views must connect them all, else one sentence (DataError);
2. each camera's intrinsics from its own views, with OpenCV (:func:`fit_camera`:
   ``cv2.calibrateCamera`` and the lens model the data support, decision 0024);
3. the cameras' poses chained from the reference camera along the spanning tree of the view
   graph, each edge being the stereo calibration of its two cameras on the views they share
   (:func:`pair_pose`: ``cv2.stereoCalibrateExtended`` with the intrinsics fixed); each board
   pose from a camera that saw it;
4. one bundle adjustment of all intrinsics, camera poses and board poses
   (:func:`vts_hw.vision.bundle.adjust`, robust loss).

``intrinsics="fixed"`` keeps step 2's intrinsics in step 4; with a plain squared loss and two
cameras that is OpenCV's stereo fit itself, and the pair's uncertainty is propagated through the
two OpenCV fits (:func:`~vts_hw.vision.calibration_uncertainty.stereo_covariance`): what
:func:`calibrate_stereo` (``vts calibrate stereo``) runs, so that every stereo figure is plain
OpenCV's (decision 0012). The checkerboard itself: :mod:`vts_hw.vision.checkerboard`.
Choices and figures: docs/decisions/0012, 0024, 0030 and 0056.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import numpy as np

import vts_hw
from vts_hw.errors import DataError, UsageError
from vts_hw.vision import bundle
from vts_hw.vision.calibration_io import CameraCalibration, CameraFit, ViewFit
from vts_hw.vision.calibration_uncertainty import stereo_covariance
from vts_hw.vision.checkerboard import PATTERN, ImageOrPath, board_points, find_corners, load_gray
from vts_hw.vision.view_graph import ViewGraph

__all__ = ["CameraCalibration", "calibrate_cameras", "calibrate_from_corners", "calibrate_stereo", "fit_camera"]

MIN_PAIRS = 3  # pairs the stereo case needs
OUTLIER_FACTOR = 3.0  # a view whose RMS is above this x the median of the views is flagged
# Lens models: "opencv" is OpenCV's default (k1, k2, p1, p2, k3); "k1" fits the first radial
# term only. "auto" takes the one with the lower Bayesian information criterion (fit_camera).
DISTORTION = {
    "opencv": (0, ["k1", "k2", "p1", "p2", "k3"]),
    "k1": (cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST, ["k1"]),
}


def fit_camera(obj, corners, image_size, distortion: str = "auto"):
    """One camera's intrinsics: (rms, K, d, model, (rvecs, tvecs)) with cv2.calibrateCamera.

    `distortion` "opencv" fits OpenCV's default five coefficients, "k1" only the first radial
    term; "auto" fits both and keeps the one with the lower Bayesian information criterion
    (n ln(RSS/n) + p ln n over the n corner coordinates): a narrow lens whose corners stay near
    the image centre cannot tell k2, k3 and the tangential terms from the principal point and
    k1, and fitting them there moves the principal point by many pixels; a wide lens needs
    them (docs/decisions/0024). `model` says which terms were fitted and why.
    """
    if distortion not in ("auto", *DISTORTION):
        raise ValueError(f"distortion must be 'auto', 'k1' or 'opencv', not {distortion!r}")
    fits = {}
    for name in ("k1", "opencv") if distortion == "auto" else (distortion,):
        flags, fitted = DISTORTION[name]
        rms, K, d, rvecs, tvecs = cv2.calibrateCamera(obj, corners, image_size, None, None, flags=flags)
        fits[name] = (float(rms), K, d, fitted, (rvecs, tvecs))
    if distortion != "auto":
        rms, K, d, fitted, poses = fits[distortion]
        return rms, K, d, {"fitted": fitted, "chosen_by": f"asked for ({distortion})"}, poses
    n_obs = 2 * sum(len(c) for c in corners)  # coordinates
    bic = {}
    for name, (rms, _, _, fitted, _) in fits.items():
        n_par = 4 + len(fitted) + 6 * len(corners)
        bic[name] = n_obs * math.log(max(rms, 1e-300) ** 2 / 2) + n_par * math.log(n_obs)
    name = "opencv" if bic["opencv"] < bic["k1"] else "k1"
    rms, K, d, fitted, poses = fits[name]
    why = (
        "its lower residual outweighs 4 more terms"
        if name == "opencv"
        else "4 more terms do not lower the residual enough"
    )
    return (
        rms,
        K,
        d,
        {
            "fitted": fitted,
            "chosen_by": (
                f"auto (BIC): RMS {fits['opencv'][0]:.4f} px with k1, k2, p1, p2, k3 vs"
                f" {fits['k1'][0]:.4f} px with k1 alone, BIC {bic['opencv']:.1f} vs {bic['k1']:.1f}:"
                f" {why}"
            ),
        },
        poses,
    )


MIN_VIEWS = 3  # views a camera needs for its own intrinsics


def pair_pose(obj, corners_a, corners_b, Ka, da, Kb, db, image_size):
    """Camera b's pose from camera a's (x_b = R x_a + T) on views both saw, intrinsics fixed:
    (rms, R, T, per-view errors (n × 2), board rvecs, tvecs in camera a)."""
    out = cv2.stereoCalibrateExtended(
        obj, corners_a, corners_b, Ka, da, Kb, db, image_size, None, None, flags=cv2.CALIB_FIX_INTRINSIC
    )
    rms, R, T, per_view = out[0], out[5], out[6], out[-1]
    if len(out) >= 12:
        rvecs, tvecs = out[9], out[10]
    else:  # pragma: no cover - OpenCV < 4.6
        poses = [cv2.solvePnP(o, c, Ka, da)[1:] for o, c in zip(obj, corners_a)]
        rvecs, tvecs = [p[0] for p in poses], [p[1] for p in poses]
    return float(rms), R, np.ravel(T), np.asarray(per_view, float).reshape(-1, 2), rvecs, tvecs


def _rms(res: np.ndarray) -> float:
    """RMS of corner errors as OpenCV gives it: sqrt(mean of dx² + dy²) over the corners."""
    return float(np.sqrt(np.mean(np.sum(np.asarray(res).reshape(-1, 2) ** 2, axis=1))))


@dataclass
class Start:
    """Steps 1-3 done: the cameras (reference first), their own fits, the chained poses."""

    names: list[str]
    graph: ViewGraph
    board: np.ndarray  # the board's corners in its plane (n × 3)
    pts: dict[str, dict[str, np.ndarray]]  # camera → view → corners (n × 1 × 2 float32)
    own: dict[str, dict[str, Any]]  # camera → its own fit: rms, K, d, model, pose per view
    pose: dict[str, tuple[np.ndarray, np.ndarray]]  # camera → (R, t) in the reference frame
    board_in: dict[str, tuple[str, np.ndarray, np.ndarray]]  # view → (camera, rvec, tvec) to start from
    edges: list[dict[str, Any]]


def start(
    corners: Mapping[str, Mapping[str, np.ndarray]],
    image_sizes: Mapping[str, tuple[int, int]],
    pattern: tuple[int, int] = PATTERN,
    square: float = 1.0,
    distortion: str = "auto",
    reference: str | None = None,
) -> Start:
    """Steps 1-3 of the module docstring."""
    names = list(corners)
    if len(names) < 2:
        raise DataError(f"only {len(names)} camera(s) given; a camera calibration needs at least two.")
    if reference is not None:
        if reference not in corners:
            raise UsageError(
                f"the reference camera {reference!r} is not among the cameras of the images: {', '.join(names)}."
            )
        names.remove(reference)
        names.insert(0, reference)
    graph = ViewGraph(names, {c: list(corners[c]) for c in names})
    graph.check()
    obj1 = board_points(pattern, square)
    n_pts = len(obj1)
    pts = {c: {v: np.asarray(x, np.float32).reshape(-1, 1, 2) for v, x in corners[c].items()} for c in names}
    for c in names:
        for v, x in pts[c].items():
            if len(x) != n_pts:
                raise DataError(
                    f"camera {c}, view {v}: {len(x)} corners, the {pattern[0]}x{pattern[1]} board has {n_pts}."
                )
    own = {}
    for c in names:
        views = graph.seen[c]
        if len(views) < MIN_VIEWS:
            raise DataError(
                f"camera {c} found the board in only {len(views)} view(s); its intrinsics need at least {MIN_VIEWS}."
            )
        rms, K, d, model, (rvecs, tvecs) = fit_camera(
            [obj1] * len(views), [pts[c][v] for v in views], tuple(image_sizes[c]), distortion
        )
        own[c] = {
            "rms": rms,
            "K": K,
            "d": d,
            "model": model,
            "size": tuple(int(x) for x in image_sizes[c]),
            "pose": {v: (np.ravel(r), np.ravel(t)) for v, r, t in zip(views, rvecs, tvecs)},
            "rvecs": rvecs,
            "tvecs": tvecs,
        }
    pose = {names[0]: (np.eye(3), np.zeros(3))}
    edges: list[dict[str, Any]] = []
    board_in: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
    for a, b in graph.spanning_tree(names[0]):
        shared = graph.shared(a, b)
        rms, R, T, _, rvecs, tvecs = pair_pose(
            [obj1] * len(shared),
            [pts[a][v] for v in shared],
            [pts[b][v] for v in shared],
            own[a]["K"],
            own[a]["d"],
            own[b]["K"],
            own[b]["d"],
            own[a]["size"],
        )
        Ra, ta = pose[a]
        pose[b] = (R @ Ra, R @ ta + T)
        for v, r, t in zip(shared, rvecs, tvecs):
            board_in.setdefault(v, (a, np.ravel(r), np.ravel(t)))
        edges.append(
            {"from": a, "to": b, "shared_views": len(shared), "rms": rms, "distance": float(np.linalg.norm(T))}
        )
    for v in graph.views:  # a view on no edge of the tree: the pose its camera's own fit gave
        if v not in board_in:
            c = next(c for c in names if v in own[c]["pose"])
            board_in[v] = (c, *own[c]["pose"][v])
    return Start(names, graph, obj1, pts, own, pose, board_in, edges)


def adjust(st: Start, intrinsics: str = "refine", loss: str = bundle.LOSS):
    """Step 4: (problem, solution, observations as (camera index, view index))."""
    if intrinsics not in ("refine", "fixed"):
        raise ValueError(f"intrinsics must be 'refine' or 'fixed', not {intrinsics!r}")
    names, views = st.names, st.graph.views
    vpose = np.zeros((len(views), 6))
    for i, v in enumerate(views):
        c, r_bc, t_bc = st.board_in[v]
        Rc, tc = st.pose[c]
        Rw = Rc.T @ cv2.Rodrigues(r_bc)[0]
        vpose[i] = np.r_[cv2.Rodrigues(Rw)[0].ravel(), Rc.T @ (t_bc - tc)]
    obs = [(ci, vi) for vi, v in enumerate(views) for ci, c in enumerate(names) if v in st.pts[c]]
    problem = bundle.Problem(
        st.board,
        np.array([o[0] for o in obs], int),
        np.array([o[1] for o in obs], int),
        np.stack([st.pts[names[ci]][views[vi]].reshape(-1, 2) for ci, vi in obs]),
        len(names),
        len(views),
        [st.own[c]["model"]["fitted"] for c in names],
        reference=0,
        fix_intrinsics=intrinsics == "fixed",
    )
    intr = np.array(
        [
            [
                st.own[c]["K"][0, 0],
                st.own[c]["K"][1, 1],
                st.own[c]["K"][0, 2],
                st.own[c]["K"][1, 2],
                *np.r_[np.ravel(st.own[c]["d"]), np.zeros(5)][:5],
            ]
            for c in names
        ]
    )
    cpose = np.array([np.r_[cv2.Rodrigues(st.pose[c][0])[0].ravel(), st.pose[c][1]] for c in names])
    p0 = problem.pack(intr, cpose, vpose)
    # the robust loss takes over beyond what a corner finder's noise can explain: 5 sigma of the
    # worst camera's own fit (each camera's own views cannot be mispaired), at least F_SCALE_PX
    noise = max(float(st.own[c]["rms"]) for c in names) / np.sqrt(2)
    sol = bundle.adjust(problem, p0, loss=loss, f_scale=max(bundle.F_SCALE_PX, 5.0 * noise))
    sol.start_rms = _rms(problem.residuals(p0))
    return problem, sol, obs


def calibrate_cameras(
    corners: Mapping[str, Mapping[str, np.ndarray]],
    image_sizes: Mapping[str, tuple[int, int]],
    pattern: tuple[int, int] = PATTERN,
    square: float = 1.0,
    unit: str = "squares",
    distortion: str = "auto",
    reference: str | None = None,
    intrinsics: str = "refine",
    loss: str = bundle.LOSS,
    outlier_factor: float = OUTLIER_FACTOR,
    skipped: Mapping[str, str] | None = None,
) -> CameraCalibration:
    """Calibrate the cameras of ``corners`` (camera → view name → the board's inner corners found
    in that camera's image of that view) into the frame of ``reference`` (default the first
    camera). ``image_sizes``: camera → (width, height). ``intrinsics``: "refine" (in the bundle
    adjustment) or "fixed" (as each camera's own fit gave them); ``loss``: SciPy's robust loss
    ("cauchy", "soft_l1", "huber") or "linear". See the module docstring.

    With the intrinsics fixed, each camera's RMS is that of its own fit (where its intrinsics
    come from); and for two cameras that saw every view (the stereo case) the standard
    deviations are propagated through the two OpenCV fits and the pair's kept in ``pair``."""
    if unit == "squares" and square != 1.0:
        raise ValueError("with unit 'squares' the square size must be 1")
    st = start(corners, image_sizes, pattern, square, distortion, reference)
    problem, sol, obs = adjust(st, intrinsics, loss)
    names, views, own = st.names, st.graph.views, st.own
    intr, cpose, vpose = problem.unpack(sol.p)
    pair = None
    if intrinsics == "fixed" and len(names) == 2 and all(len(st.graph.seen[c]) == len(views) for c in names):
        sds, pair = _pair_uncertainty(st, cpose, vpose)
    else:
        sds = bundle.covariance(problem, sol)
    res = sol.residuals
    per_obs = np.sqrt(np.mean(np.sum(res**2, axis=2), axis=1))
    view_errors: dict[str, dict[str, float]] = {v: {} for v in views}
    for k, (ci, vi) in enumerate(obs):
        view_errors[views[vi]][names[ci]] = float(per_obs[k])
    fits_v = [ViewFit(v, view_errors[v]) for v in views]
    limit = outlier_factor * float(np.median([f.rms for f in fits_v]))
    fits_v = [ViewFit(f.name, f.errors, f.rms > limit) for f in fits_v]
    cam_fits = []
    for ci, c in enumerate(names):
        mine = [k for k, (cj, _) in enumerate(obs) if cj == ci]
        K = np.array([[intr[ci, 0], 0, intr[ci, 2]], [0, intr[ci, 1], intr[ci, 3]], [0, 0, 1.0]])
        model = dict(own[c]["model"], own_rms=own[c]["rms"])
        rms = own[c]["rms"] if intrinsics == "fixed" else _rms(res[mine])
        cam_fits.append(
            CameraFit(
                c,
                K,
                intr[ci, 4:9],
                cv2.Rodrigues(cpose[ci, :3])[0],
                cpose[ci, 3:],
                own[c]["size"],
                rms,
                len(mine),
                model,
                sds[ci] or None,
            )
        )
    rule = f"view RMS (every camera that saw it) > {outlier_factor:g} x median of the views"
    method = (
        f"per-camera OpenCV intrinsics, poses chained along the view graph from {names[0]},"
        f" one bundle adjustment ({'intrinsics refined' if intrinsics == 'refine' else 'intrinsics fixed'},"
        f" {loss} loss); {sol.nfev} evaluations: {sol.status}"
    )
    return CameraCalibration(
        cam_fits,
        (int(pattern[0]), int(pattern[1])),
        float(square),
        unit,
        _rms(res),
        fits_v,
        rule,
        view_graph=st.graph.data(),
        skipped=dict(skipped or {}),
        initial={"rms": sol.start_rms, "edges": st.edges, "own_rms": {c: own[c]["rms"] for c in names}},
        adjustment={"converged": sol.converged, "evaluations": sol.nfev, "status": sol.status},
        method=method,
        created=datetime.now(UTC).isoformat(timespec="seconds"),
        software=vts_hw.__version__,
        pair=pair,
    )


def _pair_uncertainty(st: Start, cpose: np.ndarray, vpose: np.ndarray):
    """({0: sd of camera 1, 1: sd of camera 2}, the pair's) for two cameras with their own
    intrinsics, through both OpenCV fits (decision 0024)."""
    a, b = st.names
    views = st.graph.views
    obj = [st.board] * len(views)
    rot, t = cv2.Rodrigues(cpose[1, :3])[0], cpose[1, 3:].reshape(3, 1)
    rvecs = [v[:3].reshape(3, 1) for v in vpose]  # board poses in camera 1 = the frame
    tvecs = [v[3:].reshape(3, 1) for v in vpose]
    cam_a, cam_b = (
        (st.own[c]["K"], st.own[c]["d"], st.own[c]["model"]["fitted"], st.own[c]["rvecs"], st.own[c]["tvecs"])
        for c in (a, b)
    )
    unc = stereo_covariance(
        obj, [st.pts[a][v] for v in views], [st.pts[b][v] for v in views], cam_a, cam_b, rot, t, rvecs, tvecs
    )
    return {0: unc["camera1"], 1: unc["camera2"]}, {"stereo": unc["stereo"], "stereo_cov": unc["stereo_cov"]}


# ---------------------------------------------------------------- the stereo pair: N = 2
def calibrate_stereo(
    pairs: Sequence[tuple[ImageOrPath, ImageOrPath]],
    pattern: tuple[int, int] = PATTERN,
    square: float = 1.0,
    unit: str = "squares",
    names: Sequence[str] | None = None,
    distortion: str = "auto",
    outlier_factor: float = OUTLIER_FACTOR,
    cameras: tuple[str, str] = ("left", "right"),
) -> CameraCalibration:
    """The two cameras ``cameras`` from (left, right) images or image paths: corners found, then
    :func:`calibrate_from_corners`. Pairs in which either image shows no board are skipped and
    listed in ``skipped``; ``names`` names the views (default from the file names: ``01`` for
    left01/right01). ``square`` is the side of a square in ``unit`` ("squares" with square=1 when
    it is unknown). ``distortion``: each camera's lens model, "auto", "k1" or "opencv" (:func:`fit_camera`).
    """
    if names is None:
        names = [_pair_name(i, left, right) for i, (left, right) in enumerate(pairs)]
    if len(names) != len(pairs):
        raise ValueError(f"{len(names)} names for {len(pairs)} pairs")
    left_corners, right_corners, kept, skipped = [], [], [], {}
    image_size = None
    for name, (left, right) in zip(names, pairs):
        gl, gr = load_gray(left), load_gray(right)
        for img, src in ((gl, left), (gr, right)):
            size = (img.shape[1], img.shape[0])
            if image_size is None:
                image_size = size
            elif size != image_size:
                raise DataError(
                    f"{_label(src, name)} is {size[0]}x{size[1]} px, the other images"
                    f" are {image_size[0]}x{image_size[1]} px."
                )
        cl, cr = find_corners(gl, pattern), find_corners(gr, pattern)
        if cl is None or cr is None:
            missing = " and ".join(s for s, c in (("left", cl), ("right", cr)) if c is None)
            skipped[name] = f"no {pattern[0]}x{pattern[1]} board found in the {missing} image"
            continue
        left_corners.append(cl)
        right_corners.append(cr)
        kept.append(name)
    if image_size is None:
        raise DataError("no image pairs given for the stereo calibration.")
    return calibrate_from_corners(
        left_corners,
        right_corners,
        image_size,
        names=kept,
        pattern=pattern,
        square=square,
        unit=unit,
        skipped=skipped,
        distortion=distortion,
        outlier_factor=outlier_factor,
        cameras=cameras,
    )


def calibrate_from_corners(
    left_corners: Sequence[np.ndarray],
    right_corners: Sequence[np.ndarray],
    image_size: tuple[int, int],
    names: Sequence[str] | None = None,
    pattern: tuple[int, int] = PATTERN,
    square: float = 1.0,
    unit: str = "squares",
    skipped: dict[str, str] | None = None,
    distortion: str = "auto",
    outlier_factor: float = OUTLIER_FACTOR,
    cameras: tuple[str, str] = ("left", "right"),
) -> CameraCalibration:
    """The stereo case of :func:`calibrate_cameras` from corners already found (one entry per
    usable pair): the intrinsics fixed at each camera's own OpenCV fit and a plain squared loss,
    which leaves OpenCV's stereo fit as it is (decision 0012)."""
    n = len(left_corners)
    if n != len(right_corners):
        raise ValueError("left and right corner lists differ in length")
    names = list(names) if names is not None else [f"pair{i + 1:02d}" for i in range(n)]
    if len(set(names)) != n:
        raise ValueError("the pairs' names must differ")
    if n < MIN_PAIRS:
        raise DataError(
            f"only {n} pair(s) show the board in both images; the stereo calibration needs at least {MIN_PAIRS}."
        )
    a, b = cameras
    corners = {a: dict(zip(names, left_corners)), b: dict(zip(names, right_corners))}
    return calibrate_cameras(
        corners,
        {a: image_size, b: image_size},
        pattern=pattern,
        square=square,
        unit=unit,
        distortion=distortion,
        intrinsics="fixed",
        loss="linear",
        outlier_factor=outlier_factor,
        skipped=skipped,
    )


def _pair_name(i: int, left: ImageOrPath, right: ImageOrPath) -> str:
    """'01' for left01.jpg/right01.jpg, else 'left-stem/right-stem', else 'pairNN'."""
    if isinstance(left, (str, Path)) and isinstance(right, (str, Path)):
        ls, rs = Path(left).stem, Path(right).stem
        if ls.lower().startswith("left") and rs.lower()[5:] == ls.lower()[4:] and ls[4:]:
            return ls[4:]
        return f"{ls}/{rs}"
    return f"pair{i + 1:02d}"


def _label(src: ImageOrPath, name: str) -> str:
    return str(src) if isinstance(src, (str, Path)) else f"an image of pair {name}"
