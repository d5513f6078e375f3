"""Find a known rigid body (the 7-sphere phantom) among the points the VTS sees.

The stereo VTS sees more than the phantom: the wall markers behind the gantry, and, with two
cameras, pairings that the epipolar constraint alone cannot decide (two spheres near one
epipolar line). The SPECT sees only the hot spheres. So the phantom is found by its shape:

* :func:`candidate_points` triangulates *every* pairing of a detection in camera A with a
  detection in camera B that the epipolar constraint allows (ambiguous ones included): each is
  a hypothesis, a 3D point with the two detections it came from.
* :func:`find_body` looks for the template's shape (for instance the SPECT centroids at the same
  table position, in their own frame) among those hypotheses: every ordered triple of points
  whose distances match a well-spread triple of the template within ``tol_mm`` gives a rigid
  fit; the fit that brings the most template points onto a hypothesis wins. A detection used by
  two spheres, or a second fit as good as the best with another assignment, is an error, not a
  guess. The procedures need the body whole; ``min_points`` lets a caller that only names what
  it sees (the console's phantom locator, vision/phantom_locator.py) accept fewer.

Distances are in mm; a wrong pairing of two spheres on one epipolar line lands centimetres away
in depth, far outside the tolerance, so shape decides what the epipolar constraint could not.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from vts_hw.errors import DataError
from vts_hw.vision.multiview import ViewGeometry, match_views
from vts_hw.vision.registration import RigidTransform, kabsch
from vts_hw.vision.triangulate import epipolar_distances, triangulate

__all__ = ["Hypotheses", "BodyFit", "candidate_points", "find_body", "locate_body", "locate_body_views"]

DEFAULT_TOL_MM = 3.0


@dataclass(frozen=True)
class Hypotheses:
    """3D points from every epipolar-allowed pairing: ``points[k]`` from detection
    ``pairs[k][0]`` of camera A and ``pairs[k][1]`` of camera B (reprojection RMS ``rms_px``)."""

    points: np.ndarray  # (K, 3) mm, in the cameras' world frame
    pairs: np.ndarray  # (K, 2) int
    rms_px: np.ndarray  # (K,)


@dataclass(frozen=True)
class BodyFit:
    """The template found: ``points[i]`` is template point ``i`` as seen (``index[i]`` into
    the searched points; -1 and NaN for a point not seen, only with ``min_points``);
    ``transform`` takes template coordinates onto them; ``detections[i]``: per camera, the
    detection that made point ``i`` (-1: none; set by :func:`locate_body`/:func:`locate_body_views`)."""

    points: np.ndarray  # (M, 3)
    index: np.ndarray  # (M,) int
    transform: RigidTransform
    rms_mm: float  # RMS distance template (moved) -> found points
    candidates_tried: int
    detections: np.ndarray | None = None  # (M, n_cameras) int

    @property
    def found(self) -> int:
        """How many template points were seen."""
        return int(np.sum(np.asarray(self.index) >= 0))


def candidate_points(cams: Sequence, pts_a, pts_b, max_px: float = 2.0) -> Hypotheses:
    """Triangulate every pairing (i in A, j in B) whose symmetric epipolar distance is below
    ``max_px`` (the detections' pixels, distortion included)."""
    a = np.asarray(pts_a, float).reshape(-1, 2)
    b = np.asarray(pts_b, float).reshape(-1, 2)
    if len(a) == 0 or len(b) == 0:
        return Hypotheses(np.zeros((0, 3)), np.zeros((0, 2), int), np.zeros(0))
    d = epipolar_distances(cams[0], a, cams[1], b)
    ii, jj = np.nonzero(d < max_px)
    if len(ii) == 0:
        return Hypotheses(np.zeros((0, 3)), np.zeros((0, 2), int), np.zeros(0))
    tri = triangulate(list(cams[:2]), [a[ii], b[jj]])
    return Hypotheses(np.asarray(tri.points), np.stack([ii, jj], axis=1), np.asarray(tri.rms_px))


def _anchors(template: np.ndarray, spread: float = 0.2) -> list[tuple[int, int, int]]:
    """Every template triple whose triangle is at least ``spread`` of the largest one's area,
    largest first (the first: the best conditioned fit from 3 points; equal areas in the
    order of the points)."""
    tri = []
    for i, j, k in itertools.combinations(range(len(template)), 3):
        tri.append((0.5 * np.linalg.norm(np.cross(template[j] - template[i], template[k] - template[i])), (i, j, k)))
    tri.sort(key=lambda t: -t[0])  # stable: a tie keeps the combinations' order
    return [t for area, t in tri if area >= spread * tri[0][0]]


def find_body(
    points, template, tol_mm: float = DEFAULT_TOL_MM, exclusive: np.ndarray | None = None, min_points: int | None = None
) -> BodyFit:
    """Where the rigid ``template`` (M×3) lies among ``points`` (N×3, N ≥ M).

    ``exclusive`` (N×k ints, optional) names what each point is made of (e.g. the two
    detections of a stereo hypothesis): two template points may not share any of it.
    ``min_points`` (3..M, default M: the body whole): the fewest template points that must be
    seen; the ones not seen have index -1 and NaN coordinates.
    Raises :class:`DataError` when fewer than that are found within ``tol_mm``, or when
    two different assignments fit as many points equally well.
    """
    pts = np.asarray(points, float).reshape(-1, 3)
    tpl = np.asarray(template, float).reshape(-1, 3)
    m = len(tpl)
    if m < 3:
        raise DataError(f"a body needs at least 3 points to be found, the template has {m}.")
    need = m if min_points is None else min(m, max(3, int(min_points)))
    if len(pts) < need:
        raise DataError(f"only {len(pts)} point(s) seen, the body has {m}.")
    # the whole body: its best-spread triple is seen; a part of it: any well-spread triple may be the one seen
    anchors = _anchors(tpl)[:1] if need == m else _anchors(tpl)
    dist = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=-1)
    assignments: set[tuple] = set()  # template point -> point index (-1: not found)
    tried = 0
    for a, b, c in anchors:
        dab, dac, dbc = (np.linalg.norm(tpl[p] - tpl[q]) for p, q in ((a, b), (a, c), (b, c)))
        for i, j in zip(*np.nonzero(np.abs(dist - dab) < tol_mm)):
            if i == j:
                continue
            ks = np.nonzero((np.abs(dist[i] - dac) < tol_mm) & (np.abs(dist[j] - dbc) < tol_mm))[0]
            for k in ks:
                if k in (i, j):
                    continue
                tried += 1
                moved = kabsch(tpl[[a, b, c]], pts[[i, j, k]]).apply(tpl)
                dd = np.linalg.norm(moved[:, None, :] - pts[None, :, :], axis=-1)
                near = np.argmin(dd, axis=1)
                ok = dd[np.arange(m), near] < tol_mm
                if ok.sum() >= 3:
                    assignments.add(tuple(int(x) for x in np.where(ok, near, -1)))
    if not assignments:
        raise DataError(
            f"the {m}-point body was not found among the {len(pts)} points seen "
            f"(no three of them match its shape within {tol_mm:g} mm)."
        )
    # refit each distinct assignment on all its points, then rank: most points, then best fit
    ranked: dict[tuple, tuple[int, float, RigidTransform]] = {}
    for assign in assignments:
        sel = np.array([i for i, p in enumerate(assign) if p >= 0])
        idx = np.array([assign[i] for i in sel])
        tr = kabsch(tpl[sel], pts[idx])
        rms = float(np.sqrt(np.mean(np.sum((tr.apply(tpl[sel]) - pts[idx]) ** 2, axis=1))))
        ranked[assign] = (len(sel), rms, tr)
    order = sorted(ranked.items(), key=lambda kv: (-kv[1][0], kv[1][1]))
    assign, (n_in, rms, tr) = order[0]
    if n_in < need:
        missing = [str(i + 1) for i, p in enumerate(assign) if p < 0]
        raise DataError(
            f"the body was found with {n_in} of its {m} points: point(s) "
            f"{', '.join(missing)} not seen within {tol_mm:g} mm of where they belong."
        )
    idx = np.array(assign, int)
    seen = idx[idx >= 0]
    if len(set(seen.tolist())) < n_in or (exclusive is not None and _shares(exclusive, seen)):
        raise DataError(
            "two points of the body were matched to the same detection: the view is ambiguous at this position."
        )
    for other, (n2, rms2, _) in order[1:]:
        oth = np.array(other, int)
        if (
            n2 == n_in
            and other != assign
            and rms2 < max(2.0 * rms, 0.5 * tol_mm)
            and not (exclusive is not None and _shares(exclusive, oth[oth >= 0]))
        ):
            raise DataError(
                f"the body fits two ways among the points seen (RMS {rms:.2f} and "
                f"{rms2:.2f} mm): ambiguous, not guessed."
            )
    found = np.where(idx[:, None] >= 0, pts[np.maximum(idx, 0)], np.nan)
    return BodyFit(found, idx, tr, rms, tried)


def _shares(exclusive: np.ndarray, idx: np.ndarray) -> bool:
    ex = np.asarray(exclusive)[idx]
    for col in range(ex.shape[1]):
        if len(set(ex[:, col].tolist())) < len(idx):
            return True
    return False


def locate_body(
    cams: Sequence,
    pts_a,
    pts_b,
    template,
    tol_mm: float = DEFAULT_TOL_MM,
    max_px: float = 2.0,
    min_points: int | None = None,
) -> BodyFit:
    """The body ``template`` seen by a stereo pair: :func:`candidate_points` then
    :func:`find_body`, no detection used twice."""
    hyp = candidate_points(cams, pts_a, pts_b, max_px)
    fit = find_body(hyp.points, template, tol_mm, exclusive=hyp.pairs, min_points=min_points)
    return _with_detections(fit, hyp.pairs)


def _with_detections(fit: BodyFit, made_of: np.ndarray) -> BodyFit:
    """``fit`` with each template point's detections per camera (-1 for a point not seen)."""
    made_of = np.asarray(made_of, int)
    det = np.where(fit.index[:, None] >= 0, made_of[np.maximum(fit.index, 0)], -1)
    return replace(fit, detections=det)


def locate_body_views(
    cams: Sequence,
    pts: Sequence,
    template,
    tol_mm: float = DEFAULT_TOL_MM,
    max_px: float = 2.0,
    min_points: int | None = None,
) -> BodyFit:
    """The body ``template`` seen by N cameras (``pts``: each camera's detections): with two,
    :func:`locate_body`; with more, the points :func:`vts_hw.vision.multiview.match_views`
    makes from every camera that sees each marker (pairs one pair cannot tell apart are settled
    by the others; what stays ambiguous is withheld), then :func:`find_body`, no detection
    used twice."""
    if len(cams) == 2:
        return locate_body(cams, pts[0], pts[1], template, tol_mm, max_px, min_points)

    m = match_views(ViewGeometry(cams), [np.asarray(p, float).reshape(-1, 2) for p in pts], max_px)
    det = np.array([p.detections for p in m.points], int).reshape(-1, len(cams))
    # a camera a point does not use is no resource it holds: a unique filler per point
    exclusive = np.where(det >= 0, det, -1 - np.arange(len(det))[:, None])
    return _with_detections(find_body(m.xyz, template, tol_mm, exclusive=exclusive, min_points=min_points), det)
