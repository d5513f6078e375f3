"""Record several cameras at once into one recording folder: a thread per camera.

Each thread runs a reconnecting :class:`FrameStream` and appends every frame to the folder as
it arrives; gaps go into the manifest. One camera failing (even for good) never stops the
others, and whatever was recorded stays on disk.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from .drivers.axis import AxisCamera, AxisError
from .drivers.axis_stream import FrameStream, StreamGap
from .recording import Recording


@dataclass
class CameraProgress:
    name: str
    frames: int = 0
    dropped: int = 0
    torn: int = 0
    reconnects: int = 0
    error: str = ""
    started: float = field(default_factory=time.monotonic)
    last_frame: float | None = None

    @property
    def fps(self) -> float:
        dt = time.monotonic() - self.started
        return self.frames / dt if dt > 0 else 0.0


class Recorder:
    """Record ``cameras`` for ``seconds`` (None: until stop()) into ``folder``."""

    def __init__(self, cameras: list[AxisCamera], folder: str | Path, seconds: float | None = None,
                 meta: dict | None = None, give_up_after: float | None = None,
                 max_backoff: float = 5.0):
        self.cameras = cameras
        self.max_backoff = max_backoff  # longest wait between reconnection attempts (s)
        self.seconds = seconds
        self.give_up_after = give_up_after
        self.stop_event = threading.Event()
        self.progress = {c.name: CameraProgress(c.name) for c in cameras}
        self.recording = Recording(Path(folder), [c.name for c in cameras], dict(meta or {}))
        self._streams: dict[str, FrameStream] = {}
        self._threads: list[threading.Thread] = []

    def start(self) -> None:
        for cam in self.cameras:
            stream = FrameStream(cam, duration=self.seconds, stop_event=self.stop_event,
                                 give_up_after=self.give_up_after, max_backoff=self.max_backoff)
            self._streams[cam.name] = stream
            t = threading.Thread(target=self._run, args=(cam, stream), name=f"rec-{cam.name}", daemon=True)
            self._threads.append(t)
            t.start()

    def _run(self, cam: AxisCamera, stream: FrameStream) -> None:
        prog = self.progress[cam.name]
        try:
            for item in stream:
                if isinstance(item, StreamGap):
                    self.recording.add_gap(cam.name, {
                        "after_frame": item.after_seq, "camera_t0": item.camera_t0, "camera_t1": item.camera_t1,
                        "missing": item.missing, "reason": item.reason, "host_time": item.host_time})
                    prog.dropped += item.missing
                    continue
                self.recording.write_frame(cam.name, item.jpeg, item.camera_time, item.host_time)
                prog.frames += 1
                prog.last_frame = time.monotonic()
        except AxisError as exc:
            prog.error = str(exc)
            self.recording.notes[cam.name]["error"] = str(exc)
        except Exception as exc:  # keep the other cameras going, and say what happened
            prog.error = f"{type(exc).__name__}: {exc}"
            self.recording.notes[cam.name]["error"] = prog.error
        finally:
            prog.torn = stream.stats.torn
            prog.reconnects = stream.stats.reconnects
            self.recording.notes[cam.name].update(torn_frames_discarded=stream.stats.torn,
                                                  reconnects=stream.stats.reconnects)

    @property
    def running(self) -> bool:
        return any(t.is_alive() for t in self._threads)

    def stop(self) -> None:
        self.stop_event.set()
        for s in self._streams.values():
            s.stop()

    def wait(self, poll: float = 0.25, on_tick: Callable[["Recorder"], None] | None = None) -> None:
        while self.running:
            for t in self._threads:
                t.join(timeout=poll / max(1, len(self._threads)))
            if on_tick:
                on_tick(self)

    def finish(self, status: str | None = None) -> dict:
        self.stop()
        for t in self._threads:
            t.join(timeout=10)
        if status is None:
            status = "complete" if not any(p.error for p in self.progress.values()) else "partial"
        self.recording.close(status)
        return self.recording.manifest()
