"""Writing a recording folder: per camera the JPEGs exactly as received and an index, one manifest.

* ``<name>.mjpeg`` — the JPEGs concatenated, append-only;
* ``<name>.index.csv`` — ``frame,offset,length,camera_time,host_time``, a line per frame,
  written after the frame's bytes;
* ``manifest.json`` — cameras, times, software version, rig digest, frame counts and gaps;
  written at the start (status ``recording``) and rewritten whole at every step.

What can go wrong, and what is kept (docs/decisions/0026-recordings-never-lose.md):

* a ``kill -9`` loses at most the frame in flight (both files are written with plain
  ``write()`` calls, nothing waits in a user-space buffer; ``vts recording reindex`` rebuilds
  the index from the ``.mjpeg``); the manifest names its writer (``writer``: host, pid, process
  start), so that every reader takes a recording left ``recording`` by a writer that is gone
  for interrupted (unfinished.py);
* a frame that cannot be written whole (disk full) is taken back out of both files, so they
  always end with the last whole frame, and :class:`FrameNotWritten` says how much was kept;
* the manifest can always be finalised, even on a full disk: a small reserve file is made
  when the recording starts and freed just before the manifest is written for the last time;
* an existing recording is never modified by a new one: :class:`Recording` refuses a folder
  that holds one, unless ``append=True``, which adds frames after the last whole frame and
  keeps every entry of the manifest (other cameras, gaps, the ``scan`` and ``trigger``
  sections), listing each addition under ``appended``.
"""

from __future__ import annotations

import contextlib
import os
import stat
import threading
import time
from pathlib import Path

from vts_hw import __version__
from vts_hw.errors import DataError, UsageError
from vts_hw.files import WriteFailed, check_folder, ensure_dir, open_fd, os_reason, write_json_atomic
from vts_hw.lifeline import process_record
from vts_hw.recording.folder import INDEX_HEADER, MANIFEST, load_manifest, read_index

FSYNC_EVERY_S = 1.0  # write() per frame survives a killed process; fsync bounds a power cut
RESERVE_NAME = ".vts-reserve"
RESERVE_BYTES = 256 * 1024  # room for the last manifest (and its temporary copy) on a full disk
STATUS_ORDER = ("complete", "recovered", "partial", "interrupted", "failed")


class RecordingExists(UsageError):
    """The folder already holds a recording and the caller did not ask to append to it."""


class FrameNotWritten(WriteFailed):
    """A frame could not be written whole; the files end with the last whole frame."""


def worse_status(a: str | None, b: str | None) -> str:
    """The worse of two recording statuses (unknown ones count as worst)."""

    def rank(s):
        return STATUS_ORDER.index(s) if s in STATUS_ORDER else len(STATUS_ORDER)

    return max((s for s in (a, b) if s), key=rank, default="complete")


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


class CameraWriter:
    """Append frames of one camera to ``<name>.mjpeg`` and ``<name>.index.csv``.

    ``append``: continue an existing pair of files (the index must cover the ``.mjpeg`` exactly:
    after a crash, reindex first)."""

    def __init__(self, folder: Path, name: str, append: bool = False):
        self.name = name
        self.mjpeg_path = folder / f"{name}.mjpeg"
        self.index_path = folder / f"{name}.index.csv"
        rows = []
        if append and self.index_path.exists():
            rows = read_index(self.index_path)
            end = rows[-1].offset + rows[-1].length if rows else 0
            size = self.mjpeg_path.stat().st_size if self.mjpeg_path.exists() else 0
            if size != end:
                raise DataError(
                    f"{self.mjpeg_path}: holds {size} bytes but its index ends at byte {end}: "
                    f"run 'vts recording reindex {folder}' before adding to it"
                )
        self.frames_before = len(rows)
        # regular files only, never through a symbolic link; a FIFO of that name is refused, not waited on
        self._mjpeg = open_fd(self.mjpeg_path, perms=0o644)
        try:
            self._index = open_fd(self.index_path, perms=0o644)
        except BaseException:
            os.close(self._mjpeg)
            raise
        self._offset = os.fstat(self._mjpeg).st_size
        self._index_size = os.fstat(self._index).st_size
        if self._index_size == 0:
            self._append_line(",".join(INDEX_HEADER) + "\n")
        self.frames = len(rows)
        times = [r.camera_time for r in rows if r.camera_time is not None]
        self.first_camera_time: float | None = times[0] if times else None
        self.last_camera_time: float | None = times[-1] if times else None
        self.bytes_written = 0
        self._last_sync = time.monotonic()
        self._closed = False

    @property
    def frames_added(self) -> int:
        return self.frames - self.frames_before

    def _append_line(self, line: str) -> None:
        _write_all(self._index, line.encode("ascii"))
        self._index_size += len(line)

    def write(self, jpeg: bytes, camera_time: float | None, host_time: float) -> None:
        """Append one frame to both files, or (disk full) to neither: FrameNotWritten."""
        ct = "" if camera_time is None else f"{camera_time:.2f}"
        line = f"{self.frames},{self._offset},{len(jpeg)},{ct},{host_time:.6f}\n"
        try:
            _write_all(self._mjpeg, jpeg)  # the bytes first: an index line never points past them
            _write_all(self._index, line.encode("ascii"))
        except OSError as exc:
            self._take_back()
            raise FrameNotWritten(
                self.mjpeg_path, os_reason(exc), f"kept {self.frames} whole frame(s) of {self.name}"
            ) from None
        except BaseException:  # Ctrl-C between the two writes: neither file keeps a part of this frame
            self._take_back()
            raise
        self._index_size += len(line)
        self._offset += len(jpeg)
        self.bytes_written += len(jpeg)
        self.frames += 1
        if camera_time is not None:
            if self.first_camera_time is None:
                self.first_camera_time = camera_time
            self.last_camera_time = camera_time
        now = time.monotonic()
        if now - self._last_sync >= FSYNC_EVERY_S:
            self._sync()
            self._last_sync = now

    def _take_back(self) -> None:
        """Cut both files back to the last whole frame (truncating needs no free space)."""
        for fd, size in ((self._mjpeg, self._offset), (self._index, self._index_size)):
            with contextlib.suppress(OSError):
                os.ftruncate(fd, size)

    def _sync(self) -> None:
        for fd in (self._mjpeg, self._index):
            with contextlib.suppress(OSError):
                os.fsync(fd)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._sync()
            os.close(self._mjpeg)
            os.close(self._index)


def holds_recording(folder: Path) -> bool:
    return folder.is_dir() and (
        (folder / MANIFEST).exists() or any(folder.glob("*.mjpeg")) or any(folder.glob("*.index.csv"))
    )


class Recording:
    """A recording folder being written. Use as a context manager.

    ``meta`` goes to the top level of a new manifest; when appending it goes into this
    addition's entry under ``appended`` and the existing top level is kept."""

    def __init__(self, folder, cameras: list[str], meta: dict | None = None, append: bool = False):
        self.folder = Path(folder)
        self.cameras = list(cameras)
        self.meta = dict(meta or {})
        self.append = append
        self.base: dict = {}
        check_folder(self.folder, "recording folder")  # a FIFO, device or symbolic link of that name: refused
        if holds_recording(self.folder):
            if not append:
                raise RecordingExists(
                    f"{self.folder} already holds a recording: record into a new folder, or add to it with --append"
                )
            self.base = self._existing()
        else:
            ensure_dir(self.folder, "recording folder")
        self.gaps: dict[str, list[dict]] = {name: [] for name in self.cameras}
        self.notes: dict[str, dict] = {name: {} for name in self.cameras}
        self.problems: list[str] = []
        self.started = time.time()
        self.status = "recording"
        # who writes it: a reader that finds "recording" asks whether this process still runs
        # (unfinished.py; a kill -9 leaves "recording" for ever)
        self.writer = process_record()
        self._lock = threading.Lock()
        self.writers: dict[str, CameraWriter] = {}
        created = (
            [] if append else [self.folder / f"{n}{ext}" for n in self.cameras for ext in (".mjpeg", ".index.csv")]
        )
        try:
            for name in self.cameras:
                self.writers[name] = CameraWriter(self.folder, name, append=append)
            self._make_reserve()
            self.write_manifest()
        except (OSError, WriteFailed) as exc:
            for w in self.writers.values():
                w.close()
            self._free_reserve()
            for p in created:  # empty files of a recording that never started
                with contextlib.suppress(OSError):
                    st = os.lstat(p)  # ours are regular files: anything else of that name is left alone
                    if stat.S_ISREG(st.st_mode) and st.st_size <= len(",".join(INDEX_HEADER)) + 1:
                        p.unlink()
            if isinstance(exc, WriteFailed):
                raise WriteFailed(exc.path, exc.reason, "nothing was recorded") from None
            raise WriteFailed(self.folder, os_reason(exc), "nothing was recorded") from None

    def _existing(self) -> dict:
        base = load_manifest(self.folder, missing_ok=True)
        if base is None:
            raise DataError(
                f"{self.folder}: holds recording files but no {MANIFEST}: run "
                f"'vts recording reindex {self.folder}' before adding to it"
            )
        if base.get("unfinished") and base.get("status") == "recording":  # its writer runs (unfinished.py)
            raise RecordingExists(
                f"{self.folder}: {base['unfinished']}: add to it once that recording has "
                f"stopped, or record into a new folder"
            )
        if base.get("unfinished"):
            raise DataError(
                f"{self.folder}: {base['unfinished']}: run 'vts recording reindex {self.folder}' before adding to it"
            )
        return base

    # -- the reserve -------------------------------------------------------------------------
    def _make_reserve(self) -> None:
        path = self.folder / RESERVE_NAME
        with contextlib.suppress(FileNotFoundError):
            path.unlink()  # left by a killed recorder
        fd = open_fd(path, append=False, exclusive=True, perms=0o644)
        try:
            _write_all(fd, b"\0" * RESERVE_BYTES)
        finally:
            os.close(fd)

    def _free_reserve(self) -> bool:
        try:
            (self.folder / RESERVE_NAME).unlink()
            return True
        except FileNotFoundError:
            return False

    # -- frames --------------------------------------------------------------------------------
    def write_frame(self, camera: str, jpeg: bytes, camera_time: float | None, host_time: float) -> None:
        self.writers[camera].write(jpeg, camera_time, host_time)

    def add_gap(self, camera: str, gap: dict) -> None:
        with self._lock:
            self.gaps[camera].append(gap)

    # -- the manifest ----------------------------------------------------------------------------
    def _camera_entry(self, name: str, w: CameraWriter) -> dict:
        old = dict(self.base.get("cameras", {}).get(name, {}))
        gaps = list(old.get("gaps") or []) + self.gaps[name]
        return {
            **old,
            "mjpeg": w.mjpeg_path.name,
            "index": w.index_path.name,
            "frames": w.frames,
            "first_camera_time": w.first_camera_time,
            "last_camera_time": w.last_camera_time,
            "gaps": gaps,
            "dropped_frames": sum(g.get("missing", 0) or 0 for g in gaps if isinstance(g, dict)),
            **self.notes[name],
        }

    def manifest(self) -> dict:
        with self._lock:
            cams = {name: self._camera_entry(name, w) for name, w in self.writers.items()}
        finished = None if self.status == "recording" else time.time()
        if not self.base:
            return {
                "format": "vts-recording/1",
                "software": {"name": "vts-hw", "version": __version__},
                "status": self.status,
                "started": self.started,
                "finished": finished,
                **({"problems": list(self.problems)} if self.problems else {}),
                **self.meta,
                "writer": self.writer,
                "cameras": cams,
            }
        out = dict(self.base)
        out["writer"] = self.writer
        addition = {
            "started": self.started,
            "finished": finished,
            "status": self.status,
            "software": {"name": "vts-hw", "version": __version__},
            "frames_added": {n: w.frames_added for n, w in self.writers.items()},
            **({"problems": list(self.problems)} if self.problems else {}),
            **self.meta,
        }
        out["appended"] = list(self.base.get("appended") or []) + [addition]
        out["status"] = (
            "recording" if self.status == "recording" else worse_status(self.base.get("status"), self.status)
        )
        out["cameras"] = {**self.base.get("cameras", {}), **cams}
        return out

    def write_manifest(self) -> dict:
        """Rewrite manifest.json whole (and return what was written); on a full disk, free the
        reserve and try once more."""
        path = self.folder / MANIFEST
        kept = "the frames are in the .mjpeg and index files; 'vts recording reindex' rebuilds the manifest's counts"
        data = self.manifest()
        try:
            write_json_atomic(path, data, kept=kept)
        except WriteFailed as exc:
            if exc.reason != "no space left on device" or not self._free_reserve():
                raise
            write_json_atomic(path, data, kept=kept)
        return data

    def close(self, status: str = "complete") -> None:
        for w in self.writers.values():
            w.close()
        self.status = status
        self._free_reserve()
        self.write_manifest()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if self.status == "recording":
            self.close(
                "complete" if exc_type is None else ("interrupted" if exc_type is KeyboardInterrupt else "failed")
            )
        return False


__all__ = ["CameraWriter", "FrameNotWritten", "Recording", "RecordingExists", "holds_recording", "worse_status"]
