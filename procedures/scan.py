"""A scan session: every camera recording and the trigger fired, and nothing lost whatever happens.

The steps, in this order (``ScanSession.plan()`` lists them without touching the rig; the
reasons are in ``docs/decisions/0016-scan-session.md``):

1. check every camera: reachable, password accepted, the configured resolution offered;
2. check the trigger generator: its status, then frequency, duty (and levels where it has
   them) from the rig config; a square wave left running is stopped first;
3. map the trigger's device clock to host time (backends that have one);
4. measure each camera's clock offset (camera − host);
5. start recording every camera into the session folder (a thread per camera);
6. wait until every camera has delivered its first frame;
7. fire: start pulses and square wave together (``fire()``), or the square wave alone on a
   backend without start pulses; backend ``none`` records only;
8. run until ``stop()``, the duration, or Ctrl-C (the caller's ``KeyboardInterrupt``);
9. stop: square wave off, recordings closed, clock offsets measured again, the trigger clock
   mapped again, the manifest written.

Steps 1–4 touch no file: a scan that cannot start leaves nothing behind but one clear error.
From step 5 on, a failure never costs a recorded frame: a camera that drops is reconnected
while the others go on (its gap goes into the manifest), a trigger that fails to fire or is
unplugged is noted in the manifest and the recordings go on, and the manifest is rewritten
at each step so that a killed process leaves a folder ``vts recording reindex`` makes whole.
"""

from __future__ import annotations

import datetime as _dt
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw.camera import Camera, Parameters
from vts_hw.camera_led import light
from vts_hw.config import RigConfig
from vts_hw.drivers.registry import trigger_backend
from vts_hw.drivers.trigger import TriggerGenerator
from vts_hw.errors import UsageError, VtsError
from vts_hw.procedures.scan_trigger import ScanError, ScanTrigger, plain_dict
from vts_hw.recording.capture import FrameRecorder

FIRST_FRAME_TIMEOUT_S = 10.0  # a camera silent this long after the recording started: no fire
TRIGGER_POLL_S = 1.0  # how often the trigger's edges are read during the scan
RECONNECT_BACKOFF_MAX_S = 1.0  # a camera that comes back is recording again within a second
OFFSET_SAMPLES = 5


__all__ = ["ScanSession", "ScanError", "ScanTrigger", "SessionExists", "default_folder"]


class SessionExists(UsageError):
    """The session folder already holds a recording (a scan never appends to an old one)."""


@dataclass(frozen=True)
class Step:
    """One step of the plan: a short name and what it does on this rig."""

    name: str
    text: str


@dataclass(frozen=True)
class CameraState:
    name: str
    frames: int
    fps: float
    dropped: int
    reconnects: int
    state: str


@dataclass(frozen=True)
class ScanStatus:
    """What the live display shows: phase, elapsed scan time, cameras, trigger."""

    phase: str
    elapsed_s: float
    duration_s: float | None
    cameras: tuple[CameraState, ...]
    trigger: dict = field(default_factory=dict)


def default_folder(now: float | None = None, parent: str | Path = ".") -> Path:
    """``./scan-YYYYmmddTHHMMSSZ``: a new folder per scan, named by its UTC start."""
    t = _dt.datetime.fromtimestamp(time.time() if now is None else now, _dt.UTC)
    return Path(parent) / f"scan-{t:%Y%m%dT%H%M%SZ}"


def _iso(t: float) -> str:
    return _dt.datetime.fromtimestamp(t, _dt.UTC).strftime("%H:%M:%S.%f")[:-3] + "Z"


class ScanSession:
    """One scan: ``start()`` (steps 1–7), ``wait()`` (8), ``stop()`` (9) — or ``run()``.

    ``cameras`` are the rig's cameras, opened by the caller (``room.cameras``); the session checks,
    records and closes them. ``trigger()`` gives the trigger when the check needs it (``lambda:
    room.trigger``; None: the session opens the rig's). ``duration`` counts from the fire; None runs
    until :meth:`request_stop` or Ctrl-C. ``on_step(name, text)`` is told as each step is done.
    ``on_frame(camera, frame)`` is told of each frame once written, after the live path.
    """

    def __init__(
        self,
        rig: RigConfig,
        folder: str | Path,
        cameras: list[Camera],
        *,
        duration: float | None = None,
        clock=time.time,
        first_frame_timeout: float = FIRST_FRAME_TIMEOUT_S,
        on_step: Callable[[str, str], None] | None = None,
        live=None,
        on_frame: Callable[[str, object], None] | None = None,
        trigger: Callable[[], TriggerGenerator] | None = None,
    ):
        self.rig = rig
        # on_frame(camera, frame): told of each recorded frame after the live path's tap (the room
        # console's frames hub: it must return at once and is never a reason to lose a frame)
        self.on_frame = on_frame
        # live: the live motion path (procedures/scan_live.py LiveMotion), or None: records only
        self.live = live
        self.live_error = ""
        self.live_problem = ""  # the live path's word at the end: the patient was not watched, and why
        self.folder = Path(folder)
        self.duration = duration
        self.clock = clock
        self.first_frame_timeout = first_frame_timeout
        self.on_step = on_step or (lambda name, text: None)
        self.cameras: list[Camera] = list(cameras)
        self._configs = {c.name: c for c in rig.cameras}
        self.trigger = ScanTrigger(rig, clock, trigger)
        self.recorder: FrameRecorder | None = None
        self.phase = "planned"
        self.times: dict[str, float | None] = {}
        self.cam_notes: dict[str, dict] = {c.name: {} for c in self.cameras}
        self.stop_reason: str | None = None
        self.manifest: dict | None = None
        self._scan_t0: float | None = None  # monotonic time the scan clock started (the fire)
        self._stop = threading.Event()
        self._stop_lock = threading.Lock()
        self._manifest_lock = threading.RLock()  # the session's thread and the live path's alerts
        self._last_problems: list[str] = []
        self._monitor: threading.Thread | None = None
        self._rates: dict[str, deque] = {c.name: deque(maxlen=16) for c in self.cameras}

    # -- the plan ------------------------------------------------------------------------------------
    def plan(self) -> list[Step]:
        """The steps this session will take on this rig. Touches nothing."""
        r, t = self.rig, self.rig.trigger
        cfgs = [self._configs[c.name] for c in self.cameras if c.name in self._configs] or list(r.cameras)
        cams = ", ".join(f"{c.name} ({c.base_url})" for c in cfgs)
        res = sorted({c.resolution_str for c in cfgs})
        fps = sorted({f"{c.fps:g}" for c in cfgs})
        steps = [
            Step(
                "check cameras",
                f"check {len(cfgs)} camera(s) {cams}: reachable, password accepted, "
                f"{'/'.join(res)} offered, {'/'.join(fps)} fps asked; LED ring on",
            )
        ]
        backend = trigger_backend(t, str(getattr(r, "_source", None) or "rig.yaml"))  # None: backend none
        if backend is None:
            steps.append(Step("check trigger", "no trigger generator (trigger backend none): recording only"))
        else:
            levels = f", levels {t.low_v:g}..{t.high_v:g} V" if backend.levels else ""
            steps += [
                Step(
                    "check trigger",
                    f"check the {t.backend} trigger, {backend.what}, at {t.address}: "
                    f"status, stop a square wave "
                    f"left running, configure {t.frequency_hz:g} Hz, duty {t.duty:g}{levels}",
                ),
                Step("map trigger clock", "map the trigger's device clock to host time (where it has one)"),
            ]
        steps += [
            Step("measure offsets", f"measure each camera's clock offset (camera - host, {OFFSET_SAMPLES} samples)"),
            Step(
                "start recording",
                f"record every camera into {self.folder}/ (<camera>.mjpeg, <camera>.index.csv, manifest.json)",
            ),
            Step(
                "first frames",
                f"wait for the first frame of every camera (at most {self.first_frame_timeout:g} s; "
                f"else stop without firing)",
            ),
        ]
        if t.backend == "none":
            steps.append(Step("fire", "nothing to fire: the scan clock starts when every camera is recording"))
        else:
            steps.append(
                Step(
                    "fire",
                    f"start pulses ({t.pulse_ms} ms, channels 1 VTS and 2 SPECT) and the "
                    f"square wave together, or the square wave alone where the device has no "
                    f"start pulses; log to {self.folder}/trigger.csv",
                )
            )
        steps += [
            Step("run", f"record for {self.duration:g} s" if self.duration else "record until Ctrl-C"),
            Step(
                "stop",
                "stop the square wave, close the recordings, measure the clock offsets again, write the manifest",
            ),
        ]
        return steps

    # -- steps 1-7 -------------------------------------------------------------------------------------
    def start(self) -> None:
        """Check, measure, record, wait for first frames, fire. Raises ScanError (nothing left
        running) when the scan cannot start; once recording, what was recorded is kept."""
        self.times["session_started"] = self.clock()
        self.phase = "checking"
        if self.folder.exists() and any(self.folder.iterdir()):
            raise SessionExists(f"{self.folder} is not empty: give a new folder with -o")
        try:
            self._check()
        except BaseException:
            self._close_cameras()
            self.trigger.close()
            raise
        self._start_recording()
        try:
            self._record_and_fire()
        except (ScanError, KeyboardInterrupt):
            raise  # stopped already, or the caller stops it
        except Exception as exc:  # a bug or an odd device: what is recorded is closed and kept
            self.trigger.error("start", exc)
            self.stop("error")
            raise

    def _check(self) -> None:
        self._check_cameras()
        self.on_step("check cameras", ", ".join(f"{c.name} ok" for c in self.cameras))
        self.trigger.check()
        if self.trigger.present:
            gen = self.trigger.gen
            if gen is None:  # check() opens the generator the rig names, or raises
                raise RuntimeError("the trigger generator was not opened by its check")
            st = self.trigger.info.get("confirmed") or {}
            self.on_step("check trigger", f"{gen.name}: {st.get('frequency_hz')} Hz, duty {st.get('duty')}")
        self._measure_offsets("clock_offset_before", strict=True)
        self.on_step(
            "measure offsets",
            ", ".join(f"{n} {d['clock_offset_before']['offset_s']:+.3f} s" for n, d in self.cam_notes.items()),
        )

    def _record_and_fire(self) -> None:
        self.on_step("start recording", str(self.folder))
        self._wait_first_frames()
        self.on_step("first frames", "every camera is recording")
        self.phase = "firing"
        self.trigger.fire()
        self._scan_t0 = time.monotonic()
        self.times["scan_started"] = self.trigger.info.get("fire_time") or self.clock()
        self.phase = "running"
        if self.trigger.present:
            self._monitor = threading.Thread(target=self._watch_trigger, name="scan-trigger", daemon=True)
            self._monitor.start()
        self._write_manifest()
        t = self.trigger.info
        self.on_step(
            "fire",
            "recording only"
            if not self.trigger.present
            else (f"{t['mode']} at {_iso(t['fire_time'])}" if t.get("fired") else f"FAILED: {t['errors'][-1]}"),
        )

    def _check_cameras(self) -> None:
        failures: list[VtsError] = []
        if not self.cameras:
            raise ScanError("cannot start the scan: no cameras were given")
        for cam in self.cameras:
            try:
                cfg = self.rig.camera(cam.name)
                info = cam.device_info()
                self.cam_notes[cfg.name].update(
                    url=cfg.base_url,
                    resolution=cfg.resolution_str,
                    fps_asked=cfg.fps,
                    device={k: info.get(k) for k in ("ProdNbr", "SerialNumber", "Version") if k in info},
                )
                self._check_image(cam, cfg)
                self.cam_notes[cfg.name]["led"] = light(cam)  # on: the markers are bright only with it on
            except VtsError as exc:
                failures.append(exc)
        if failures:
            raise ScanError("cannot start the scan: " + "; ".join(str(e) for e in failures), failures[0].exit_code)

    def _check_image(self, cam: Camera, cfg) -> None:
        if not isinstance(cam, Parameters):
            self.cam_notes[cfg.name]["parameters"] = "none (this kind of camera has no parameters)"
            return
        try:
            offered = cam.get_params("Properties.Image").get("Properties.Image.Resolution", "")
        except VtsError:
            offered = ""  # older firmware does not list them: the stream request will tell
        sizes = [s.strip().lower() for s in offered.split(",") if s.strip()]
        if sizes and cfg.resolution_str.lower() not in sizes:
            raise ScanError(f"camera {cfg.name} does not offer {cfg.resolution_str} (it offers {offered})")
        fps = cam.get_params("Image.I0").get("Image.I0.Stream.FPS", "")
        if fps.isdigit() and 0 < int(fps) < cfg.fps:
            self.cam_notes[cfg.name]["warning"] = f"the camera limits its streams to {fps} fps"

    def _measure_offsets(self, key: str, strict: bool) -> None:
        failures = []
        for cam in self.cameras:
            try:
                self.cam_notes[cam.name][key] = plain_dict(cam.clock_offset(OFFSET_SAMPLES))
            except VtsError as exc:
                self.cam_notes[cam.name][key] = {"error": str(exc)}
                failures.append(exc)
        if failures and strict:
            raise ScanError("cannot start the scan: " + "; ".join(str(e) for e in failures))

    def _start_recording(self) -> None:
        meta = {"kind": "scan", "rig": self.rig.rig, "rig_digest": self.rig.digest, "duration_asked": self.duration}
        self.phase = "recording"
        self._live_call("prepare")
        self.recorder = recorder = FrameRecorder(
            self.cameras,
            self.folder,
            seconds=None,
            meta=meta,
            max_backoff=RECONNECT_BACKOFF_MAX_S,
            on_frame=self._frame_hook(),
        )
        self.times["recording_started"] = recorder.recording.started
        self.trigger.attach_log(self.folder / "trigger.csv")
        self._live_call("start")
        self._write_manifest()
        recorder.start()

    def _wait_first_frames(self) -> None:
        deadline = time.monotonic() + self.first_frame_timeout
        while True:
            prog = self._started().progress.values()
            dead = [p for p in prog if p.error]
            if dead:
                why = "; ".join(f"camera {p.name}: {p.error}" for p in dead)
                break
            if all(p.frames > 0 for p in prog):
                self.times["first_frames"] = self.clock()
                return
            if time.monotonic() > deadline:
                why = (
                    ", ".join(f"camera {p.name}" for p in prog if not p.frames)
                    + f" delivered no frame within {self.first_frame_timeout:g} s"
                )
                break
            time.sleep(0.02)
        self.trigger.error("not fired", why)
        self.stop("no first frame")
        raise ScanError(f"scan stopped before the trigger: {why}; what was recorded is in {self.folder}")

    def _watch_trigger(self) -> None:
        while not self._stop.wait(TRIGGER_POLL_S):
            self.trigger.poll()

    # -- step 8 ------------------------------------------------------------------------------------
    def request_stop(self) -> None:
        """Ask :meth:`wait` to return (from any thread)."""
        self._stop.set()

    def wait(self, on_tick: Callable[[ScanStatus], None] | None = None, interval: float = 0.5) -> str:
        """Until the duration, :meth:`request_stop`, or Ctrl-C (raised to the caller).
        Returns why it ended: ``duration`` or ``stopped``."""
        next_tick = time.monotonic()
        while True:
            now = time.monotonic()
            if self._stop.is_set():
                return "stopped"
            if self.recorder is not None and self.recorder.write_failure is not None:
                return "disk full"
            if self.duration is not None and self._scan_t0 is not None and now - self._scan_t0 >= self.duration:
                return "duration"
            if on_tick is not None and now >= next_tick:
                on_tick(self.status())
                next_tick = now + interval
            time.sleep(0.05)

    def status(self) -> ScanStatus:
        """A snapshot for the live display (fps over the last two seconds)."""
        now = time.monotonic()
        cams = []
        if self.recorder is not None:
            for p in self.recorder.progress.values():
                hist = self._rates[p.name]
                hist.append((now, p.frames))
                while len(hist) > 2 and now - hist[1][0] >= 2.0:
                    hist.popleft()
                (t0, f0) = hist[0]
                fps = (p.frames - f0) / (now - t0) if now - t0 > 0.2 else 0.0
                quiet = p.last_frame is None or now - p.last_frame > 1.0
                state = p.error or ("reconnecting" if quiet and p.frames else "waiting" if quiet else "ok")
                cams.append(CameraState(p.name, p.frames, fps, p.dropped, p.reconnects, state))
        elapsed = now - self._scan_t0 if self._scan_t0 is not None else 0.0
        return ScanStatus(self.phase, elapsed, self.duration, tuple(cams), self.trigger.live())

    # -- step 9 ------------------------------------------------------------------------------------
    def stop(self, reason: str = "stopped") -> dict:
        """Square wave off, recordings closed, offsets measured again, manifest written.

        Safe in any state and more than once (later calls return the same manifest); returns
        the manifest ({} when nothing was recorded)."""
        with self._stop_lock:
            if self.manifest is not None:
                return self.manifest
            self.stop_reason = reason
            self.phase = "stopping"
            self._stop.set()
            self.times["stopped"] = self.clock()
            stop_mono = time.monotonic()
            if self._monitor is not None:
                self._monitor.join(timeout=10)
            self.trigger.stop()
            self._live_call("stop")  # its alerts in the manifest before the recording closes
            self.live_problem = str(getattr(self.live, "problem", "") or "")
            if self.recorder is None:
                self.trigger.finish()
                self._close_cameras()
                self.phase = "stopped"
                self.manifest = {}
                return self.manifest
            recorder = self.recorder
            recorder.finish("recording")  # closed; the status is set below, last
            self._note_trailing_gaps(stop_mono)
            self._measure_offsets("clock_offset_after", strict=False)
            self.trigger.finish()
            self.times["finished"] = self.clock()
            problems = self._problems()
            rec = recorder.recording
            rec.status = "failed" if reason == "no first frame" else ("partial" if problems else "complete")
            self.manifest = self._write_manifest(problems)
            self._close_cameras()
            self.phase = "stopped"
            return self.manifest

    def _note_trailing_gaps(self, stop_mono: float) -> None:
        """A camera silent at the end (still off the network when the scan stopped) has a gap
        that no later frame reveals: it is added here."""
        recorder = self._started()
        rec = recorder.recording
        for cam in self.cameras:
            p = recorder.progress[cam.name]
            if p.last_frame is None:
                continue
            silent = stop_mono - p.last_frame
            if silent > max(1.0, 3.0 / cam.fps):
                w = rec.writers[cam.name]
                rec.add_gap(
                    cam.name,
                    {
                        "after_frame": w.frames - 1,
                        "camera_t0": w.last_camera_time,
                        "camera_t1": None,
                        "missing": int(round(silent * cam.fps)),
                        "reason": f"no frames for the last {silent:.1f} s of the scan",
                        "host_time": self.times["stopped"],
                    },
                )

    def _problems(self) -> list[str]:
        out = []
        recorder = self._started()
        rec = recorder.recording
        for name, gaps in rec.gaps.items():
            p = recorder.progress[name]
            if p.error:
                out.append(p.error if p.error.startswith(f"camera {name}") else f"camera {name}: {p.error}")
            if gaps:
                missing = sum(g.get("missing", 0) for g in gaps)
                out.append(
                    f"camera {name}: {missing} frame(s) missing in {len(gaps)} gap(s), {p.reconnects} reconnect(s)"
                )
            if "error" in (self.cam_notes[name].get("clock_offset_after") or {}):
                out.append(f"camera {name}: clock offset after the scan not measured")
        out += [f"trigger: {e}" for e in self.trigger.info["errors"]]
        if recorder.write_failure is not None:
            out.append(f"recording stopped: {recorder.write_failure}")
        return out

    def _started(self) -> FrameRecorder:
        """The recorder, once :meth:`_start_recording` has made it (RuntimeError before)."""
        if self.recorder is None:
            raise RuntimeError("the recording has not started")
        return self.recorder

    def _live_call(self, step: str) -> None:
        """``live.prepare/start/stop(self)``: a failure of the live path is noted and never stops
        or loses the recording (the live path is then off)."""
        if self.live is None:
            return
        try:
            getattr(self.live, step)(self)
        except Exception as exc:
            self.live_error = f"live tracking failed at {step}: {type(exc).__name__}: {exc}"
            if step != "stop":
                self.live = None
                if self.recorder is not None:
                    self.recorder.on_frame = self._frame_hook()

    def _frame_hook(self) -> Callable[[str, object], None] | None:
        """The recorder's ``on_frame``: the live path's tap, then :attr:`on_frame` (even when the
        tap raised: the recorder counts that and goes on)."""
        live = None if self.live is None else self.live.on_frame
        extra = self.on_frame
        if live is None or extra is None:
            return live or extra

        def both(camera: str, frame) -> None:
            try:
                live(camera, frame)
            finally:
                extra(camera, frame)

        return both

    def update_manifest(self, change: Callable[[dict], None]) -> dict | None:
        """``change(meta)`` on the manifest's top level, then the manifest rewritten whole
        (atomically, under the session's manifest lock: no entry of another writer is lost).
        From any thread; None once the recording is closed."""
        with self._manifest_lock:
            if self.recorder is None or self.recorder.recording.status != "recording":
                return None
            change(self.recorder.recording.meta)
            return self._write_manifest(self._last_problems)

    def _write_manifest(self, problems: list[str] | None = None) -> dict:
        with self._manifest_lock:
            rec = self._started().recording
            self._last_problems = list(problems or [])
            for name, notes in self.cam_notes.items():
                rec.notes[name].update(notes)
            rec.meta["scan"] = {
                "times": dict(self.times),
                "duration_asked": self.duration,
                "stop_reason": self.stop_reason,
                "problems": problems or [],
                "steps": [s.name for s in self.plan()],
                **({"live_error": self.live_error} if self.live_error else {}),
                **({"live_problem": self.live_problem} if self.live_problem else {}),
            }
            rec.meta["trigger"] = self.trigger.info
            for _attempt in range(2):  # a camera thread may be adding its notes at this very moment
                try:
                    return rec.write_manifest()
                except RuntimeError:
                    time.sleep(0.01)
            return rec.write_manifest()  # the third time, its error raised

    def _close_cameras(self) -> None:
        for cam in self.cameras:
            cam.close()

    # -- all of it ---------------------------------------------------------------------------------
    def run(self, on_tick: Callable[[ScanStatus], None] | None = None) -> dict:
        """start(), wait(), stop(); Ctrl-C stops cleanly (reason ``interrupted``)."""
        self.start()
        reason = "interrupted"
        try:
            reason = self.wait(on_tick)
        finally:
            manifest = self.stop(reason)
        return manifest
