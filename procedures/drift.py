"""Wall-marker drift: has a fixed camera moved since its baseline, and does its LED work?

The procedure, as a physicist does it every morning:

1. LED on, a few snapshots; LED off, one snapshot (then the LED is switched back on).
2. Detect the bright blobs (sub-pixel centroids) in every LED-on frame and match each to its
   baseline marker (nearest, one-to-one, within a gate).
3. Per marker and per camera: mean and SD of the displacement in x and y, in pixels and in mm
   at the wall; markers not found and stray blobs are reported, never dropped silently.
4. The LED-off frame must show none of the markers (the LED switches).
5. Each metric gets a state from its tolerance window; the run's state is the worst.

It reads like pylinac: ``DriftAnalysis.acquire(camera, baseline)`` (or ``.from_frames``) →
``analyze(tolerances)`` → ``results()`` / ``results_data()`` / ``plot()``.
"""

from __future__ import annotations

import datetime as _dt
import math
import time
from dataclasses import dataclass, field

import numpy as np

from vts_hw import __version__, catalog
from vts_hw.camera import Frame, Illumination
from vts_hw.catalog import DRIFT
from vts_hw.errors import DataError
from vts_hw.figures import figure_png
from vts_hw.results import Measure
from vts_hw.tolerance import State, Window, worst
from vts_hw.vision.detect import DetectorSettings, detect_jpeg
from vts_hw.vision.marker_roles import GATE_PX, MOVE_FLOOR_PX, PATIENT, Role, follow, roles_of_tracks  # noqa: F401
from vts_hw.vision.marker_roles import match_markers as _match
from vts_hw.vision.wall_baseline import Baseline, BaselineMarker  # noqa: F401

LED_SETTLE_S = 0.1  # time for the LED ring to switch before the next frame is taken
SPAN_S = 3.0  # frames spread over this see a breathing marker move: half a slow breath (3-6 s)
_STRAY_REASONS = ("roundness", "border", "crowded", "truncated", "too many")


@dataclass
class MarkerDrift:
    id: str
    baseline: tuple[float, float]
    found: int
    dx: list[float] = field(default_factory=list)
    dy: list[float] = field(default_factory=list)

    def stats(self) -> tuple[float, float, float, float]:
        if not self.dx:
            return math.nan, math.nan, math.nan, math.nan
        dx, dy = np.array(self.dx), np.array(self.dy)
        sdx = float(dx.std(ddof=1)) if len(dx) > 1 else 0.0
        sdy = float(dy.std(ddof=1)) if len(dy) > 1 else 0.0
        return float(dx.mean()), float(dy.mean()), sdx, sdy


class DriftAnalysis:
    """Drift of one camera against its baseline, from LED-on frames and an LED-off frame."""

    procedure = DRIFT.name

    def __init__(
        self,
        camera: str,
        baseline: Baseline,
        frames_on: list[Frame],
        frame_off: Frame | None,
        mm_per_px: float = 1.25,
        settings: DetectorSettings | None = None,
    ):
        self.camera = camera
        self.baseline = baseline
        self.frames_on = frames_on
        self.frame_off = frame_off
        self.mm_per_px = mm_per_px
        self.settings = settings or DetectorSettings()
        self.analyzed = False

    # -- load ----------------------------------------------------------------------------
    @classmethod
    def from_frames(
        cls, camera: str, baseline: Baseline, jpegs_on: list[bytes], jpeg_off: bytes | None, **kwargs
    ) -> DriftAnalysis:
        on = [Frame(i, j, None, 0.0) for i, j in enumerate(jpegs_on)]
        off = Frame(0, jpeg_off, None, 0.0) if jpeg_off is not None else None
        return cls(camera, baseline, on, off, **kwargs)

    @classmethod
    def acquire(cls, cam, baseline: Baseline, n_frames: int = 5, on_frame=None, **kwargs) -> DriftAnalysis:
        """LED on, ``n_frames`` snapshots, LED off, one snapshot, LED back on (``on_frame``:
        as :func:`acquire_led_frames`)."""
        frames_on, frame_off = acquire_led_frames(cam, n_frames, on_frame=on_frame)
        return cls(cam.name, baseline, frames_on, frame_off, **kwargs)

    # -- analyze -------------------------------------------------------------------------
    def analyze(self, tolerances: dict[str, Window] | None = None) -> DriftAnalysis:
        self.tolerances = catalog.windows(tolerances)  # the catalog's windows, the given ones on top
        ref = self.baseline.points()
        self.markers = [MarkerDrift(m.id, (m.x, m.y), 0) for m in self.baseline.markers]
        self.moved_near: list[str] = []
        rejected: list[tuple[float, float]] = []
        unmatched: list[np.ndarray] = []
        self.detections = []
        for snap in self.frames_on:
            res = detect_jpeg(snap.jpeg, self.settings)
            self.detections.append(res)
            pts = np.array([(b.x, b.y) for b in res.blobs]).reshape(-1, 2)
            pairs = _match(ref, pts, GATE_PX)
            matched = {j for _, j in pairs}
            for i, j in pairs:
                md = self.markers[i]
                md.found += 1
                md.dx.append(float(pts[j][0] - ref[i][0]))
                md.dy.append(float(pts[j][1] - ref[i][1]))
            unmatched.append(pts[[j for j in range(len(pts)) if j not in matched]])
            # rejected candidates that are real bright things (not specks of noise) are strays too
            rejected += [
                (b.x, b.y)
                for b, why in res.rejected
                if why in _STRAY_REASONS or (why == "area" and b.area > self.settings.max_area)
            ]
        n = len(self.frames_on)
        # the markers that are not the baseline's, each known by what it is (vision/marker_roles.py):
        # one that moved over the frames is the patient's, never a stray; a still one is a stray
        # unless place() (the daily QA, every camera measured) finds it on the table
        need = max(1, (n + 1) // 2)
        self.others: list[tuple[float, float, Role]] = []
        # every marker not the baseline's, for place() to match across the cameras (a marker still
        # here may have moved in another camera's frames: both views are needed to place it)
        self.candidates: list[tuple[float, float]] = []
        strays: list[tuple[float, float]] = []
        tracks = follow(unmatched)
        for t, role in zip(tracks, roles_of_tracks(tracks)):
            if role is not None and role.role == PATIENT:
                self.others.append((t.x, t.y, role))
                self.candidates.append((t.x, t.y))
            elif t.seen >= need:
                strays.append((t.x, t.y))
                self.candidates.append((t.x, t.y))
        # a stray counts if it is there in at least half the frames (not a flicker of noise)
        self.strays = strays + _persistent(rejected, n)
        # a baseline marker whose match moved over the frames is not that wall marker (a patient's
        # marker passing near where it was, the wall marker hidden): not found
        for md in self.markers:
            if len(md.dx) >= 2 and math.hypot(np.ptp(md.dx), np.ptp(md.dy)) > MOVE_FLOOR_PX:
                self.moved_near.append(md.id)
                md.found, md.dx, md.dy = 0, [], []
        # LED off: how many baseline markers are still bright
        self.led_off_visible = None
        if self.frame_off is not None:
            res = detect_jpeg(self.frame_off.jpeg, self.settings)
            pts = np.array([(b.x, b.y) for b in res.blobs]).reshape(-1, 2)
            self.led_off_visible = len(_match(ref, pts, GATE_PX))
        self._measure()
        self.analyzed_at = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        self.analyzed = True
        return self

    def look_longer(self, cam, frames: int = 4, span_s: float = SPAN_S, on_frame=None) -> DriftAnalysis:
        """When markers neither the baseline's nor seen moving are in view (:attr:`strays`):
        ``frames`` more LED-on snapshots over ``span_s`` (the LED was left on), and the analysis
        made again over every frame: a patient's marker still over a few quick frames moves over
        half a breath (rule 1 of vision/marker_roles.py). Nothing more is taken without strays."""
        self._need()
        if not self.strays or frames < 1:
            return self
        time.sleep(LED_SETTLE_S)
        for k in range(frames):
            time.sleep(span_s / frames)
            self.frames_on.append(cam.snapshot())
            if on_frame is not None:
                on_frame(self.frames_on[-1], True, k + 1, frames)
        return self.analyze(self.tolerances)

    def place(self, roles) -> DriftAnalysis:
        """Rule 2 for the markers that are not the baseline's (:attr:`candidates`, in order;
        ``roles`` from :meth:`vts_hw.vision.marker_roles.RoomGeometry.place`): one on the table (the
        phantom, a patient holding still) is no stray (one that moved is already the patient's);
        the measures are made again."""
        self._need()
        for (x, y), role in zip(list(self.candidates), roles):
            if role is not None and not role.is_wall and (x, y) in self.strays:
                self.others.append((x, y, role))
                self.strays = [p for p in self.strays if p != (x, y)]
        self._measure()
        return self

    def _measure(self) -> None:
        n = len(self.frames_on)
        self.missing = [m.id for m in self.markers if m.found < max(1, (n + 1) // 2)]
        good = [m for m in self.markers if m.id not in self.missing]
        self.measures: list[Measure] = []
        cam = self.camera
        if good:
            means = np.array([m.stats() for m in good])
            dx, dy = float(means[:, 0].mean()), float(means[:, 1].mean())
            sd = float(np.nanmax(means[:, 2:4]))
            spread = (float(means[:, 0].std()), float(means[:, 1].std()))
        else:
            dx = dy = sd = math.nan
            spread = (math.nan, math.nan)
        self.drift_px = (dx, dy)
        self.spread_px = spread
        add = self._add
        add(cam, "drift_x_px", dx, "px")
        add(cam, "drift_y_px", dy, "px")
        add(cam, "drift_x_mm", dx * self.mm_per_px, "mm", window="drift_x_px", scale=self.mm_per_px)
        add(cam, "drift_y_mm", dy * self.mm_per_px, "mm", window="drift_y_px", scale=self.mm_per_px)
        add(cam, "drift_sd_px", sd, "px")
        add(cam, "markers_missing", float(len(self.missing)), "markers")
        add(cam, "stray_blobs", float(len(self.strays)), "blobs")
        if self.led_off_visible is not None:
            add(cam, "led_off_visible", float(self.led_off_visible), "markers")
        for m in self.markers:
            mx, my, sx, sy = m.stats()
            subj = f"{cam}/{m.id}"
            state_ok = m.id not in self.missing
            add(subj, "drift_x_px", mx if state_ok else None, "px")
            add(subj, "drift_y_px", my if state_ok else None, "px")
            add(subj, "drift_sd_px", max(sx, sy) if state_ok else None, "px")
        self.state = worst(m.state for m in self.measures if "/" not in m.subject)

    def _add(self, subject, metric, value, unit, window=None, scale=1.0):
        w = self.tolerances.get(window or metric)
        if value is None or (isinstance(value, float) and math.isnan(value)):
            state = State.ACTION
            value = None
        elif w is None:
            state = State.OK
        else:
            state = w.state(value / scale)
        self.measures.append(Measure(subject, metric, value, unit, state))

    # -- report --------------------------------------------------------------------------
    def _need(self):
        if not self.analyzed:
            raise RuntimeError("call analyze() first")

    def results_data(self) -> dict:
        self._need()
        return {
            "procedure": self.procedure,
            "camera": self.camera,
            "state": str(self.state),
            "software_version": __version__,
            "analyzed": self.analyzed_at,
            "baseline": {
                "taken": self.baseline.taken,
                "run_id": self.baseline.run_id,
                "markers": [m.__dict__ for m in self.baseline.markers],
            },
            "frames": len(self.frames_on),
            "mm_per_px": self.mm_per_px,
            "drift_px": {"x": _r(self.drift_px[0]), "y": _r(self.drift_px[1])},
            "drift_mm": {"x": _r(self.drift_px[0] * self.mm_per_px), "y": _r(self.drift_px[1] * self.mm_per_px)},
            "spread_between_markers_px": {"x": _r(self.spread_px[0]), "y": _r(self.spread_px[1])},
            "markers": [
                {
                    "id": m.id,
                    "found": m.found,
                    **dict(zip(("dx_px", "dy_px", "sd_x_px", "sd_y_px"), map(_r, m.stats()))),
                }
                for m in self.markers
            ],
            "missing": self.missing,
            "strays": [{"x": _r(x), "y": _r(y)} for x, y in self.strays],
            "not_wall": [{"x": _r(x), "y": _r(y), **r.to_dict()} for x, y, r in self.others],
            "moved_near": self.moved_near,
            "led_off_visible": self.led_off_visible,
            "measurements": [
                {"subject": m.subject, "metric": m.metric, "value": _r(m.value), "unit": m.unit, "state": str(m.state)}
                for m in self.measures
            ],
        }

    def results(self) -> str:
        self._need()
        d = self.results_data()
        lines = [
            f"Wall-marker drift, camera {self.camera}: {self.state}",
            f"  {len(self.frames_on)} frames against the baseline of "
            f"{_date(self.baseline.taken)} ({len(self.baseline.markers)} markers)",
            f"  drift x {_f(self.drift_px[0])} px ({_f(d['drift_mm']['x'])} mm at the wall), "
            f"y {_f(self.drift_px[1])} px ({_f(d['drift_mm']['y'])} mm)",
        ]
        for m in d["markers"]:
            lines.append(
                f"    {m['id']}: dx {_f(m['dx_px'])} ± {_f(m['sd_x_px'])} px, dy {_f(m['dy_px'])} ± "
                f"{_f(m['sd_y_px'])} px, found in {m['found']}/{len(self.frames_on)} frames"
            )
        if self.missing:
            lines.append(f"  MISSING markers: {', '.join(self.missing)}")
        for s in d["strays"]:
            lines.append(f"  STRAY bright blob at ({s['x']:.1f}, {s['y']:.1f}) px")
        for s in d["not_wall"]:
            lines.append(f"  not a wall marker at ({s['x']:.0f}, {s['y']:.0f}) px: {s['role']}: {s['reason']}")
        for mid in self.moved_near:
            lines.append(f"  {mid}: what was found there moved over the frames (not the wall marker): not found")
        if self.led_off_visible is not None:
            lines.append(
                "  LED check: "
                + (
                    "markers vanish with the LED off (OK)"
                    if self.led_off_visible == 0
                    else f"{self.led_off_visible} marker(s) still bright with the LED off"
                )
            )
        else:
            lines.append("  LED check: not made (no LED-off frame; e.g. a camera that cannot switch its LED)")
        for m in self.measures:
            if "/" not in m.subject and m.state != State.OK:
                lines.append(f"  {m.state}: {m.metric} = {_f(m.value)} {m.unit}")
        return "\n".join(lines)

    def plot(self, path=None, arrow_scale: float = 20.0):
        """The first LED-on frame with baseline (+) and current (x) centroids, and arrows
        from baseline to current, ``arrow_scale`` times longer than the drift."""
        import cv2
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        self._need()
        img = cv2.imdecode(np.frombuffer(self.frames_on[0].jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise DataError(f"camera {self.camera}: its first LED-on frame is not a picture OpenCV can read: no plot")
        fig, ax = plt.subplots(figsize=(8, 6.4), dpi=100)
        ax.imshow(img, cmap="gray", vmin=0, vmax=255)
        for m in self.markers:
            bx, by = m.baseline
            ax.plot(bx, by, "+", color="#4fc3f7", ms=12, mew=1.5)
            ax.annotate(m.id, (bx, by), xytext=(10, -10), textcoords="offset points", color="#4fc3f7", fontsize=9)
            mx, my, _, _ = m.stats()
            if not math.isnan(mx):
                ax.plot(bx + mx, by + my, "x", color="#ffb74d", ms=9, mew=1.5)
                ax.annotate(
                    "",
                    xy=(bx + arrow_scale * mx, by + arrow_scale * my),
                    xytext=(bx, by),
                    arrowprops=dict(arrowstyle="->", color="#ffb74d", lw=1.5),
                )
            else:
                ax.plot(bx, by, "o", mfc="none", mec="red", ms=18)
        for x, y in self.strays:
            ax.plot(x, y, "s", mfc="none", mec="red", ms=14)
        from matplotlib.lines import Line2D

        ax.legend(
            handles=[
                Line2D([], [], ls="", marker="+", color="#4fc3f7", ms=10, label="baseline"),
                Line2D([], [], ls="", marker="x", color="#ffb74d", ms=8, label="today"),
                Line2D([], [], color="#ffb74d", label=f"drift ×{arrow_scale:g}"),
                Line2D([], [], ls="", marker="o", mfc="none", mec="red", ms=10, label="missing / stray"),
            ],
            loc="lower right",
            fontsize=8,
            framealpha=0.8,
        )
        ax.set_title(
            f"{self.camera}: drift x {_f(self.drift_px[0])} px, y {_f(self.drift_px[1])} px "
            f"({self.state}); arrows ×{arrow_scale:g}"
        )
        ax.set_xlim(0, img.shape[1])
        ax.set_ylim(img.shape[0], 0)
        fig.tight_layout()
        if path is not None:
            figure_png(fig, path, dpi=fig.dpi)  # whole or not at all (a full disk: WriteFailed)
            plt.close(fig)
        return fig


def acquire_led_frames(cam, n_frames: int = 5, settle_s: float = LED_SETTLE_S, on_frame=None, every_s: float = 0.0):
    """LED on, ``n_frames`` snapshots (``every_s`` apart at least: the baseline spreads them over
    a breath), LED off, one snapshot; the LED is left on.

    A camera without an LED to switch (not :class:`~vts_hw.camera.Illumination`, e.g. a replayed
    recording) gives no LED-off frame: the LED check is not made rather than failed.
    ``on_frame(frame, led_on, taken, needed)`` hears of each frame as it is taken, and first
    (frame None, taken 0) before the LED is switched (progress, a console that must close its
    own stream of the camera first and then shows these frames); it must return soon."""
    switches = isinstance(cam, Illumination)
    needed = n_frames + (1 if switches else 0)
    tell = on_frame or (lambda *a: None)
    tell(None, True, 0, needed)
    if switches:
        cam.led_on()
    time.sleep(settle_s)
    on = []
    for k in range(n_frames):
        if k and every_s > 0:
            time.sleep(every_s)
        on.append(cam.snapshot())
        tell(on[-1], True, len(on), needed)
    if not switches:
        return on, None
    cam.led_off()
    time.sleep(settle_s)
    try:
        off = cam.snapshot()
        tell(off, False, needed, needed)
    finally:
        cam.led_on()
    return on, off


def _persistent(points: list[tuple[float, float]], n_frames: int, radius: float = 5.0) -> list[tuple[float, float]]:
    """Cluster points seen across frames; keep clusters seen in at least half the frames."""
    clusters: list[list[tuple[float, float]]] = []
    for p in points:
        for c in clusters:
            if math.dist(c[0], p) <= radius:
                c.append(p)
                break
        else:
            clusters.append([p])
    need = max(1, (n_frames + 1) // 2)
    return [tuple(np.mean(c, axis=0)) for c in clusters if len(c) >= need]


def _r(v, nd: int = 4):
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return None
    return round(float(v), nd)


def _f(v) -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:+.3f}"


def _date(t: float) -> str:
    return _dt.datetime.fromtimestamp(t, _dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
