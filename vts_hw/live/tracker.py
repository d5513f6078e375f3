"""The live worker: frames from the tap decoded (grey, full resolution), detected, grouped
across cameras by time, matched and triangulated over N views, mapped to the SPECT frame, and
fed to the estimator -- in one thread of its own, beside the recording.

The worker never holds up the recording: it reads only what the tap gives it (bounded
queues that drop the oldest for the live path) and everything it does happens in its own
thread. An alert is handed to ``on_alert(alert, estimate)``, which must return at once (the
scan session queues it for its own thread). A failure in the worker ends the live path
with its reason in :meth:`LiveTracker.snapshot`; the recording goes on.
"""

from __future__ import annotations

import threading
import time
import traceback
from collections import deque
from typing import Callable

import cv2
import numpy as np

from vts_hw.live.estimator import LiveEstimate, LiveEstimator, LiveSettings
from vts_hw.live.grouping import FrameGrouper, FrameSet, Pending
from vts_hw.live.tap import FrameTap
from vts_hw.vision.detect import DEFAULT as DEFAULT_DETECTOR, DetectorSettings, detect
from vts_hw.vision.multiview import ViewGeometry, match_views

__all__ = ["LiveTracker"]

LATENCY_KEEP = 200_000


class LiveTracker:
    """``cameras``: ``{name: calibrated camera}`` (two or more; frames of other cameras are
    ignored); ``motion``: the rig's ``motion:`` section; ``mapping``: VTS → SPECT (anything
    with ``apply``) or None (positions stay in the calibration's frame); ``clock_offsets``:
    per camera its clock minus host clock (s); ``fps``: the cameras' frame rate."""

    def __init__(self, cameras: dict, motion, *, mapping=None, clock_offsets: dict | None = None,
                 fps: float = 25.0, settings: LiveSettings | None = None,
                 detector: DetectorSettings = DEFAULT_DETECTOR, queue_len: int = 4,
                 on_alert: Callable | None = None, max_px: float = 2.0):
        self.names = list(cameras)
        self.geo = ViewGeometry([cameras[n] for n in self.names], self.names)
        self.mapping = mapping
        self.offsets = dict(clock_offsets or {})
        self.detector = detector
        self.max_px = max_px
        self.on_alert = on_alert
        cam0 = self.geo.cams[0]
        if mapping is not None:
            est = LiveEstimator(motion, settings, frame="spect", axis=(0.0, 0.0, 1.0),
                                toward=mapping.apply(cam0.center))
        else:
            est = LiveEstimator(motion, settings, frame="vts", axis=cam0.R.T @ np.array([0.0, 0.0, 1.0]),
                                toward=cam0.center)
        self.estimator = est
        self.tap = FrameTap(self.names, queue_len)
        self.grouper = FrameGrouper(len(self.names), 0.5 / fps, 1.5 / fps)
        self.latency: deque[tuple[float, float]] = deque(maxlen=LATENCY_KEEP)  # (from last, from first) s
        self.sets = 0
        self.undecodable = 0
        self.error = ""
        self._index = {n: i for i, n in enumerate(self.names)}
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- the hook -------------------------------------------------------------------------------
    def on_frame(self, camera: str, frame) -> None:
        """Called by the recorder after it wrote ``frame``: queue it for the live path."""
        self.tap.put(camera, frame)

    def start(self) -> "LiveTracker":
        self._thread = threading.Thread(target=self._run, name="live-tracker", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        self.tap.wake()
        if self._thread is not None:
            self._thread.join(timeout)

    # -- the worker -----------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                items = self.tap.take(0.1)
                for name, arrival, frame in items:
                    p = self._detect(name, arrival, frame)
                    if p is not None:
                        self.grouper.add(p)
                for fs in self.grouper.ready(time.monotonic()):
                    self._estimate(fs)
        except Exception as exc:   # the live path ends; the recording is not touched
            self.error = f"live tracking stopped: {type(exc).__name__}: {exc}"
            self.error_trace = traceback.format_exc()

    def _detect(self, name: str, arrival: float, frame) -> Pending | None:
        gray = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            self.undecodable += 1
            return None
        blobs = detect(gray, self.detector).blobs
        uv = np.array([(b.x, b.y) for b in blobs], float).reshape(-1, 2)
        t = frame.host_time if frame.camera_time is None else frame.camera_time - self.offsets.get(name, 0.0)
        c = self._index[name]
        # undistorted now, while the set may still wait for other cameras: off the set's path
        return Pending(c, t, arrival, uv, self.geo.normalize(c, uv))

    def _estimate(self, fs: FrameSet) -> None:
        pts = [np.zeros((0, 2)) if u is None else u for u in fs.uv]
        norm = [np.zeros((0, 2)) if u is None else u for u in fs.norm]
        xyz = match_views(self.geo, pts, self.max_px, norm=norm).xyz
        if self.mapping is not None and len(xyz):
            xyz = self.mapping.apply(xyz)
        with self._lock:
            alert = self.estimator.update(fs.time, xyz)
            self.sets += 1
            now = time.monotonic()
            self.latency.append((now - fs.last_arrival, now - fs.first_arrival))
        if alert is not None and self.on_alert is not None:
            self.on_alert(alert, self.snapshot())

    # -- what it says ---------------------------------------------------------------------------
    def stats(self, last: int | None = 500) -> dict:
        """Counts, and the latency from a frame set's arrival (its last frame at the tap; and
        its first) to its markers being in the estimate: p50, p95 in ms over the ``last`` sets
        (None: all kept)."""
        with self._lock:   # the worker appends to it
            lat = list(self.latency) if last is None else \
                [self.latency[i] for i in range(max(0, len(self.latency) - last), len(self.latency))]
        lat = np.array(lat, float).reshape(-1, 2)

        def pct(col, q):
            return round(float(np.percentile(lat[:, col], q) * 1e3), 3) if len(lat) else None
        return {"sets": self.sets, "live_dropped": dict(self.tap.dropped), "tapped": dict(self.tap.received),
                "unmatched_frames": self.grouper.unmatched, "undecodable": self.undecodable,
                "latency_ms_p50": pct(0, 50), "latency_ms_p95": pct(0, 95),
                "latency_from_first_frame_ms_p50": pct(1, 50), "latency_from_first_frame_ms_p95": pct(1, 95),
                "error": self.error}

    def snapshot(self) -> LiveEstimate:
        with self._lock:
            return self.estimator.snapshot(self.stats())
