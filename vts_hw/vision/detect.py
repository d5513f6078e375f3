"""Marker detection: bright retro-reflective blobs in a grey image, with sub-pixel centroids.

Pixel convention (OpenCV): pixel centres at integer coordinates, ``x`` = column, ``y`` = row.

The pipeline costs a fraction of a JPEG decode (docs/decisions/0006-marker-detection.md):

1. **Threshold**: configured, or from a sparse sample of the frame (about 300 pixels): median
   plus ``max(k_sigma * robust sigma, min_contrast)`` -- a floor, so noise alone gives no blob.
2. **Candidates on a decimated view**: ``gray[::step, ::step]`` is thresholded and its outer
   contours found; each bounding box, scaled back, gives a square region of interest (ROI)
   surely holding the whole blob, ``roi_margin`` clear pixels and a one-pixel border ring.
3. **All ROIs at once, at full resolution**: the ROIs (one common size) are stacked as float
   rows; one product of their above-threshold masks with a constant matrix gives each
   candidate's area, second moments (roundness, size) and its pixels on the ROI's border
   ring, and one product of the ROIs with another gives the least-squares plane
   ``a + b·x + c·y`` through the border ring: the *local* background, which follows the
   shading of the wall.
4. **Centroid**: per candidate, one product of its ROI with a cached matrix gives
   Σ w·(I − B), Σ w·x·(I − B), Σ w·y·(I − B) over a circular window ``w`` -- centred on the
   pixel nearest the mask centroid, radius twice the major standard deviation (a uniform
   disk's radius) plus ``window_pad``, so that the whole anti-aliased edge is in, not just the
   thresholded pixels. The plane ``B`` is linear in the ROI, so its subtraction is folded into
   the cached matrix. Values below the background are kept, not clipped (clipping biases the
   centroid toward the window centre; measured in 0006).

A candidate whose ROI may hold part of another candidate is measured alone: its own
connected pixels, grown by ``window_pad``, with the others' masked out. Rejected candidates
come back with a reason: ``"border"`` (cut by the image edge), ``"crowded"``, ``"truncated"``
(the blob reaches its background ring), ``"area"``, ``"contrast"`` (nothing above the local
background), ``"roundness"``, ``"too many"``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from operator import attrgetter

import cv2
import numpy as np

NAN = float("nan")
_BY_Y_X = attrgetter("y", "x")


@dataclass(frozen=True)
class Blob:
    """One bright blob.

    ``x, y``: intensity-weighted centroid (px) after local background subtraction. ``area``:
    pixels above the threshold. ``peak``: maximum grey level above the local background.
    ``roundness``: minor/major axis ratio from the second moments of the above-threshold
    pixels (1 = circle). ``sum``: background-subtracted grey-level sum over the window.
    """

    x: float
    y: float
    area: int
    peak: float
    roundness: float
    sum: float


@dataclass(frozen=True)
class DetectorSettings:
    """Detection parameters. The defaults suit the reference rig: 25 mm wall disks (about
    20 px), 13 mm spheres (about 12 px), background about 20 and markers about 220 grey levels.

    ``threshold``: grey level, a pixel counts when above it; ``None`` = automatic,
    ``median + max(k_sigma * sigma, min_contrast)`` (at most ``max_threshold``), ``sigma`` =
    median minus 16th percentile of a sample of the frame. ``step``: decimation of the
    candidate search; every blob at least ``1.5 * step`` px across is found (a disk's inscribed
    square then holds a sample). ``roi_margin``: clear pixels between a blob's extent and its
    background ring. ``window_pad``: centroid window radius beyond the blob's edge (px).
    ``max_candidates``: beyond this many (a natural scene, not a marker frame) candidates are
    rejected unmeasured as ``"too many"``.
    """

    threshold: float | None = None
    min_area: int = 12
    max_area: int = 5000
    min_roundness: float = 0.6
    roi_margin: int = 3
    k_sigma: float = 8.0
    min_contrast: float = 40.0
    max_threshold: float = 250.0
    step: int = 5
    window_pad: float = 2.5
    max_candidates: int = 100

    def __post_init__(self):
        if self.step < 1 or self.roi_margin < 0 or self.window_pad < 0 or self.max_candidates < 0:
            raise ValueError(f"invalid detector settings: {self}")


@dataclass
class DetectionResult:
    """``blobs``: accepted, sorted by y then x. ``threshold``: the grey level used.
    ``background``: median grey level of the frame (sampled). ``rejected``: ``(blob, reason)``
    for every candidate filtered out (unmeasured ones have NaN roundness and sum)."""

    blobs: list[Blob]
    threshold: float
    background: float
    rejected: list[tuple[Blob, str]] = field(default_factory=list)


DEFAULT = DetectorSettings()


# ---------------------------------------------------------------- threshold
def auto_threshold(gray: np.ndarray, settings: DetectorSettings = DEFAULT) -> tuple[float, float]:
    """``(threshold, median)`` as :func:`detect` chooses them: from about 300 pixels on a
    regular grid of the decimated view ``gray[::step, ::step]``."""
    small = gray[:: settings.step, :: settings.step]
    return _threshold(small, max(1, int(math.sqrt(small.size / 300.0))), settings)


def _threshold(img: np.ndarray, stride: int, s: DetectorSettings) -> tuple[float, float]:
    """``(threshold, median)`` from ``img[::stride, ::stride]``: median plus
    ``max(k_sigma * (median - 16th percentile), min_contrast)``, floored to a whole grey level
    (so that ``pixel > threshold`` means the same for OpenCV and numpy)."""
    # A radix sort (numpy's stable sort of 8-bit data) is cheaper here than a partition.
    ranked = img[stride // 2 :: stride, stride // 2 :: stride].flatten()
    ranked.sort(kind="stable")
    n = ranked.size - 1
    median = ranked.item(n // 2)  # Python ints: no numpy scalar arithmetic below
    thr = median + max(s.k_sigma * max(median - ranked.item(n * 16 // 100), 1), s.min_contrast)
    median = float(median)
    return float(min(math.floor(thr), s.max_threshold)), median


# ---------------------------------------------------------------- entry points
def detect(gray: np.ndarray, settings: DetectorSettings = DEFAULT) -> DetectionResult:
    """Find the bright round blobs of a uint8 (H, W) image (see the module docstring)."""
    thr, median, boxes = candidate_boxes(gray, settings)
    result = DetectionResult([], thr, median)
    if boxes:
        _measure(gray, boxes, thr, settings, result)
        result.blobs.sort(key=_BY_Y_X)
    return result


def candidate_boxes(gray: np.ndarray, settings: DetectorSettings = DEFAULT) -> tuple[float, float, list[Sequence[int]]]:
    """Steps 1 and 2 of :func:`detect` alone: ``(threshold, median, boxes)``, ``boxes`` the
    bounding boxes ``(x, y, w, h)`` of the above-threshold regions of the decimated view, in
    its samples. (bench/detect_speed.py times it: the floor under any measuring step.)"""
    if not isinstance(gray, np.ndarray) or gray.dtype.char != "B" or gray.ndim != 2:
        raise ValueError(
            "detect needs a grey uint8 image (H x W), got "
            f"{getattr(gray, 'dtype', type(gray).__name__)} "
            f"{getattr(gray, 'shape', '')}"
        )
    step = settings.step
    small = gray[::step, ::step].copy()  # contiguous, for OpenCV
    # The threshold's sample: about 300 pixels, taken from the decimated view.
    thr, median = _threshold(small, max(1, int(math.sqrt(small.size / 300.0))), settings)
    if settings.threshold is not None:
        thr = float(settings.threshold)
    binary = cv2.threshold(small, thr, 255, cv2.THRESH_BINARY)[1]
    contours = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)[0]
    return thr, median, list(map(cv2.boundingRect, contours))


def detect_jpeg(jpeg: bytes, settings: DetectorSettings = DEFAULT) -> DetectionResult:
    """Decode a JPEG to grey at full resolution and :func:`detect` in it."""
    gray = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    if gray is None:
        raise ValueError("not a decodable JPEG")
    return detect(gray, settings)


# ---------------------------------------------------------------- candidates -> ROIs
def _measure(gray, boxes, thr, s: DetectorSettings, result: DetectionResult) -> None:
    """Turn decimated bounding boxes ``(x, y, w, h)`` into measured, filtered blobs."""
    H, W = gray.shape
    step = s.step
    if len(boxes) > s.max_candidates:
        for b in boxes[s.max_candidates :]:
            result.rejected.append((_coarse(gray, b, step), "too many"))
        boxes = boxes[: s.max_candidates]
    # A candidate's samples bx..bx+bw-1 hold its pixels above the threshold, which therefore
    # lie within (bx-1)*step+1 .. (bx+bw)*step-1; its anti-aliased edge adds one pixel: its
    # "extent" is (bx-1)*step .. (bx+bw)*step. The ROI adds roi_margin clear pixels and the
    # ring; its size is common to all candidates (the largest needed).
    lim = (min(H, W) - 2 * s.roi_margin - 3) // step - 1
    cells = 4 * s.max_area // (step * step)
    kept = []
    big = 0
    for b in boxes:
        bw, bh = b[2], b[3]
        if bw > lim or bh > lim or bw * bh > cells:
            result.rejected.append((_coarse(gray, b, step), "area"))
            continue
        kept.append(b)
        if bw > big:
            big = bw
        if bh > big:
            big = bh
    if not kept:
        return
    need = (big + 1) * step // 2 + 1 + s.roi_margin
    size = 2 * need + 1
    xmax, ymax = W - size, H - size
    rois = []
    for bx, by, bw, bh in kept:  # centred on the extent, moved inside the image if need be
        ox, oy = (2 * bx + bw - 1) * step // 2 - need, (2 * by + bh - 1) * step // 2 - need
        rois.append((0 if ox < 0 else xmax if ox > xmax else ox, 0 if oy < 0 else ymax if oy > ymax else oy))
    crowded = _crowded(rois, size - 2 - s.roi_margin) if len(rois) > 1 else ()
    _measure_batch(gray, [r for i, r in enumerate(rois) if i not in crowded] if crowded else rois, size, thr, s, result)
    for i in sorted(crowded):
        bx, by, bw, bh = kept[i]
        extent = ((bx - 1) * step, (by - 1) * step, (bx + bw) * step, (by + bh) * step)
        _measure_alone(gray, extent, step, thr, s, result)


def _crowded(rois, near) -> set[int]:
    """Candidates whose ROI may hold part of another candidate: ROI origins closer than
    ``near`` in both x and y (a candidate's extent lies at least roi_margin + 1 px inside its
    ROI, so farther ROIs cannot reach it). A sweep in x."""
    out = set()
    order = sorted([(x, y, i) for i, (x, y) in enumerate(rois)])
    for a, (rx, ry, i) in enumerate(order):
        for qx, qy, j in order[a + 1 :]:
            if qx - rx > near:
                break
            if -near <= qy - ry <= near:
                out.add(i)
                out.add(j)
    return out


def _coarse(gray, box, step) -> Blob:
    """A rough blob from the decimated view only, for candidates not worth measuring."""
    x, y, w, h = box
    patch = gray[y * step : (y + h) * step : step, x * step : (x + w) * step : step]
    return Blob(
        float((x + (w - 1) / 2) * step),
        float((y + (h - 1) / 2) * step),
        int(w * h * step * step),
        float(patch.max()),
        NAN,
        NAN,
    )


# ---------------------------------------------------------------- measurement
@lru_cache(maxsize=32)
def _kernels(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Constant float32 matrices of a square ROI of ``size`` (coordinates relative to its
    centre): ``Q`` (7, size²), rows 1, x, y, x², xy, y², ring -- applied to an above-threshold
    mask: area, moments, pixels on the border ring; ``P`` (3, size²), applied to the ROI:
    ``a, b, c`` of the least-squares plane ``a + b·x + c·y`` through the border ring."""
    c = (size - 1) / 2.0
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64) - c
    x, y = xx.ravel(), yy.ravel()
    ones = np.ones_like(x)
    ring = ((np.abs(xx) == c) | (np.abs(yy) == c)).ravel()
    P = np.zeros((3, size * size))
    P[:, ring] = np.linalg.pinv(np.stack([ones, x, y], axis=1)[ring])
    Q = np.stack([ones, x, y, x * x, x * y, y * y, ring.astype(float)])
    return Q.astype(np.float32), P.astype(np.float32)


_WINDOWS: dict = {}


def _window(size: int, diameter: int, dx: int, dy: int) -> np.ndarray:
    """The (3, size²) float32 measuring matrix of a circular window, ``diameter`` px across,
    centred ``(dx, dy)`` from the centre of a ``size``² ROI (the pixels whose centres are
    inside), in ROI-centred coordinates: ``M @ roi`` = Σ w·(I − B), Σ w·x·(I − B),
    Σ w·y·(I − B), the window sums of the ROI minus its ring plane ``B = a + b·x + c·y``.
    (``a, b, c`` are linear in the ROI, so the background subtraction folds into the matrix.)
    Cached: the keys repeat from frame to frame."""
    key = (size, diameter, dx, dy)
    hit = _WINDOWS.get(key)
    if hit is not None:
        return hit
    c = (size - 1) / 2.0
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64) - c
    x, y = xx.ravel(), yy.ravel()
    w = ((x - dx) ** 2 + (y - dy) ** 2 <= diameter * diameter / 4.0).astype(np.float64)
    P = _kernels(size)[1].astype(np.float64)
    rows = [w * v - sum((w * v * u).sum() * p for u, p in zip((1.0, x, y), P)) for v in (1.0, x, y)]
    hit = np.vstack(rows).astype(np.float32)
    if len(_WINDOWS) >= 512:  # bounded (a few MB): forget everything (rare; rebuilt as needed)
        _WINDOWS.clear()
    _WINDOWS[key] = hit
    return hit


def _shape(n, sx, sy, sxx, sxy, syy) -> tuple[float, float]:
    """``(roundness, major variance)`` of ``n`` pixels from their moment sums; roundness is the
    minor/major axis ratio (each pixel's own 1/12 variance keeps a line from being 0/0)."""
    mx, my = sx / n, sy / n
    a, b, c = sxx / n - mx * mx + 1 / 12, sxy / n - mx * my, syy / n - my * my + 1 / 12
    root = math.sqrt(0.25 * (a - c) ** 2 + b * b)
    lmax = 0.5 * (a + c) + root
    return math.sqrt(max(0.5 * (a + c) - root, 0.0) / lmax), lmax


def _reason(area, total, roundness, s: DetectorSettings) -> str:
    """Why a measured, complete candidate is not a marker, or "" (it is one)."""
    if area < s.min_area or area > s.max_area:
        return "area"
    if not total > 0:
        return "contrast"
    if roundness < s.min_roundness:
        return "roundness"
    return ""


def _measure_batch(gray, rois, size, thr, s: DetectorSettings, result: DetectionResult) -> None:
    """Measure the candidates whose ROIs (``size``², origins ``rois``) hold only themselves."""
    H, W = gray.shape
    n = len(rois)
    if not n:
        return
    f = np.empty((n, size, size), np.float32)
    for k, (ox, oy) in enumerate(rois):
        f[k] = gray[oy : oy + size, ox : ox + size]
    f = f.reshape(n, -1)
    Q, P = _kernels(size)
    above = cv2.threshold(f, thr, 1.0, cv2.THRESH_BINARY)[1]
    n0, nx, ny, nxx, nxy, nyy, nring = Q.dot(above.T).tolist()
    pa, pb, pc = P.dot(f.T).tolist()
    peaks = np.maximum.reduce(f, axis=1).tolist()
    c0 = (size - 1) / 2.0
    pad2 = 2.0 * s.window_pad + 1.0  # + 1: int() below rounds the diameter up
    min_area, max_area, min_round = s.min_area, s.max_area, s.min_roundness
    sqrt, floor, windows, new = math.sqrt, math.floor, _WINDOWS, object.__new__
    for k, (ox, oy) in enumerate(rois):
        area = n0[k]
        if area < 0.5:  # cannot happen with the candidate's own threshold; be safe
            result.rejected.append((Blob(ox + c0, oy + c0, 0, NAN, NAN, NAN), "contrast"))
            continue
        # The above-threshold pixels: centroid, covariance (+1/12 on the diagonal: a pixel's
        # own extent, so that a line is not 0/0), twice the principal variances (h +- r).
        mx, my = nx[k] / area, ny[k] / area
        vxx = nxx[k] / area - mx * mx + 1 / 12
        vyy = nyy[k] / area - my * my + 1 / 12
        vxy = nxy[k] / area - mx * my
        h, r = vxx + vyy, sqrt((vxx - vyy) ** 2 + 4.0 * vxy * vxy)
        rnd = sqrt((h - r) / (h + r)) if h > r else 0.0  # minor / major axis
        # Window: centred on the pixel nearest the mask centroid; radius 2 x the major
        # standard deviation (a uniform disk's radius) + window_pad.
        key = (size, int(sqrt(8.0 * (h + r)) + pad2), floor(mx + 0.5), floor(my + 0.5))
        M = windows.get(key)
        total, sx, sy = (_window(*key) if M is None else M).dot(f[k]).tolist()
        a, b, c = pa[k], pb[k], pc[k]
        x, y = (sx / total, sy / total) if total > 0 else (mx, my)
        area = int(area + 0.5)
        # Blob(...) without the frozen dataclass's __init__ (six object.__setattr__ calls, a
        # measurable share of the time budget): the same object, built directly.
        blob = new(Blob)
        blob.__dict__.update(
            x=ox + c0 + x, y=oy + c0 + y, area=area, peak=peaks[k] - (a + b * x + c * y), roundness=rnd, sum=total
        )
        if nring[k] > 0:
            edge = ox == 0 or oy == 0 or ox + size == W or oy + size == H
            result.rejected.append((blob, "border" if edge else "truncated"))
        elif min_area <= area <= max_area and total > 0 and rnd >= min_round:
            result.blobs.append(blob)
        else:
            result.rejected.append((blob, _reason(area, total, rnd, s)))


def _measure_alone(gray, e, step, thr, s: DetectorSettings, result: DetectionResult) -> None:
    """Slow path for a crowded candidate (extent ``e``): its own ROI, in which the
    above-threshold pixels are labelled; the window is this candidate's component grown by
    ``window_pad``, minus the other components grown alike; the background plane is fitted to
    the ROI's border pixels outside all of them. Same quantities as the batch."""
    H, W = gray.shape
    m = s.roi_margin + 1
    xa, ya, xb, yb = max(e[0] - m, 0), max(e[1] - m, 0), min(e[2] + m, W - 1), min(e[3] + m, H - 1)
    roi = gray[ya : yb + 1, xa : xb + 1].astype(np.float64)
    yy, xx = np.mgrid[ya : yb + 1, xa : xb + 1]
    count, labels = cv2.connectedComponents((roi > thr).astype(np.uint8), connectivity=8)
    # This candidate's component: the one with most pixels among its own samples' box.
    own_box = labels[e[1] + step - ya : e[3] - step - ya + 1, e[0] + step - xa : e[2] - step - xa + 1]
    votes = np.bincount(own_box.ravel(), minlength=count)
    votes[0] = 0
    own = int(votes.argmax())
    cx, cy = (xa + xb) / 2.0, (ya + yb) / 2.0
    if votes[own] == 0:
        result.rejected.append((Blob(cx, cy, 0, float(roi.max()), NAN, NAN), "crowded"))
        return
    r = max(int(math.ceil(s.window_pad)), 1)
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    mine = labels == own
    near_mine = cv2.dilate(mine.astype(np.uint8), disk) > 0
    others = cv2.dilate(((labels > 0) & ~mine).astype(np.uint8), disk) > 0
    border = (xx == xa) | (xx == xb) | (yy == ya) | (yy == yb)
    ring = border & ~near_mine & ~others
    area = int(mine.sum())
    px, py = xx[mine] - cx, yy[mine] - cy
    rnd, _ = _shape(area, px.sum(), py.sum(), (px * px).sum(), (px * py).sum(), (py * py).sum())
    if int(ring.sum()) < 8:
        result.rejected.append((Blob(cx + px.mean(), cy + py.mean(), area, float(roi.max()), rnd, NAN), "crowded"))
        return
    basis = np.stack([np.ones(int(ring.sum())), xx[ring] - cx, yy[ring] - cy], axis=1)
    a, b, c = np.linalg.lstsq(basis, roi[ring], rcond=None)[0]
    w = np.where(near_mine & ~others, roi - (a + b * (xx - cx) + c * (yy - cy)), 0.0)
    total = float(w.sum())
    if total > 0:
        x, y = float((w * xx).sum() / total), float((w * yy).sum() / total)
    else:
        x, y = cx + px.mean(), cy + py.mean()
    on_edge = bool((mine & ((xx == 0) | (yy == 0) | (xx == W - 1) | (yy == H - 1))).any())
    reason = "border" if on_edge else "crowded" if (mine & border).any() else _reason(area, total, rnd, s)
    blob = Blob(x, y, area, float(w[mine].max()), rnd, total)
    if reason:
        result.rejected.append((blob, reason))
    else:
        result.blobs.append(blob)
