"""A simulated recording folder written straight from the scene: no HTTP, no real time.

For tests and benchmarks of the processing (vts_hw/tracking/processing.py): each camera's frames are
rendered at their exposure times (host clock), JPEG-encoded, stamped with the camera's own
clock (truncated to 10 ms, as an Axis camera does) and written with the
:class:`~vts_hw.recording.writer.Recording` writer, with a simulated host receive time = exposure +
latency (a floor, exponential jitter, rare large outliers; a late frame delays the frames
behind it, as on one TCP connection).

The moving body is a patient band (:data:`BAND_LAYOUT`, 4 spheres of 13 mm) on the table,
breathing (a sinusoid in Y) and moved axially (Z) a few times by smooth steps, so that the
tracks have both slow continuous motion and clear motion events. The truth is returned, not
written into the folder.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vts_hw.files import open_writable
from vts_hw.recording.axis_jpeg import stamp_jpeg
from vts_hw.recording.folder import read_index
from vts_hw.recording.writer import Recording
from vts_hw.sim_devices.patient import add_patient
from vts_hw.sim_devices.render import Renderer, encode
from vts_hw.sim_devices.scene import CameraClock, Marker, RigidBody, Scene

__all__ = ["BAND_LAYOUT", "BreathingBand", "SimRecording", "simulate_recording"]

# Band markers in body coordinates (mm): 4 spheres across the chest, 10 cm apart in X, at
# heights and axial positions chosen (by a search over seeds 0-2 of the reference rig) so that
# no two markers, wall markers included, come within 15 px of each other's epipolar line over
# the default motion: markers level with each other along the baseline would be ambiguous.
BAND_LAYOUT = {
    "B1": (-150.0, -13.0, 51.0),
    "B2": (-50.0, 30.0, 15.0),
    "B3": (50.0, -6.0, -46.0),
    "B4": (150.0, -33.0, -46.0),
}
BAND_DIAMETER = 13.0
BAND_PLACEMENT = (0.0, 60.0, -40.0)


@dataclass
class BreathingBand:
    """The band's pose over host time ``t`` (s): breathing in Y and axial steps in Z (mm).

    ``steps``: ``(t_offset_s, dz_mm)`` — at ``start + t_offset_s`` the band starts moving by
    ``dz_mm`` along Z, over ``step_s`` seconds (a smooth cosine ramp).
    """

    start: float
    amplitude_mm: float = 5.0
    period_s: float = 4.0
    steps: tuple = ((6.0, 10.0), (14.0, -20.0))
    step_s: float = 0.5
    placement: tuple = BAND_PLACEMENT

    def translation(self, t):
        """Body translation (mm, table coordinates) at host time(s) ``t``: (..., 3)."""
        t = np.asarray(t, float)
        u = t - self.start
        y = self.placement[1] + self.amplitude_mm * np.sin(2 * math.pi * u / self.period_s)
        z = np.full_like(u, self.placement[2])
        for t0, dz in self.steps:
            f = np.clip((u - t0) / self.step_s, 0.0, 1.0)
            z = z + dz * (0.5 - 0.5 * np.cos(math.pi * f))
        return np.stack([np.full_like(u, self.placement[0]), y, z], axis=-1)

    def events(self) -> list[tuple[float, float]]:
        """``(host time of the step's middle, dz_mm)`` for each step."""
        return [(self.start + t0 + self.step_s / 2, dz) for t0, dz in self.steps]


@dataclass
class SimRecording:
    """What :func:`simulate_recording` made, with the truth.

    Per camera (dicts by name): ``exposure`` (host epoch s, the true instant of each written
    frame), ``camera_time`` (the stamp written, camera epoch s), ``host_time`` (the simulated
    receive time). ``scene``: the scene (true cameras: ``scene.camera_at``; clocks:
    ``scene.clocks``). ``band``: the band's motion.
    """

    folder: Path
    scene: Scene
    band: BreathingBand
    fps: float
    duration_s: float
    exposure: dict = field(default_factory=dict)
    camera_time: dict = field(default_factory=dict)
    host_time: dict = field(default_factory=dict)
    torn_bytes: dict = field(default_factory=dict)
    patient: object = None

    @property
    def cameras(self) -> list[str]:
        return list(self.exposure)

    def marker_positions(self, t) -> tuple[list[str], np.ndarray]:
        """``(ids, positions)``: every marker (wall, then band) in the world/SPECT frame (mm)
        at host time(s) ``t`` — positions (..., n_markers, 3)."""
        t = np.asarray(t, float)
        wall = np.array([m.center for m in self.scene.wall_markers])
        band_local = np.array(list(BAND_LAYOUT.values()))
        trans = self.band.translation(t)  # (..., 3); the band does not rotate, the table stays
        band = band_local + trans[..., None, :]
        wall_b = np.broadcast_to(wall, t.shape + wall.shape)
        ids = [m.id for m in self.scene.wall_markers] + list(BAND_LAYOUT)
        return ids, np.concatenate([wall_b, band], axis=-2)

    def seen_by(self, cam: str, t: float) -> np.ndarray:
        """Which markers (in :meth:`marker_positions` order) camera ``cam`` sees at host time
        ``t``: in front of it, facing it, centre inside the image, not behind a SPECT head."""
        ids, pos = self.marker_positions(float(t))
        camera = self.scene.camera_at(cam, float(t))
        walls = list(self.scene.wall_markers)
        faces = np.array([m.faces(camera.center) for m in walls] + [True] * (len(ids) - len(walls)))
        uv = camera.project(pos)
        inside = (
            (uv[:, 0] >= 0)
            & (uv[:, 0] <= camera.width - 1)
            & (uv[:, 1] >= 0)
            & (uv[:, 1] <= camera.height - 1)
            & (camera.to_camera(pos)[:, 2] > 0)
        )
        radius = np.array([m.diameter_mm / 2 for m in walls] + [BAND_DIAMETER / 2] * (len(ids) - len(walls)))
        hidden = (
            self.scene.gantry.hides(camera.center, pos, float(t), radius)
            if self.scene.gantry is not None
            else np.zeros(len(ids), bool)
        )
        return faces & inside & ~hidden


def simulate_recording(
    folder,
    duration_s: float = 20.0,
    fps: float = 25.0,
    seed: int = 0,
    scene: Scene | None = None,
    band: BreathingBand | None = None,
    phases_s: dict | None = None,
    latency_floor_s: float = 0.004,
    jitter_s: float = 0.003,
    outlier_rate: float = 0.01,
    outlier_s: tuple = (0.05, 0.3),
    quality: int = 75,
    noise_sigma: float = 2.0,
    gaps: dict | None = None,
    torn_tail: tuple = (),
    clock_offsets_s: dict | None = None,
    start: float | None = None,
    add_band: bool = True,
    patient: dict | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> SimRecording:
    """Write a recording folder of every camera of ``scene`` (default: the reference rig with
    ``seed``, 2 cameras, LEDs on, a :class:`BreathingBand`) over ``duration_s`` seconds.

    ``phases_s``: per camera, the delay of its frame grid after the scene's start (default:
    cam1 0, the others 13 ms apart: free-running cameras are not in step). ``gaps``: per
    camera, ``[(t0, t1), ...]`` offsets (s from the start) during which no frame arrives
    (a lost connection; the gap is put in the manifest). ``torn_tail``: cameras whose
    ``.mjpeg`` ends with half a JPEG and no index line (a killed recorder).
    ``clock_offsets_s``: override camera clock offsets (s), e.g. to make them differ by
    seconds. Host receive time = exposure + ``latency_floor_s`` + exponential(``jitter_s``),
    plus with probability ``outlier_rate`` a uniform ``outlier_s`` extra, never before the
    previous frame's receipt. ``start``: host time of the first frames (default 5 s after the
    scene's start). ``add_band=False``: no band (the scene's own bodies, e.g. a source marker
    with its scheduled moves, are rendered as scheduled either way; the truth is then
    ``scene.markers_world(t)``).
    """
    rng = np.random.default_rng(seed + 7)
    if scene is None:
        scene = Scene.reference(seed=seed, start_epoch=1_790_000_000.0 + 1000.0 * seed)
    if clock_offsets_s:
        for name, off in clock_offsets_s.items():
            old = scene.clocks[name]
            scene.clocks[name] = CameraClock(float(off), old.skew_ppm, old.ref_epoch)
    start = scene.start_epoch + 5.0 if start is None else float(start)
    if band is None:
        band = BreathingBand(start)
    the_patient = None
    if patient is not None:
        the_patient = add_patient(scene, start, duration_s, seed, **patient)
        add_band = False
    if add_band and "band" not in scene.bodies:
        markers = [
            Marker(k, np.array(v), np.array([0.0, 1.0, 0.0]), BAND_DIAMETER, "sphere") for k, v in BAND_LAYOUT.items()
        ]
        scene.add_body(RigidBody("band", markers))
    names = scene.camera_names
    for cam in names:
        scene.set_led(cam, True)
    renderer = Renderer(scene, noise_sigma=noise_sigma, seed=seed, cache_size=1)
    phases = {c: 0.013 * i for i, c in enumerate(names)}
    phases.update(phases_s or {})
    gaps = gaps or {}
    folder = Path(folder)
    out = SimRecording(folder, scene, band, fps, duration_s)
    out.patient = the_patient
    n = int(round(duration_s * fps))
    # Frame times per camera, then rendered in time order (the band's pose is set per frame).
    plan: list[tuple[float, str, int]] = []
    for cam in names:
        t = start + phases[cam] + np.arange(n) / fps
        keep = np.ones(n, bool)
        for t0, t1 in gaps.get(cam, ()):
            keep &= ~((t >= start + t0) & (t < start + t1))
        t = t[keep]
        lat = latency_floor_s + rng.exponential(jitter_s, t.size)
        late = rng.random(t.size) < outlier_rate
        low, high = outlier_s
        lat[late] += rng.uniform(low, high, late.sum())
        recv = np.maximum.accumulate(t + lat)
        recv[1:] = np.maximum(recv[1:], recv[:-1] + 1e-4)
        clock = scene.clocks[cam]
        ctimes = [clock.camera_time(float(x)) for x in t]
        out.exposure[cam], out.host_time[cam] = t, recv
        out.camera_time[cam] = np.floor(np.array(ctimes) * 100.0 + 1e-6) / 100.0
        plan.extend((float(x), cam, i) for i, x in enumerate(t))
    plan.sort()
    meta = {"simulated": {"seed": seed, "fps": fps, "duration_s": duration_s}}
    done = 0
    with Recording(folder, names, meta) as rec:
        for cam in names:
            clock = scene.clocks[cam]
            for t0, t1 in gaps.get(cam, ()):  # in the recorder's form (vts_hw/recording/capture.py)
                before = int(np.searchsorted(out.exposure[cam], start + t0)) - 1
                rec.add_gap(
                    cam,
                    {
                        "after_frame": before,
                        "camera_t0": clock.camera_time(start + t0),
                        "camera_t1": clock.camera_time(start + t1),
                        "missing": int(round((t1 - t0) * fps)),
                        "reason": "simulated: connection lost",
                        "host_time": start + t1,
                    },
                )
        trans = band.translation(np.array([p[0] for p in plan]))
        for (at, cam, i), tr in zip(plan, trans):
            if add_band:
                scene.set_body_pose("band", (0.0, 0.0, 0.0), tr)
            img = renderer.render(cam, at)
            jpeg = stamp_jpeg(encode(img, quality), scene.clocks[cam].camera_time(at), scene.products[cam])
            rec.write_frame(cam, jpeg, float(out.camera_time[cam][i]), float(out.host_time[cam][i]))
            done += 1
            if progress and done % 100 == 0:
                progress(done, len(plan))
    for cam in torn_tail:
        img = renderer.render(cam, start + duration_s)
        jpeg = stamp_jpeg(encode(img, quality), scene.clocks[cam].camera_time(start + duration_s), scene.products[cam])
        half = jpeg[: len(jpeg) // 2]
        with open_writable(folder / f"{cam}.mjpeg", "ab") as f:
            f.write(half)
        out.torn_bytes[cam] = len(half)
    return out


def received_frames(folder, cameras) -> tuple[list[tuple[float, str, object]], dict[str, float]]:
    """A recording's frames as the live path received them: (host receipt time, camera, frame
    with ``jpeg``, ``camera_time``, ``host_time``) in receipt order, and per camera its clock
    minus the host clock (the median over its frames), to feed a LiveTracker without cameras."""
    import statistics
    from types import SimpleNamespace

    folder = Path(folder)
    frames: list[tuple[float, str, object]] = []
    offsets: dict[str, float] = {}
    for name in cameras:
        rows = read_index(folder / f"{name}.index.csv")
        data = (folder / f"{name}.mjpeg").read_bytes()
        # a simulated recording stamps every frame with both times
        timed = [(r, r.camera_time, r.host_time) for r in rows if r.camera_time is not None and r.host_time is not None]
        offsets[name] = statistics.median(c - h for _, c, h in timed)
        frames += [
            (h, name, SimpleNamespace(jpeg=data[r.offset : r.offset + r.length], camera_time=c, host_time=h))
            for r, c, h in timed
        ]
    frames.sort(key=lambda f: f[0])
    return frames, offsets
