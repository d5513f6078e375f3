"""What each simulated camera sees: a grey 640x480 image of the scene, and its colour JPEG.

A marker's outline is the exact projection of a 3D circle (a disk's rim, or the circle where
the viewing cone touches a sphere) through the full camera model, distortion and drift
included: ``outline_points`` points of the circle go through :func:`cv2.projectPoints`, and the
convex polygon they form is rasterised by :func:`polygon_coverage` -- the exact covered length
of each of ``supersample`` sub-rows per pixel row, i.e. exact area in x and supersampled in y.
Disks are uniformly bright; spheres have a soft radial profile made of concentric outlines
scaled about the outline's centroid (which keeps the centroid where it is).

Motion blur: each camera exposes for ``exposure[cam]`` seconds (default 8 ms; the simulated
Axis camera's profile sets it), centred on the frame's instant ``t``. A marker whose projected
centre moves more than ``blur_min_px`` over the exposure is drawn as the mean of its outline at
``blur_steps`` sub-instants spread evenly over it (so its centroid is where it was at ``t``, to
first order); markers that move less are drawn once, as without blur, so a static scene
renders exactly as it would with no exposure at all and stays cached. Only bodies that move
continuously (the patient) are smeared: scheduled poses and table positions change in steps,
at an instant, and are drawn as they are at ``t``.

Focus: ``focus[cam]`` is the lens's defocus, the standard deviation (px) of a Gaussian blur of
the marker light (sim_devices/optics.py); 0 (the default) draws the markers sharp at no cost.

Speed: the noise-free image (float32, not yet quantised) is cached per camera, keyed by the
LED state, every marker's projected centre rounded to 1e-3 px, and the table/body poses, so a
static scene is rasterised once. Noise comes from a bank of precomputed float32 frames, taken
at a random bank index and a random row/column offset, and added by one OpenCV call that also
rounds and clips to uint8 -- so quantisation happens after the noise, as in a real sensor.

JPEG: as a real Axis camera sends it, 3-component YCbCr with 4:2:0 chroma (:func:`encode`).
The grey image becomes the luma; blue and red are lifted and lowered by a few levels on the dim
background and meet at white on the LED-lit markers, so the background is slightly coloured and
the markers white, and the decoded luma is the grey image (``cv2.IMREAD_GRAYSCALE`` gives it
back, and skips the chroma work).
"""

from __future__ import annotations

import random
import threading
from collections import OrderedDict
from typing import Any

import cv2
import numpy as np

from vts_hw.sim_devices.scene import Marker, Scene, Schedule

# Sphere brightness profile: (scale of the outline, weight); weights sum to 1, so the centre
# is at full level and the rim at 0.35 of it.
SPHERE_RINGS = ((1.0, 0.35), (0.85, 0.13), (0.7, 0.13), (0.55, 0.13), (0.4, 0.13), (0.25, 0.13))
DISK_RINGS = ((1.0, 1.0),)


def polygon_centroid(poly: np.ndarray) -> np.ndarray:
    """Area centroid of a simple polygon (Nx2)."""
    x, y = poly[:, 0], poly[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cross = x * y1 - x1 * y
    area = cross.sum() / 2.0
    return np.array([((x + x1) * cross).sum(), ((y + y1) * cross).sum()]) / (6.0 * area)


def polygon_coverage(
    poly: np.ndarray, x0: int, y0: int, w: int, h: int, supersample: int = 8, rings=DISK_RINGS
) -> np.ndarray:
    """Brightness (0..1) of the patch ``[y0, y0+h) x [x0, x0+w)`` covered by a convex polygon
    (Nx2, pixel coordinates, pixel centres at integers). Float32 (h, w).

    Each pixel row is cut into ``supersample`` sub-rows; on each, the polygon covers one span
    ``[xl, xr]`` whose overlap with every pixel is taken exactly. ``rings`` adds copies of the
    polygon scaled about its centroid, each with a weight: ``((1.0, 1.0),)`` is a uniform fill.
    """
    s = supersample
    scales = np.array([sc for sc, _ in rings])[:, None]
    weights = np.array([wt for _, wt in rings])
    cx, cy = polygon_centroid(poly)
    ys = y0 - 0.5 + (np.arange(h * s) + 0.5) / s
    q = (cy + (ys[None, :] - cy) / scales).ravel()  # each ring's sub-rows, mapped onto the polygon
    # Split the polygon at its lowest and highest vertex into two chains along which y only
    # grows; a sub-row's span lies between the two chains' x at its height.
    lo = int(np.argmin(poly[:, 1]))
    ring = np.concatenate([poly[lo:], poly[:lo]])
    hi = int(np.argmax(ring[:, 1]))
    chain_a = ring[: hi + 1]
    chain_b = np.concatenate([ring[hi:], ring[:1]])[::-1]
    xa = np.interp(q, chain_a[:, 1], chain_a[:, 0], left=np.nan, right=np.nan)
    xb = np.interp(q, chain_b[:, 1], chain_b[:, 0], left=np.nan, right=np.nan)
    k = len(weights)
    inside = ~(np.isnan(xa) | np.isnan(xb)).reshape(k, -1)
    xl = np.where(inside, cx + scales * (np.fmin(xa, xb).reshape(k, -1) - cx), np.inf)
    xr = np.where(inside, cx + scales * (np.fmax(xa, xb).reshape(k, -1) - cx), -np.inf)
    cols = x0 + np.arange(w)
    cover = np.minimum(xr[:, :, None], cols + 0.5) - np.maximum(xl[:, :, None], cols - 0.5)
    np.clip(cover, 0.0, 1.0, out=cover)
    total = np.tensordot(weights, cover, axes=1)  # (h*s, w)
    return total.reshape(h, s, w).mean(axis=1).astype(np.float32)


# Blue = 0.96 g + 8, red = 1.01525 g - 3.05: the luma 0.299 R + 0.587 G + 0.114 B stays g
# (0.299 * 1.01525 + 0.114 * 0.96 = 0.413; 0.299 * -3.05 + 0.114 * 8 = 0), the background
# (g ~ 20) is a dim blue-grey, and a marker (g ~ 220) is white within a level.
_LEVELS = np.arange(256, dtype=np.float64)
_BLUE = np.clip(np.rint(0.96 * _LEVELS + 8.0), 0, 255).astype(np.uint8)
_RED = np.clip(np.rint(1.01525 * _LEVELS - 3.05), 0, 255).astype(np.uint8)
_JPEG_420 = [cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420]


def colourise(img: np.ndarray) -> np.ndarray:
    """The BGR image of a grey one: the same luma, a slight tint that fades out towards white."""
    return cv2.merge([cv2.LUT(img, _BLUE), img, cv2.LUT(img, _RED)])


def encode(img: np.ndarray, quality: int, colour: bool = True) -> bytes:
    """JPEG at ``quality`` (1..100), via OpenCV: of a grey image, 3-component YCbCr 4:2:0 as a
    camera sends it (:func:`colourise`), or 1-component with ``colour=False``; a BGR image is
    encoded as it is."""
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)]
    if colour and img.ndim == 2:
        img, params = colourise(img), params + _JPEG_420
    ok, buf = cv2.imencode(".jpg", img, params)
    if not ok:
        raise RuntimeError("JPEG encoding failed")
    return buf.tobytes()


class Renderer:
    """Renders grey images of a :class:`Scene` as each camera sees it. Thread-safe.

    ``background`` is the mean grey level of the dim background (with gentle low-frequency
    structure, seeded per camera). Marker light adds to it: ``marker_level - background`` while
    the camera's LED is on (so markers reach about ``marker_level``), only ``led_off_level``
    while it is off. ``noise_sigma`` is the sensor noise (grey levels, 1 sigma; 0 gives
    noise-free images). ``stats`` counts cache hits and misses.
    """

    def __init__(
        self,
        scene: Scene,
        noise_sigma: float = 2.0,
        background: float = 20.0,
        marker_level: float = 220.0,
        led_off_level: float = 5.0,
        supersample: int = 8,
        outline_points: int = 96,
        noise_frames: int = 8,
        noise_pad: int = 32,
        seed: int = 0,
        cache_size: int = 4,
        exposure_s: float = 0.008,
        blur_steps: int = 5,
        blur_min_px: float = 0.2,
    ):
        self.scene = scene
        self.exposure = {name: float(exposure_s) for name in scene.cameras}  # s, per camera
        self.focus = {name: 0.0 for name in scene.cameras}  # defocus blur (px, 1 sigma), per camera
        self.blur_steps = int(blur_steps)
        self.blur_min_px = float(blur_min_px)
        self.noise_sigma = float(noise_sigma)
        self.marker_level = float(marker_level)
        self.led_off_level = float(led_off_level)
        self.background_level = float(background)
        self.supersample = int(supersample)
        self.outline_points = int(outline_points)
        self.cache_size = int(cache_size)
        self._bg = {
            name: self._make_background(c.width, c.height, background, seed * 101 + i)
            for i, (name, c) in enumerate(scene.cameras.items())
        }
        self._cache: dict[str, OrderedDict] = {name: OrderedDict() for name in scene.cameras}
        self._static: dict[tuple, np.ndarray] = {}  # the wall markers' signal, per camera pose
        self._lock = threading.Lock()
        self._rng = random.Random(seed)
        self._pad = int(noise_pad)
        self._noise = None
        if self.noise_sigma > 0:
            w = max(c.width for c in scene.cameras.values()) + self._pad
            h = max(c.height for c in scene.cameras.values()) + self._pad
            self._noise = (
                np.random.default_rng(seed).normal(0.0, self.noise_sigma, (noise_frames, h, w)).astype(np.float32)
            )
        self.stats = {"hits": 0, "misses": 0}

    @staticmethod
    def _make_background(w: int, h: int, level: float, seed: int) -> np.ndarray:
        """Dim background: ``level`` plus smooth waves of a few grey levels and a vignette."""
        rng = np.random.default_rng(seed)
        xx, yy = np.meshgrid(np.linspace(-1, 1, w), np.linspace(-1, 1, h))
        bg = np.full((h, w), level, dtype=np.float64)
        for amp in (2.5, 1.5):
            fx, fy = rng.uniform(0.3, 1.2, 2)
            bg += amp * np.cos(np.pi * (fx * xx + fy * yy) + rng.uniform(0, 2 * np.pi))
        bg -= 3.0 * (xx**2 + yy**2) / 2.0 - 1.0
        return bg.astype(np.float32)

    def background(self, cam: str) -> np.ndarray:
        """The background ``cam`` shows where there is no marker, as a noise-free uint8 image."""
        return np.clip(np.rint(self._bg[cam]), 0, 255).astype(np.uint8)

    # ------------------------------------------------------------------ rendering
    def render(self, cam: str, t: float, noise: bool = True, led: bool | None = None) -> np.ndarray:
        """The uint8 (H, W) image ``cam`` sees at host time ``t``, with sensor noise unless
        ``noise`` is False (or ``noise_sigma`` is 0); ``led`` overrides the LED ring's state."""
        clean = self.clean(cam, t, led)
        if self._noise is None or not noise:
            return np.clip(np.rint(clean), 0, 255).astype(np.uint8)
        h, w = clean.shape
        with self._lock:
            k = self._rng.randrange(len(self._noise))
            dy, dx = self._rng.randrange(self._pad + 1), self._rng.randrange(self._pad + 1)
        return cv2.add(clean, self._noise[k, dy : dy + h, dx : dx + w], dtype=cv2.CV_8U)

    def clean(self, cam: str, t: float, led: bool | None = None) -> np.ndarray:
        """The noise-free float32 image at ``t`` (not quantised), from the cache when the scene
        looks the same (``led``: the LED ring's state, default the scene's). The array is
        shared: do not modify it."""
        camera, markers, uv, _ = self.scene.project_markers(cam, t)
        led = self.scene.led_on(cam, t) if led is None else bool(led)
        key: tuple[Any, ...] = (led, tuple(np.round(uv, 3).ravel().tolist()), self.scene.pose_key(t))
        smear, ends = self._smear(cam, camera, markers, uv, t)
        if smear:
            key += (("blur", ends),)
        focus = self.focus.get(cam, 0.0)
        if focus > 0:
            key += (("focus", focus),)
        cache = self._cache[cam]
        with self._lock:
            img = cache.get(key)
            if img is not None:
                cache.move_to_end(key)
                self.stats["hits"] += 1
                return img
        hidden = self.scene.hidden(camera.center, markers, t)  # behind a SPECT head: not drawn
        keep = [i for i, h in enumerate(hidden) if not h]
        n_wall = len(self.scene.wall_markers)  # first in project_markers' list; they never move
        img = self._rasterise(
            cam,
            camera,
            [markers[i] for i in keep],
            led,
            {k: smear[i] for k, i in enumerate(keep) if i in smear},
            n_static=sum(1 for i in keep if i < n_wall),
            focus=focus,
        )
        with self._lock:
            self.stats["misses"] += 1
            cache[key] = img
            while len(cache) > self.cache_size:
                cache.popitem(last=False)
        return img

    def _smear(self, cam: str, camera, markers, uv, t: float) -> tuple[dict, tuple]:
        """The markers that move more than ``blur_min_px`` over the exposure: ``{index: [the
        marker at each sub-instant]}``, and their projected centres at the exposure's two ends
        (for the cache key). Only bodies that move continuously (a pose that is not a
        :class:`Schedule`: the patient) are smeared; scheduled poses and the table change in
        steps ("from this instant on") and are drawn as they are at ``t``."""
        exposure, n = self.exposure.get(cam, 0.0), self.blur_steps
        if exposure <= 0 or n < 2 or not markers:
            return {}, ()
        times = t + exposure * ((np.arange(n) + 0.5) / n - 0.5)
        y, z = self.scene.table.at(t)
        offset = np.array([0.0, y, z])
        paths: dict[int, list[Marker]] = {}
        k = len(self.scene.wall_markers)
        for body in list(self.scene.bodies.values()):
            count = len(body.markers)
            if not isinstance(body.pose, Schedule):
                at = [body.markers_at(float(x), offset) for x in times]
                paths.update({k + j: [ms[j] for ms in at] for j in range(count)})
            k += count
        paths = {i: p for i, p in paths.items() if i < len(markers) and p[0].id == markers[i].id}
        if not paths:
            return {}, ()
        idx = sorted(paths)
        uv0 = camera.project(np.array([paths[i][0].center for i in idx]))
        uv1 = camera.project(np.array([paths[i][-1].center for i in idx]))
        moved = np.maximum(np.linalg.norm(uv0 - uv[idx], axis=1), np.linalg.norm(uv1 - uv[idx], axis=1))
        keep = [j for j, m in enumerate(moved) if m > self.blur_min_px]
        if not keep:
            return {}, ()
        ends = tuple(np.round(np.hstack([uv0[keep], uv1[keep]]), 3).ravel().tolist())
        return {idx[j]: paths[idx[j]] for j in keep}, ends

    def signal(self, camera, markers, smear: dict | None = None, into: np.ndarray | None = None) -> np.ndarray:
        """Float32 (H, W) marker brightness in 0..1 (coverage times profile), no background.
        ``smear``: for the index of a marker that moves during the exposure, the marker at each
        sub-instant; it is drawn as the mean of those outlines. ``into``: draw onto this signal
        (each pixel the brightest marker there) instead of a blank one."""
        sig = np.zeros((camera.height, camera.width), dtype=np.float32) if into is None else into
        eye = camera.center
        smear = smear or {}
        drawn = [
            (i, m)
            for i, m in enumerate(markers)
            if m.faces(eye) and camera.to_camera(m.center[None])[0, 2] > m.diameter_mm
        ]
        if not drawn:
            return sig
        n = self.outline_points
        outlines = camera.project(np.vstack([m.outline(eye, n) for _, m in drawn])).reshape(-1, n, 2)
        for (i, m), poly in zip(drawn, outlines):
            rings = SPHERE_RINGS if m.kind == "sphere" else DISK_RINGS
            if i in smear:
                path = smear[i]
                polys = camera.project(np.vstack([p.outline(eye, n) for p in path])).reshape(-1, n, 2)
                self._draw(sig, polys, rings)
            else:
                self._draw(sig, poly[None], rings)
        return sig

    def _draw(self, sig: np.ndarray, polys: np.ndarray, rings) -> None:
        """Draw the mean of the outlines ``polys`` (k x n x 2; one outline: not blurred)."""
        h_img, w_img = sig.shape
        x0, y0 = np.maximum(np.floor(polys.reshape(-1, 2).min(axis=0) + 0.5).astype(int) - 1, 0)
        x1, y1 = np.minimum(np.floor(polys.reshape(-1, 2).max(axis=0) + 0.5).astype(int) + 2, (w_img, h_img))
        if x1 <= x0 or y1 <= y0:
            return  # entirely outside the image
        patch = polygon_coverage(polys[0], x0, y0, x1 - x0, y1 - y0, self.supersample, rings)
        if len(polys) > 1:
            for poly in polys[1:]:
                patch += polygon_coverage(poly, x0, y0, x1 - x0, y1 - y0, self.supersample, rings)
            patch /= np.float32(len(polys))
        region = sig[y0:y1, x0:x1]
        np.maximum(region, patch, out=region)

    def _rasterise(
        self, cam: str, camera, markers, led: bool, smear: dict | None = None, n_static: int = 0, focus: float = 0.0
    ) -> np.ndarray:
        """The image of ``markers`` (the first ``n_static`` of them fixed: the wall's, drawn
        once per camera pose and kept, ``self._static``); a scene with a moving body redraws
        only that body's markers each frame. ``focus`` > 0: the marker light blurred by a
        Gaussian of that standard deviation (px), a lens out of focus."""
        bg = self._bg[cam]
        smear = smear or {}
        fixed = [i for i in range(n_static) if i not in smear]
        if fixed:
            key = tuple(
                (markers[i].id, *np.round(camera.project(markers[i].center[None])[0], 3).tolist()) for i in fixed
            )
            with self._lock:
                base = self._static.get((cam, key))
            if base is None:
                base = self.signal(camera, [markers[i] for i in fixed])
                base.flags.writeable = False
                with self._lock:
                    self._static[(cam, key)] = base
                    while len(self._static) > 4 * len(self._bg):
                        self._static.pop(next(iter(self._static)))
            moving = [i for i in range(len(markers)) if i not in set(fixed)]
            sig = self.signal(
                camera,
                [markers[i] for i in moving],
                {k: smear[i] for k, i in enumerate(moving) if i in smear},
                into=base.copy(),
            )
        else:
            sig = self.signal(camera, markers, smear)
        if focus > 0:
            sig = cv2.GaussianBlur(sig, (0, 0), focus, borderType=cv2.BORDER_CONSTANT)
        amp = self.marker_level - self.background_level if led else self.led_off_level
        img = cv2.scaleAdd(sig, float(amp), bg)  # bg + sig * amp, in one pass
        img.flags.writeable = False
        return img

    @staticmethod
    def encode(img: np.ndarray, quality: int, colour: bool = True) -> bytes:
        """JPEG of ``img`` at ``quality`` (see :func:`encode`)."""
        return encode(img, quality, colour)
