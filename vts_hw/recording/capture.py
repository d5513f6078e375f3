"""Record several cameras at once into one recording folder: a thread per camera.

Each thread runs a reconnecting :class:`FrameStream` and appends every frame to the folder as
it arrives; gaps go into the manifest. One camera failing (even for good) never stops the
others, and whatever was recorded stays on disk. A frame that cannot be written (disk full)
stops every camera: the files end with the last whole frame and the manifest says why.

The status of a finished recording says what it holds, never more:

* ``complete`` — every camera streamed for the whole time (frames the camera skipped are
  counted in the manifest as ``dropped_frames`` and shown, never hidden);
* ``partial`` — some camera failed, lost its stream (reconnected), or recorded nothing, or
  the disk filled up; each camera's cause is one sentence in the manifest (``error``);
* ``failed`` — no camera recorded a frame;
* ``interrupted`` — stopped early (Ctrl-C).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw.camera import Camera, CameraError, Stream, StreamGap
from vts_hw.files import WriteFailed
from vts_hw.recording.writer import Recording


@dataclass
class CameraProgress:
    name: str
    frames: int = 0
    dropped: int = 0
    torn: int = 0
    reconnects: int = 0
    error: str = ""  # why this camera recorded nothing more (one sentence naming it)
    lost: str = ""  # the stream was lost and came back (frames missing in between)
    started: float = field(default_factory=time.monotonic)
    last_frame: float | None = None

    @property
    def fps(self) -> float:
        dt = time.monotonic() - self.started
        return self.frames / dt if dt > 0 else 0.0


class FrameRecorder:
    """Record ``cameras`` (any :class:`vts_hw.camera.Camera`) for ``seconds`` (None: until
    stop()) into ``folder``."""

    def __init__(
        self,
        cameras: list[Camera],
        folder: str | Path,
        seconds: float | None = None,
        meta: dict | None = None,
        give_up_after: float | None = None,
        max_backoff: float = 5.0,
        append: bool = False,
        on_frame: Callable[[str, object], None] | None = None,
    ):
        self.cameras = cameras
        # on_frame(camera, frame): told of each frame after it is written (the live path's tap);
        # it must return at once, and its failure never stops the recording (counted below)
        self.on_frame = on_frame
        self.on_frame_errors = 0
        self.max_backoff = max_backoff  # longest wait between reconnection attempts (s)
        self.seconds = seconds
        self.give_up_after = give_up_after
        self.stop_event = threading.Event()
        self.progress = {c.name: CameraProgress(c.name) for c in cameras}
        self.recording = Recording(Path(folder), [c.name for c in cameras], dict(meta or {}), append=append)
        self.write_failure: WriteFailed | None = None  # the first frame that could not be written
        self._streams: dict[str, Stream] = {}
        self._interrupted = False
        self._threads: list[threading.Thread] = []

    def start(self) -> None:
        for cam in self.cameras:
            stream = cam.stream(
                duration=self.seconds,
                stop_event=self.stop_event,
                give_up_after=self.give_up_after,
                max_backoff=self.max_backoff,
            )
            self._streams[cam.name] = stream
            t = threading.Thread(target=self._run, args=(cam, stream), name=f"rec-{cam.name}", daemon=True)
            self._threads.append(t)
            t.start()

    def _run(self, cam: Camera, stream: Stream) -> None:
        prog = self.progress[cam.name]
        try:
            for item in stream:
                if isinstance(item, StreamGap):
                    self.recording.add_gap(
                        cam.name,
                        {
                            "after_frame": item.after_seq,
                            "camera_t0": item.camera_t0,
                            "camera_t1": item.camera_t1,
                            "missing": item.missing,
                            "reason": item.reason,
                            "host_time": item.host_time,
                        },
                    )
                    prog.dropped += item.missing
                    continue
                self.recording.write_frame(cam.name, item.jpeg, item.camera_time, item.host_time)
                prog.frames += 1
                prog.last_frame = time.monotonic()
                if self.on_frame is not None:
                    try:
                        self.on_frame(cam.name, item)
                    except Exception:
                        self.on_frame_errors += 1
        except WriteFailed as exc:  # disk full: every camera stops, what is on disk stays whole
            self.write_failure = self.write_failure or exc
            prog.error = f"camera {cam.name}: stopped: {exc}"
            self.stop_event.set()
        except CameraError as exc:
            prog.error = str(exc)
        except Exception as exc:  # keep the other cameras going, and say what happened
            prog.error = f"camera {cam.name}: {type(exc).__name__}: {exc}"
        finally:
            prog.torn = stream.stats.torn
            prog.reconnects = stream.stats.reconnects
            if not prog.error and prog.frames == 0 and not self._interrupted:
                why = stream.stats.last_error or "no frame arrived"
                prog.error = (
                    f"camera {cam.name}: recorded nothing in {self.seconds:g} s"
                    if self.seconds
                    else f"camera {cam.name}: recorded nothing"
                ) + f"; last error: {why}"
            elif not prog.error and stream.stats.reconnects:
                why = stream.stats.last_error or "the camera ended the stream early"
                prog.lost = (
                    f"camera {cam.name}: stream lost and reconnected {stream.stats.reconnects} time(s) (last: {why})"
                )
            notes = self.recording.notes[cam.name]
            notes.update(torn_frames_discarded=stream.stats.torn, reconnects=stream.stats.reconnects)
            if stream.stats.problems:
                notes["stream_notes"] = list(stream.stats.problems)
            if prog.error:
                notes["error"] = prog.error
            elif prog.lost:
                notes["problem"] = prog.lost

    @property
    def running(self) -> bool:
        return any(t.is_alive() for t in self._threads)

    def stop(self) -> None:
        self.stop_event.set()
        for s in self._streams.values():
            s.stop()

    def wait(self, poll: float = 0.25, on_tick: Callable[[FrameRecorder], None] | None = None) -> None:
        while self.running:
            for t in self._threads:
                t.join(timeout=poll / max(1, len(self._threads)))
            if on_tick:
                on_tick(self)

    def finish(self, status: str | None = None) -> dict:
        """Stop, close the recording with its status (see the module docstring; ``status``
        given overrides it, e.g. ``interrupted``) and return the manifest written."""
        self._interrupted = status == "interrupted"
        self.stop()
        for t in self._threads:
            t.join(timeout=10)
        if status is None:
            status = self.status()
        if self.write_failure is not None:
            self.recording.problems.append(str(self.write_failure))
        self.recording.close(status)
        return self.recording.manifest()

    def status(self) -> str:
        progs = list(self.progress.values())
        if not any(p.frames for p in progs):
            return "failed"
        if self.write_failure is not None or any(p.error or p.lost for p in progs):
            return "partial"
        return "complete"

    def problems(self) -> list[str]:
        """One sentence per camera that did not record all the way, and the write failure."""
        out = [p.error or p.lost for p in self.progress.values() if p.error or p.lost]
        return out
