"""A scan started from the Scan page: the same ``ScanSession`` and ``LiveMotion`` as `vts scan
start --live`, in a worker thread, its frames handed to the console's frames hub.

:class:`ScanRun` does what the command does and nothing more: checks, records, fires, waits,
stops (procedures/scan.py), the live path tracking the patient (procedures/scan_live.py). What
the console adds is around it (docs/decisions/0060 and 0065):

* before the session opens its streams, ``hub.attach(cameras)`` (the hub closes its own reader
  of those cameras: a camera never sees two viewers); the session's ``on_frame`` is the live
  path's tap then ``hub.feed`` (both only append to memory); ``hub.detach`` once it stopped;
* a view of it for the page (:meth:`ScanRun.view`), read afresh at each call: the live
  estimate with its status and age, each figure with whether it is known, the breathing
  traces of the last ``TRACE_S`` seconds (sampled from the live estimate; a stretch not
  TRACKING is a gap, never a line), the recorded and dropped frames per camera;
* alerts (PATIENT MOVED, PATIENT NOT TRACKED): each kept with the time it reached the console,
  until someone acknowledges it (:meth:`ScanRun.acknowledge`: who and when);
* the end: the summary in the command's words (procedures/scan_summary.py) and its verdict;
* its outcome in the action log (``on_said(what, detail)``): ``scan started`` once it records,
  ``scan ended`` with its status and verdict, or ``scan not started`` and why; a scan that did
  not start leaves no folder holding nothing (a full disk: the folder made, nothing written).
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

from vts_hw.errors import VtsError
from vts_hw.procedures.scan import ScanSession, ScanStatus
from vts_hw.procedures.scan_live import LiveMotion
from vts_hw.procedures.scan_summary import summary_lines, verdict
from vts_hw.room import Room
from vts_hw.tracking.live.estimator import LiveSettings

TRACE_S = 30.0  # the breathing trace shown: the last this many seconds
SAMPLE_S = 0.1  # how often the live estimate is sampled for the traces
STATS_S = 2.0  # how often the view's latency figures are computed
NOTES_KEPT = 50

log = logging.getLogger(__name__)

__all__ = ["ScanRun", "ScanBusy", "clean", "drop_if_empty"]


def drop_if_empty(folder: Path) -> bool:
    """Remove ``folder`` when it holds nothing (no file with a byte in it): True when it is gone
    (or was never made); False when something in it is kept."""
    if not folder.is_dir() or folder.is_symlink():
        return not folder.exists()
    for root, dirs, files in os.walk(folder):
        if any(os.path.islink(os.path.join(root, d)) for d in dirs):
            return False
        for f in files:
            try:
                if os.lstat(os.path.join(root, f)).st_size > 0:
                    return False
            except OSError:
                return False
    try:
        for root, dirs, files in os.walk(folder, topdown=False):
            for f in files:
                os.unlink(os.path.join(root, f))
            for d in dirs:
                os.rmdir(os.path.join(root, d))
        os.rmdir(folder)
    except OSError as exc:
        log.warning("%s: an empty scan folder could not be removed (%s)", folder, exc.strerror or exc)
        return False
    return True


class ScanBusy(VtsError):
    """A scan is already running in this console (one at a time: one set of cameras)."""


def clean(x):
    """``x`` for JSON: NaN and infinities as None (not known), tuples as lists, floats rounded."""
    if isinstance(x, float):
        return round(x, 4) if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean(v) for v in x]
    return x


class ScanRun:
    """One scan of ``rig`` into ``folder``, started by ``user``. ``hub``: the console's frames
    hub; ``open_room()``: the scan's room (``Room(rig)``: its cameras and trigger, opened for the
    scan and closed when it ends)."""

    def __init__(
        self,
        rig,
        folder: Path,
        hub,
        open_room: Callable[[], Room],
        *,
        user: str,
        reference_s: float = 10.0,
        duration: float | None = None,
        clock=time.time,
        marker_names=None,
        on_said=None,
    ):
        self.rig, self.folder, self.hub, self.user = rig, Path(folder), hub, user
        #: the console's MarkerNames (names.py): the live tracker names the patient's band markers there
        self.marker_names = marker_names
        self.open_room = open_room
        #: on_said(what, detail): the scan's outcome for the action log (None: not said)
        self.on_said = on_said
        self.reference_s, self.duration = float(reference_s), duration
        self.clock = clock
        self.names = [c.name for c in rig.cameras]
        self.phase = "starting"  # starting | running | stopping | stopped | failed
        # the end (stopped or failed) is published as the phase only once the scan's devices are
        # closed and its outcome is in the action log: whoever sees it sees the whole end
        self._end_phase = "failed"
        self.error = ""
        self.steps: list[tuple[str, str]] = []
        self.notes: deque[str] = deque(maxlen=NOTES_KEPT)
        self.alerts: list[dict] = []
        self.session: ScanSession | None = None
        self.live: LiveMotion | None = None
        self.manifest: dict | None = None
        self.summary: dict | None = None
        self.started_at = clock()
        self.traces: dict[int, deque] = {}
        self._last_t: float | None = None
        self._stats_at = float("-inf")
        self._stats: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.stop_reason = "stopped"  # "interrupted": the console itself was stopped
        self._status: ScanStatus | None = None
        self.thread = threading.Thread(target=self._run, name="console-scan", daemon=True)

    # -- the worker ---------------------------------------------------------------------------------
    def start(self) -> ScanRun:
        self.thread.start()
        return self

    def request_stop(self, reason: str = "stopped") -> None:
        """Stop the scan (from any thread); ``reason`` goes into its manifest's stop_reason."""
        self.stop_reason = reason
        self._stop.set()
        if self.session is not None:
            self.session.request_stop()

    def stop_and_wait(self, reason: str, timeout: float) -> bool:
        """Stop the scan and wait until it is closed (the console's own end: Ctrl-C, SIGTERM):
        the wave off, the recording finalised. Whether it was, within ``timeout`` seconds."""
        self.request_stop(reason)
        self.thread.join(timeout)
        return not self.thread.is_alive()

    def _run(self) -> None:
        attached, room = False, None
        try:
            room = self.open_room()
            cameras = room.cameras  # every kind checked before any is opened
            self.live = LiveMotion(
                self.rig,
                settings=LiveSettings(reference_s=self.reference_s),
                on_alert_text=self._alert,
                on_note=self.notes.append,
                on_names=None if self.marker_names is None else self._band_names,
            )
            self.hub.attach(self.names)  # before the session opens its streams
            attached = True
            hub = self.hub
            scan_room = room
            self.session = ScanSession(
                self.rig,
                self.folder,
                cameras,
                duration=self.duration,
                live=self.live,
                on_step=lambda name, text: self.steps.append((name, text)),
                on_frame=hub.feed,
                trigger=lambda: scan_room.trigger,
            )
            if self._stop.is_set():
                raise VtsError("the scan was stopped before it started")
            self.session.start()
            self.phase = "running"
            self._say("scan started", {"reference_s": self.reference_s, "duration_s": self.duration})
            reason = "error"
            try:
                reason = self.session.wait(self._tick, SAMPLE_S)
                if reason == "stopped":
                    reason = self.stop_reason
            finally:
                self.phase = "stopping"
                self.manifest = self.session.stop(reason)
            self._finish()
        except VtsError as exc:
            self.error = str(exc)
            if self.session is not None and self.session.recorder is not None:
                self.manifest = self.session.stop("error")
                self._finish()
        except Exception as exc:  # a bug: said on the page, what was recorded is closed and kept
            self.error = f"the scan stopped on an unexpected error: {type(exc).__name__}: {exc}"
            if self.session is not None and self.session.recorder is not None:
                self.manifest = self.session.stop("error")
                self._finish()
        finally:
            if room is not None:
                try:
                    room.close()  # what the session did not close already (a scan that did not start: all of it)
                except Exception as exc:
                    self.notes.append(f"closing the scan's devices: {exc}")
            if attached:
                self.hub.detach(self.names)
            if self.marker_names is not None:
                for n in self.names:
                    self.marker_names.clear(n, "band")
            self._said_end()
            self.phase = self._end_phase

    def _said_end(self) -> None:
        """The outcome in the action log; a folder the scan made and left empty is removed."""
        if self._end_phase == "stopped" and self.manifest is not None:
            s = self.summary or {}
            self._say(
                "scan ended",
                {
                    "status": s.get("status"),
                    "verdict": s.get("verdict"),
                    "exit": s.get("exit"),
                    **({"error": self.error} if self.error else {}),
                },
            )
            return
        kept = not drop_if_empty(self.folder)
        self._say(
            "scan not started",
            {
                "why": self.error or "it stopped before recording",
                "folder": "kept" if kept else "none left (nothing was written)",
            },
        )

    def _say(self, what: str, detail: dict) -> None:
        if self.on_said is None:
            return
        try:
            self.on_said(what, clean({"scan": self.folder.name, **detail}))
        except Exception as exc:  # the log's failures are its own (actions.StoreActions keeps them)
            log.warning("the scan's action %r could not be logged: %s", what, exc)

    def _band_names(self, camera: str, points) -> None:
        """The live tracker's names of the patient's markers on ``camera`` (a second's hold: names
        that stop coming, because the patient is not tracked, fade rather than stay)."""
        self.marker_names.set(camera, "band", points, source="the scan's live tracking", hold_s=1.0)

    def _finish(self) -> None:
        rec = self.session.recorder if self.session is not None else None
        last, code = verdict(self.folder, self.manifest, rec.write_failure if rec is not None else None)
        self.summary = {
            "status": (self.manifest or {}).get("status", "nothing recorded"),
            "lines": summary_lines(self.folder, self.manifest or {}),
            "verdict": last,
            "exit": code,
        }
        self._end_phase = "stopped"

    # -- alerts ---------------------------------------------------------------------------------------
    def _alert(self, text: str) -> None:
        """LiveMotion's ``on_alert_text`` (its own thread): kept until acknowledged."""
        with self._lock:
            alert = {
                "id": len(self.alerts) + 1,
                "scan": self.folder.name,
                "kind": "not tracking" if "NOT TRACKED" in text else "motion",
                "text": text,
                "raised": self.clock(),
                "acked_by": None,
                "acked_at": None,
            }
            self.alerts.append(alert)

    def acknowledge(self, alert_id: int, user: str) -> dict | None:
        """``user`` acknowledged alert ``alert_id`` (now); None when there is no such alert. An
        alert acknowledged already keeps its first acknowledgement."""
        with self._lock:
            for a in self.alerts:
                if a["id"] == alert_id:
                    if a["acked_by"] is None:
                        a["acked_by"], a["acked_at"] = user, self.clock()
                    return dict(a)
        return None

    # -- the traces -----------------------------------------------------------------------------------
    def _tick(self, status) -> None:
        """Every SAMPLE_S from the session's wait: the live estimate sampled for the traces."""
        self._status = status
        est = self.live.snapshot(stats=False) if self.live is not None else None
        if est is None or est.time is None or est.time == self._last_t:
            return
        self._last_t = est.time
        tracked = est.status == "TRACKING"
        for b in est.bands:
            tr = self.traces.setdefault(b.band, deque())
            v = b.breathing_mm if tracked and b.breathes and math.isfinite(b.breathing_mm) else None
            if v is None and tr and tr[-1][1] is None:
                continue  # one gap marker per stretch not tracked
            tr.append((est.time, v))
            while tr and est.time - tr[0][0] > TRACE_S:
                tr.popleft()

    # -- what the page shows --------------------------------------------------------------------------
    def view(self) -> dict:
        st = self._status  # the session's status as of its last tick (status() is not for two threads)
        cams = (
            []
            if st is None
            else [
                {
                    "name": c.name,
                    "frames": c.frames,
                    "fps": round(c.fps, 1),
                    "dropped": c.dropped,
                    "reconnects": c.reconnects,
                    "state": c.state,
                }
                for c in st.cameras
            ]
        )
        if self.manifest and self.phase == "stopped":
            cams = [
                {
                    "name": n,
                    "frames": c["frames"],
                    "fps": None,
                    "dropped": c["dropped_frames"],
                    "reconnects": c.get("reconnects", 0),
                    "state": "closed",
                }
                for n, c in self.manifest.get("cameras", {}).items()
            ]
        with self._lock:
            alerts = [dict(a) for a in self.alerts]
        return clean(
            {
                "phase": self.phase,
                "folder": self.folder.name,
                "user": self.user,
                "started_at": self.started_at,
                "error": self.error,
                "steps": list(self.steps),
                "notes": list(self.notes),
                "elapsed_s": None if st is None else st.elapsed_s,
                "duration_s": self.duration,
                "reference_s": self.reference_s,
                "cameras": cams,
                "live": self._live_view(),
                "alerts": alerts,
                "summary": self.summary,
                "traces": {str(k): list(v) for k, v in self.traces.items()},
            }
        )

    def _live_view(self) -> dict | None:
        live = self.live
        if live is None:
            return None
        now = time.monotonic()  # the latency figures (percentiles) every STATS_S, not every view
        with_stats = now - self._stats_at >= STATS_S
        est = live.snapshot(stats=with_stats)
        if est is None:  # no tracker yet
            return {"status": "OFF", "reason": live.off_reason or "live tracking not started yet"}
        if with_stats:
            self._stats_at, self._stats = now, dict(est.stats or {})
        tracked = est.status == "TRACKING" and est.six_dof is not None
        bands = [
            {
                "band": b.band,
                "markers": b.markers,
                "seen": b.seen,
                "breathes": b.breathes,
                "known": tracked and b.seen > 0 and math.isfinite(b.distance_mm),
                "displacement_mm": list(b.displacement_mm),
                "distance_mm": b.distance_mm,
                "breathing_mm": b.breathing_mm,
                "rate_per_min": b.rate_per_min,
                "rate_range_per_min": None if b.rate_range is None else list(b.rate_range),
            }
            for b in est.bands
        ]
        return {
            "status": est.status,
            "reason": est.reason,
            "for_s": est.status_for_s,
            "age_s": est.age_s,
            "phase": est.phase,
            "note": est.note,
            "frame": est.frame,
            "state": est.state,
            "six_dof": None if est.six_dof is None else list(est.six_dof),
            "six_known": tracked,
            "move_mm": est.move_mm if est.six_dof is not None else None,
            "turn_deg": est.turn_deg if est.six_dof is not None else None,
            "alerts": est.alerts,
            "bands": bands,
            "latency_ms_p95": self._stats.get("latency_ms_p95"),
            "live_dropped": sum((self._stats.get("live_dropped") or {}).values()),
        }
