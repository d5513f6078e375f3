"""A recorded session played back as a live camera: the ``replay`` kind of :class:`vts_hw.camera.Camera`.

Any recording folder (``vts camera record``, a scan, a simulated session) can be run through
the live pipeline — the recorder, the scan session, the daily drift QA, processing — as if
the rig were there. rig.yaml::

    - name: cam1
      kind: replay
      options: {folder: /data/scan-20260301T0930Z, camera: cam1, speed: 4}

``camera`` is the camera's name in the recording (default: this entry's name); ``speed`` plays
it faster than real time (1 = as recorded).

* Playback starts at the first frame asked for (a snapshot or a stream), on the recording's
  common timeline (host receive times, from the first frame of any of its cameras), so the
  cameras of one folder stay in step.
* Every frame carries the recording's own times: ``camera_time`` as stamped, ``host_time``
  as received while recording (``time_source == "recording"``); ``clock_offset()`` is the
  recording's (median camera − host time).
* ``snapshot()`` is the frame at the current playback time; a stream yields each frame when
  its time comes and ends (:class:`~vts_hw.camera.SourceEnded`) at the end of the recording.
* Its roles (:mod:`vts_hw.camera`): frames, device information and the clock. A recording
  cannot switch its LED, has no parameters and no uptime: it has none of those roles (callers
  ask, and say "not known" or "not checked"), and ``device_info()`` says so.
"""

from __future__ import annotations

import bisect
import statistics
import threading
import time
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

from vts_hw.bounded import ANY_SIZE, TABLE, open_bounded, open_checked
from vts_hw.camera import ClockOffset, Frame, SourceEnded, kind_settings
from vts_hw.camera_stream import FrameStream
from vts_hw.errors import ConfigError, DataError
from vts_hw.recording.folder import load_manifest, read_index


class ReplayOptions(BaseModel):
    """The ``replay`` kind's own keys (``options:``)."""

    model_config = ConfigDict(extra="forbid")
    folder: Path = Field(description="the recording folder to play back")
    camera: str | None = Field(
        default=None, description="the camera's name in the recording (default: this entry's name)"
    )
    speed: float = Field(default=1.0, gt=0, le=1000, description="1 plays it as recorded; 4, four times faster")


ReplaySettings = kind_settings(
    "ReplaySettings",
    "A recording folder played back as a live camera: under `options:` the folder, the camera "
    "in it and the speed; no address.",
    ("resolution",),
    options=ReplayOptions,
)


class ReplayCamera:
    """One camera of a recording folder, played back."""

    settings = ReplaySettings

    def __init__(
        self,
        name: str,
        folder: str | Path,
        source: str | None = None,
        *,
        speed: float = 1.0,
        fps: float | None = None,
        resolution: str = "640x480",
        clock=time.time,
    ):
        self.name = name
        self.folder = Path(folder)
        self.source = source or name
        self.speed = float(speed)
        self.clock = clock
        self.resolution = resolution
        load_manifest(self.folder, missing_ok=True)  # a folder with a broken manifest is named here
        index = self.folder / f"{self.source}.index.csv"
        if not index.is_file():
            have = sorted(p.name[: -len(".index.csv")] for p in self.folder.glob("*.index.csv"))
            raise DataError(
                f"{self.folder}: no camera {self.source!r} in this recording"
                + (f" (it has {', '.join(have)})" if have else " (no .index.csv files)")
            )
        rows = read_index(index)
        if not rows:
            raise DataError(f"{index}: no frames to replay")
        self._rows = rows
        self._mjpeg = self.folder / f"{self.source}.mjpeg"
        # the timeline: host receive times of the recording (common to its cameras)
        times = [r.host_time if r.host_time is not None else r.camera_time for r in rows]
        self._times = [t for t in times if t is not None]
        if len(self._times) != len(times):
            raise DataError(f"{index}: a frame has neither a camera nor a host time; cannot replay it")
        self._origin = min([self._times[0], *_first_times(self.folder)])
        span = self._times[-1] - self._times[0]
        self.fps = float(fps or ((len(rows) - 1) / span if span > 0 else 25.0))
        self._t0: float | None = None  # monotonic time playback started
        self._lock = threading.Lock()
        self._fh = open_checked(self._mjpeg, ANY_SIZE, "recording's .mjpeg")  # a FIFO would block the open

    @classmethod
    def from_config(cls, cfg, clock=time.time) -> ReplayCamera:
        opts = cls.settings.from_entry(cfg)
        if not opts.folder.is_dir():
            raise ConfigError(f"camera {cfg.name!r} (kind replay): options.folder: no such folder {opts.folder}")
        return cls(cfg.name, opts.folder, opts.camera, speed=opts.speed, resolution=cfg.resolution_str, clock=clock)

    def __repr__(self) -> str:
        return f"ReplayCamera({self.name!r}, {str(self.folder)!r}, source={self.source!r}, speed={self.speed:g})"

    def close(self) -> None:
        self._fh.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- playback time -----------------------------------------------------------------
    def _position(self) -> float:
        """Recording time (its host timeline) now; playback starts on the first call."""
        with self._lock:
            now = time.monotonic()
            if self._t0 is None:
                self._t0 = now
            return self._origin + (now - self._t0) * self.speed

    def _index_at(self, t: float) -> int | None:
        """The last frame at or before recording time ``t`` (None past the end)."""
        if t > self._times[-1] + 1.5 / self.fps:
            return None
        return max(0, bisect.bisect_right(self._times, t) - 1)

    def _frame(self, i: int, seq: int) -> Frame:
        row = self._rows[i]
        with self._lock:
            self._fh.seek(row.offset)
            jpeg = self._fh.read(row.length)
        problems = () if len(jpeg) == row.length else ("JPEG cut short (the .mjpeg ends early)",)
        return Frame(seq, jpeg, row.camera_time, self._times[i], problems, time_source="recording")

    def _ended(self) -> SourceEnded:
        return SourceEnded(
            self.name, f"camera {self.name}: the replay of {self.folder} ({self.source}) reached its end"
        )

    # -- its roles: frames, device information, the clock ---------------------------------------------------------------
    def snapshot(self, compression: int | None = None) -> Frame:
        """The frame at the current playback time."""
        i = self._index_at(self._position())
        if i is None:
            raise self._ended()
        return self._frame(i, self._rows[i].frame)

    def open_stream(
        self,
        *,
        fps: float | None = None,
        duration: float | None = None,
        nbrofframes: int | None = None,
        first_seq: int = 0,
        stall_timeout: float = 2.0,
    ):
        return _ReplayConnection(self, first_seq, nbrofframes)

    def stream(self, **kwargs) -> FrameStream:
        return FrameStream(self, **kwargs)

    def device_info(self) -> dict[str, str]:
        return {
            "Brand": "vts-hw",
            "ProdNbr": "replay",
            "SerialNumber": f"{self.folder.name}/{self.source}",
            "Source": str(self.folder),
            "Camera": self.source,
            "Speed": f"{self.speed:g}",
            "Frames": str(len(self._rows)),
            "LED": "none: a recording cannot switch its LED (an LED switch is a no-op)",
        }

    def clock_offset(self, samples: int = 5) -> ClockOffset:
        """The recording's own offset: median camera − host time of its frames."""
        d = [r.camera_time - r.host_time for r in self._rows if r.camera_time is not None and r.host_time is not None]
        if not d:
            return ClockOffset(0.0, 0.0, self.clock(), "recording (no camera stamps)", 0, source="receipt")
        med = statistics.median(d)
        spread = max(abs(x - med) for x in d)
        return ClockOffset(med, spread, self._times[0], "recording", len(d), source="recording")


class _ReplayConnection:
    """Frames from the current playback time on, each when its time comes."""

    def __init__(self, cam: ReplayCamera, first_seq: int, nbrofframes: int | None):
        self.cam = cam
        self.seq = first_seq
        self.left = nbrofframes
        self._closed = threading.Event()

    def close(self) -> None:
        self._closed.set()

    def __iter__(self):
        cam = self.cam
        i = cam._index_at(cam._position())
        if i is None:
            raise cam._ended()
        while not self._closed.is_set():
            if self.left is not None and self.left <= 0:
                return
            due = cam._times[i]
            wait = (due - cam._position()) / cam.speed
            if wait > 0 and self._closed.wait(wait):
                return
            yield cam._frame(i, self.seq)
            self.seq += 1
            if self.left is not None:
                self.left -= 1
            i += 1
            if i >= len(cam._times):
                raise cam._ended()


def _first_times(folder: Path) -> list[float]:
    """The host (else camera) time of the first frame of each camera of a recording folder."""
    out = []
    for index in folder.glob("*.index.csv"):
        try:
            with open_bounded(index, TABLE, "recording index", encoding="ascii") as fh:  # no device, no FIFO
                fh.readline()
                parts = fh.readline().strip().split(",")
            t = parts[4] or parts[3]
            out.append(float(t))
        except (OSError, ValueError, IndexError, UnicodeDecodeError):
            continue  # a camera of the folder that cannot be read does not move the timeline
    return out
