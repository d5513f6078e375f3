"""The live worker: frames from the tap decoded (grey, full resolution), detected, grouped
across cameras by time, matched and triangulated over N views, mapped to the SPECT frame, and
fed to the estimator -- in one thread of its own, beside the recording; and a watch thread
that says, a few times a second, whether the patient is tracked (:mod:`vts_hw.tracking.live.watch`).

The worker never holds up the recording: it reads only what the tap gives it (bounded
queues, ``queue_len`` frames per camera, that drop the oldest for the live path: when it falls
behind it works on the newest frames and counts the others) and everything it does happens in
its own thread. What a view reads (:meth:`LiveTracker.snapshot`) is the last estimate the
worker *published* (an immutable object, replaced whole) with its status and age worked out
at the moment it is read: no lock is shared with the worker, so a view never waits for it,
and a figure the worker has not renewed shows its age and NOT TRACKING, never as current.

An alert is handed to ``on_alert(alert, estimate)`` and what the watch finds (status changes,
NOT TRACKING stretches that ended, NOT TRACKING alerts) to ``on_event(event)``; both must
return at once (the scan session queues them for its own thread). A failure in the worker
ends the live path with its reason in :meth:`LiveTracker.snapshot`; the recording goes on.
"""

from __future__ import annotations

import dataclasses
import math
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from vts_hw.pose_health import pose_health
from vts_hw.tracking.frame_sets import FrameGrouper, FrameSet, Pending
from vts_hw.tracking.live.estimator import LiveEstimate, LiveEstimator, LiveSettings
from vts_hw.tracking.live.tap import FrameTap
from vts_hw.tracking.live.watch import NOT_TRACKING, BlindAlert, Facts, Watch
from vts_hw.vision.detect import DEFAULT as DEFAULT_DETECTOR
from vts_hw.vision.detect import DetectorSettings, detect
from vts_hw.vision.multiview import ViewGeometry, match_views

__all__ = ["LiveTracker"]

LATENCY_KEEP = 200_000
DETECTED_KEEP = 64  # frames whose detection times are kept until their set (their set's last frame)
#: the parts of a frame set's latency (s each; their sum is the latency from its last frame):
#: that frame waiting for the worker, its decode and detection, the set waiting for its other
#: cameras (and their frames' detection), matching across the views, the estimator's update (the
#: model's fit among it), the published estimate
PARTS = ("queued", "detect", "grouping", "match", "fit", "publish")
GROUP_WAIT_S = 1.0  # a frame set waits this long at most for a camera that is not quiet (0048)


class LiveTracker:
    """``cameras``: ``{name: calibrated camera}`` (two or more; frames of other cameras are
    ignored); ``motion``: the rig's ``motion:`` section; ``mapping``: VTS → SPECT (anything
    with ``apply``) or None (positions stay in the calibration's frame); ``clock_offsets``:
    per camera its clock minus host clock (s); ``fps``: the cameras' frame rate; ``late_s``:
    how long without a pose is still TRACKING; ``clock``: monotonic seconds; ``space``: the
    table-and-gantry volume in the SPECT frame (:class:`~vts_hw.vision.marker_roles.TableSpace`)."""

    def __init__(
        self,
        cameras: dict,
        motion,
        *,
        mapping=None,
        clock_offsets: dict | None = None,
        fps: float = 25.0,
        settings: LiveSettings | None = None,
        detector: DetectorSettings = DEFAULT_DETECTOR,
        queue_len: int = 2,
        on_alert: Callable | None = None,
        on_event: Callable | None = None,
        max_px: float = 2.0,
        late_s: float = 0.5,
        publish_s: float = 0.1,
        clock: Callable[[], float] = time.monotonic,
        on_names: Callable | None = None,
        names_every_s: float = 0.25,
        space=None,
    ):
        self.names = list(cameras)
        self.geo = ViewGeometry([cameras[n] for n in self.names], self.names)
        self.mapping = mapping
        self.offsets = dict(clock_offsets or {})
        self.detector = detector
        self.max_px = max_px
        self.on_alert = on_alert
        self.on_event = on_event or (lambda event: None)
        #: told, at most every ``names_every_s``, each camera's named patient markers in its pixels:
        #: ``on_names(camera, [(name, x, y), ...])`` (a page labels its pictures with them)
        self.on_names, self.names_every_s, self._names_at = on_names, float(names_every_s), float("-inf")
        self.clock = clock
        self.late_s, self.publish_s = float(late_s), float(publish_s)
        cam0 = self.geo.cams[0]
        if mapping is not None:
            est = LiveEstimator(motion, settings, frame="spect", axis=(0.0, 0.0, 1.0), space=space)
        else:
            est = LiveEstimator(motion, settings, frame="vts", axis=cam0.R.T @ np.array([0.0, 0.0, 1.0]))
        self.estimator = est
        self.tap = FrameTap(self.names, queue_len)
        self.grouper = FrameGrouper(len(self.names), 0.5 / fps, max(1.5 / fps, GROUP_WAIT_S))
        self._host_minus_mono = time.time() - time.monotonic()
        self.watch = Watch(
            self.names,
            late_s=late_s,
            blind_alert_s=getattr(motion, "blind_alert_s", 3.0),
            reference_deadline_s=2.0 * est.s.reference_s,
            host_of=self.host_of,
        )
        self.facts = Facts()
        self.published: LiveEstimate = est.snapshot()
        self._published_capture: float | None = None
        self.blind_alerts: list[BlindAlert] = []
        self.latency: deque[tuple[float, float]] = deque(maxlen=LATENCY_KEEP)  # (from last, from first) s
        self.parts: deque[tuple[float, ...]] = deque(maxlen=LATENCY_KEEP)  # per set, s of each of PARTS
        self._detected: dict[float, tuple[float, float]] = {}  # a frame's arrival -> its detection's start, end
        self.sets = 0
        self.processed = {n: 0 for n in self.names}
        self.undecodable = 0
        self.error = ""
        self._delay_floor: dict[str, float] = {}
        self._index = {n: i for i, n in enumerate(self.names)}
        self._lock = threading.Lock()  # the latency list only (never held for long)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._finished = False

    def host_of(self, mono: float) -> float:
        """Host epoch s of a monotonic time of this process."""
        return mono + self._host_minus_mono

    # -- the hook -------------------------------------------------------------------------------
    def on_frame(self, camera: str, frame) -> None:
        """Called by the recorder after it wrote ``frame``: queue it for the live path."""
        self.tap.put(camera, frame)

    def start(self) -> LiveTracker:
        self._threads = [
            threading.Thread(target=self._run, name="live-tracker", daemon=True),
            threading.Thread(target=self._watch_run, name="live-watch", daemon=True),
        ]
        for t in self._threads:
            t.start()
        return self

    def stop(self, timeout: float = 5.0) -> None:
        """The threads stopped; the watch's last word (a NOT TRACKING stretch still open ends
        now) handed to ``on_event``."""
        self._stop.set()
        self.tap.wake()
        for t in self._threads:
            t.join(timeout)
        if not self._finished:
            self._finished = True
            now = self.clock()
            self.tick(now)
            for event in self.watch.finish(now):
                self.on_event(event)

    # -- the worker -----------------------------------------------------------------------------
    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                self.step(0.1)
        except Exception as exc:  # the live path ends; the recording is not touched
            self.error = f"live tracking stopped: {type(exc).__name__}: {exc}"
            self.error_trace = traceback.format_exc()

    def step(self, timeout: float, now: float | None = None) -> None:
        """One round of the worker: what the tap holds detected, frame by frame in the order they
        arrived, each set estimated as soon as it is ready (before the next frame's detection:
        a frame of the next set that came meanwhile does not hold this one up)."""
        items = self.tap.take(timeout)
        for name, arrival, frame, number in items:
            t0 = self.clock()
            p = self._detect(name, arrival, frame, number)
            self.processed[name] += 1
            if p is not None:
                self.grouper.add(p)
                self._detected[arrival] = (t0, self.clock())
                for fs in self.grouper.ready(self.clock() if now is None else now):
                    self._estimate(fs)
        if len(self._detected) > 4 * DETECTED_KEEP:  # frames that went into no set, or not last
            for k in list(self._detected)[:-DETECTED_KEEP]:
                del self._detected[k]
        for fs in self.grouper.ready(self.clock() if now is None else now):
            self._estimate(fs)

    def _detect(self, name: str, arrival: float, frame, number: int = -1) -> Pending | None:
        gray = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
        if gray is None:
            self.undecodable += 1
            return None
        blobs = detect(gray, self.detector).blobs
        uv = np.array([(b.x, b.y) for b in blobs], float).reshape(-1, 2)
        t = frame.host_time if frame.camera_time is None else frame.camera_time - self.offsets.get(name, 0.0)
        c = self._index[name]
        # how much later than its best this camera's frame arrived: frames delayed before the
        # tap (network, a busy recorder) are late even when the live path is not
        delay = self.host_of(arrival) - t
        floor = self._delay_floor[name] = min(self._delay_floor.get(name, delay), delay)
        # undistorted now, while the set may still wait for other cameras: off the set's path
        return Pending(c, t, arrival, uv, self.geo.normalize(c, uv), arrival - (delay - floor), number)

    def _estimate(self, fs: FrameSet) -> None:
        t_start = self.clock()
        pts = [np.zeros((0, 2)) if u is None else u for u in fs.uv]
        norm = [np.zeros((0, 2)) if u is None else u for u in fs.norm]
        matches = match_views(self.geo, pts, self.max_px, norm=norm)
        t_matched = self.clock()
        xyz = matches.xyz
        if self.mapping is not None and len(xyz):
            xyz = self.mapping.apply(xyz)
        est, f = self.estimator, self.facts
        phase = est.phase
        cams = np.array([np.count_nonzero(np.asarray(p.detections) >= 0) for p in matches.points], float)
        alert = est.update(fs.time, xyz, cams if len(cams) == len(xyz) else fs.n_cameras, tuple(fs.index))
        t_fitted = self.clock()
        seen, resumed, broke, seen_arrival = f.seen, f.resumed, f.broke, f.seen_arrival
        if est.observed:
            if seen is None or fs.capture - seen > self.late_s:
                resumed, broke = fs.capture, seen
            seen, seen_arrival = fs.capture, fs.last_arrival
        learned = f.learned if f.learned is not None or est.phase != "tracking" else fs.capture
        # the figures first, then the facts that say they are current: a view reading in
        # between sees old facts with new figures (never TRACKING on old figures)
        if (
            alert is not None
            or est.phase != phase
            or self._published_capture is None
            or fs.capture - self._published_capture >= self.publish_s
        ):
            # the breathing figures as last worked out: refreshed below, after this set's latency
            self.published = est.snapshot(fresh=False)  # then its capture: a reader in between overstates its age
            self._published_capture = fs.capture
        self.facts = Facts(
            est.phase,
            self.tap.first,
            seen,
            resumed,
            fs.capture,
            "" if est.observed else est.note,
            learned,
            seen_arrival,
            broke,
        )
        self.sets += 1
        now = self.clock()
        d0, d1 = self._detected.pop(fs.last_arrival, (math.nan, math.nan))
        parts = (
            d0 - fs.last_arrival,
            d1 - d0,
            t_start - (fs.last_arrival if math.isnan(d1) else d1),
            t_matched - t_start,
            t_fitted - t_matched,
            now - t_fitted,
        )
        with self._lock:
            self.latency.append((now - fs.last_arrival, now - fs.first_arrival))
            self.parts.append(parts)
        # once a second of trace, the breathing figures (a few ms): after the set's markers are in
        # the estimate, so they hold up no set's markers; the next frames that came meanwhile
        # wait (their sets' `queued`, which the latency counts)
        est.refresh()
        if self.on_names is not None and now - self._names_at >= self.names_every_s:
            self._names_at = now
            self._tell_names(matches, pts)
        if alert is not None and self.on_alert is not None:
            self.on_alert(alert, self.snapshot())

    def _tell_names(self, matches, pts) -> None:
        """Each camera's named markers (the estimator's names, through the detections that made
        each 3D point); a camera with none is told an empty list. Never fails the live path."""
        if self.on_names is None:
            return
        try:
            per: dict[str, list] = {n: [] for n in self.names}
            for name, k in self.estimator.seen_names():
                for c, d in enumerate(matches.points[k].detections):
                    if d >= 0:
                        x, y = pts[c][d]
                        per[self.names[c]].append((name, float(x), float(y)))
            for cam, named in per.items():
                self.on_names(cam, named)
        except Exception:  # a page's labels are never worth the live path
            pass

    # -- the watch ------------------------------------------------------------------------------
    def _watch_run(self) -> None:
        try:
            while not self._stop.wait(0.1):
                self.tick()
        except Exception as exc:
            self.error = f"live watch stopped: {type(exc).__name__}: {exc}"
            self.error_trace = traceback.format_exc()

    def silence(self, now: float) -> dict:
        """Per camera the seconds since its last frame reached the live path (None: none yet)."""
        return {n: None if t is None else now - t for n, t in self.tap.last.items()}

    def _facts(self) -> Facts:
        f = self.facts
        return dataclasses.replace(f, started=self.tap.first) if f.started is None else f

    def tick(self, now: float | None = None) -> list:
        """The watch evaluated at ``now`` (default the clock); what it found is handed to
        ``on_event`` and returned."""
        now = self.clock() if now is None else now
        events = self.watch.tick(now, self._facts(), self.silence(now))
        for e in events:
            if isinstance(e, BlindAlert):
                self.blind_alerts.append(e)
            self.on_event(e)
        return events

    # -- what it says ---------------------------------------------------------------------------
    def stats(self, last: int | None = 500) -> dict:
        """Counts, and the latency from a frame set's arrival (its last frame at the tap; and
        its first) to its markers being in the estimate: p50, p95 in ms over the ``last`` sets
        (None: all kept)."""
        with self._lock:  # the worker appends to it
            kept = (
                list(self.latency)
                if last is None
                else [self.latency[i] for i in range(max(0, len(self.latency) - last), len(self.latency))]
            )
        lat = np.array(kept, float).reshape(-1, 2)

        def pct(col, q):
            return round(float(np.percentile(lat[:, col], q) * 1e3), 3) if len(lat) else None

        return {
            "sets": self.sets,
            "live_dropped": dict(self.tap.dropped),
            "tapped": dict(self.tap.received),
            "processed": dict(self.processed),
            "queued": self.tap.queued(),
            "unmatched_frames": self.grouper.unmatched,
            "undecodable": self.undecodable,
            "latency_ms_p50": pct(0, 50),
            "latency_ms_p95": pct(0, 95),
            "latency_from_first_frame_ms_p50": pct(1, 50),
            "latency_from_first_frame_ms_p95": pct(1, 95),
            "error": self.error,
        }

    def latency_parts(self, last: int | None = 500) -> dict:
        """Per part of the latency (:data:`PARTS`) its p50 and p95 in ms over the ``last`` sets
        (None: all kept); a part not measured for a set (its last frame's detection not kept)
        is left out of that part's figures."""
        with self._lock:
            rows = (
                list(self.parts)
                if last is None
                else [self.parts[i] for i in range(max(0, len(self.parts) - last), len(self.parts))]
            )
        a = np.array(rows, float).reshape(-1, len(PARTS))
        out = {}
        for k, name in enumerate(PARTS):
            col = a[:, k][np.isfinite(a[:, k])]
            out[name] = (
                (round(float(np.percentile(col, 50)) * 1e3, 3), round(float(np.percentile(col, 95)) * 1e3, 3))
                if len(col)
                else (None, None)
            )
        return out

    def snapshot(self, now: float | None = None, stats: bool = True) -> LiveEstimate:
        """The last published estimate, with whether the patient is tracked *now* and the age
        of its figures. Never waits for the worker."""
        now = self.clock() if now is None else now
        f = self._facts()
        status, reason = self.watch.classify(now, f, self.silence(now))
        w = self.watch
        if status == w.status and w.since is not None:
            since = w.since
        else:  # the watch has not ticked since: as it will see it
            since = (f.seen if status == NOT_TRACKING and f.seen is not None else f.started) or now
        if self.error:
            status, reason = NOT_TRACKING, self.error
        cap = self._published_capture
        age = None if cap is None else max(0.0, now - cap)
        snap = self.published
        health: dict[str, Any] = {}
        if snap.fit_figures and age is not None:  # the pose shown, as sure as its age lets it be
            n, model_n, rms, cams = snap.fit_figures
            h = pose_health(n, model_n, rms, cams, age)
            health = {"health": h.state, "health_why": h.why, "confidence": h.confidence}
        return dataclasses.replace(
            snap,
            status=status,
            reason=reason,
            status_for_s=max(0.0, now - since),
            age_s=age,
            stats=self.stats() if stats else {},
            **health,
        )
