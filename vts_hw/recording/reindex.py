"""Rebuilding a recording's indexes from its ``.mjpeg`` files alone (after a crash).

Reindex repairs; it never makes anything worse (docs/decisions/0026-recordings-never-lose.md):

* an index is replaced only when the rebuilt one still holds every frame the old one listed
  (same offset and length); a damaged index (a bad line before its last) is replaced, and
  kept beside as ``<name>.index.damaged.csv``. Otherwise — the ``.mjpeg`` damaged, truncated, or not the file the
  index was written for — the old index stays in place and the rebuilt one is written beside
  it as ``<name>.index.rebuilt.csv``, and the report says so;
* host receive times are not in the JPEGs: they are kept from the old index for the frames it
  already had;
* a manifest that cannot be read as a recording manifest is kept as
  ``manifest.unreadable.json`` and a fresh one is written from what the files hold;
* every file is written whole or not at all (vts_hw/files.py): on a full disk the old index
  and manifest are unchanged and the error names the file;
* a recording left ``recording`` is marked ``recovered`` (``interrupted`` says why it was never
  closed); one a running vts is still recording is refused, nothing changed (unfinished.py).
"""

from __future__ import annotations

import contextlib
import io
import mmap
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw.bounded import ANY_SIZE, TABLE, open_checked, read_bytes
from vts_hw.errors import DataError, UsageError
from vts_hw.files import WriteFailed, check_target, os_reason, write_atomic, write_json_atomic
from vts_hw.recording.axis_jpeg import inspect_jpeg
from vts_hw.recording.folder import INDEX_HEADER, MANIFEST, FrameRow, load_manifest, read_index
from vts_hw.recording.mjpeg import split_jpegs

RESERVE_NAME = ".vts-reserve"  # the recording writer's reserve, left behind by a killed recorder
REBUILT_SUFFIX = ".index.rebuilt.csv"
DAMAGED_SUFFIX = ".index.damaged.csv"
UNREADABLE_MANIFEST = "manifest.unreadable.json"


@dataclass
class CameraReindex:
    name: str
    frames: int  # frames in the rebuilt index
    host_times_kept: int
    torn: int  # frames cut short at the end, left out
    old_frames: int | None  # frames the old index listed (None: there was none, or unreadable)
    replaced: bool  # the rebuilt index is now the index
    note: str = ""  # why the old index was kept, or what was odd

    def as_dict(self) -> dict:
        return dict(self.__dict__)


@dataclass
class ReindexReport:
    folder: Path
    cameras: list[CameraReindex] = field(default_factory=list)
    manifest_note: str = ""

    def __getitem__(self, name: str) -> CameraReindex:
        for c in self.cameras:
            if c.name == name:
                return c
        raise KeyError(name)

    @property
    def problems(self) -> list[str]:
        out = [f"{c.name}: {c.note}" for c in self.cameras if c.note]
        return out + ([self.manifest_note] if self.manifest_note else [])


def _read_mjpeg(path: Path):
    """The file's bytes as a read-only map (no copy of a recording of gigabytes in memory)."""
    try:  # a regular file only: a FIFO of that name would block the open for ever (bounded.py)
        with open_checked(path, ANY_SIZE, "recording's .mjpeg") as f:
            if os.fstat(f.fileno()).st_size == 0:
                return b""
            return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except OSError as exc:
        raise DataError(f"{path}: cannot read ({os_reason(exc)})") from None


def _old_index(path: Path) -> tuple[list[FrameRow] | None, str]:
    """The old index's rows and, when it is damaged, why (its whole rows are still read, for
    their host times)."""
    if not path.exists():
        return None, ""
    try:
        return read_index(path), ""
    except DataError as exc:
        try:
            return read_index(path, lenient=True), str(exc)
        except DataError:
            return None, str(exc)


def _rebuild(data, old: dict[int, FrameRow]) -> tuple[str, int, int, int, set]:
    spans = split_jpegs(data)
    buf = io.StringIO()
    buf.write(",".join(INDEX_HEADER) + "\n")
    n = kept = torn = 0
    found = set()
    for span in spans:
        if not span.complete:
            torn += 1
            continue
        try:
            ct = inspect_jpeg(bytes(data[span.offset : span.offset + span.length])).timestamp
        except DataError:
            ct = None
        prev = old.get(span.offset)
        ht = prev.host_time if prev is not None and prev.length == span.length else None
        kept += ht is not None
        found.add((span.offset, span.length))
        buf.write(
            f"{n},{span.offset},{span.length},{'' if ct is None else f'{ct:.2f}'},{'' if ht is None else f'{ht:.6f}'}\n"
        )
        n += 1
    return buf.getvalue(), n, kept, torn, found


def reindex_camera(folder: Path, mjpeg: Path) -> CameraReindex:
    name = mjpeg.name[: -len(".mjpeg")]
    index_path = folder / f"{name}.index.csv"
    old_rows, old_problem = _old_index(index_path)
    data = _read_mjpeg(mjpeg)
    try:
        text, n, kept, torn, found = _rebuild(data, {r.offset: r for r in old_rows or []})
    finally:
        if isinstance(data, mmap.mmap):
            data.close()
    listed = old_rows or []
    lost = [r for r in listed if (r.offset, r.length) not in found]
    rebuilt = folder / f"{name}{REBUILT_SUFFIX}"
    if lost and not old_problem:
        write_atomic(rebuilt, text, encoding="ascii")
        note = (
            f"the rebuilt index would lose {len(lost)} of the {len(listed)} frame(s) the old one lists "
            f"({mjpeg.name} holds {n} whole frame(s)): the old index is kept as it was and the rebuilt "
            f"one is beside it as {rebuilt.name}"
        )
        return CameraReindex(name, n, kept, torn, len(listed), False, note)
    note = ""
    if old_problem:  # a damaged index is replaced, and kept beside for whoever wants to look
        damaged = folder / f"{name}{DAMAGED_SUFFIX}"
        write_atomic(damaged, read_bytes(index_path, TABLE, "recording index"), kept="the old index is unchanged")
        note = f"the old index was damaged ({old_problem}); it is kept as {damaged.name}"
    write_atomic(
        index_path,
        text,
        encoding="ascii",
        kept="the old index is unchanged" if index_path.exists() else "no index was written",
    )
    with contextlib.suppress(FileNotFoundError):
        rebuilt.unlink()  # an earlier rebuilt copy is now the index
    return CameraReindex(name, n, kept, torn, None if old_rows is None else len(old_rows), True, note)


def reindex(folder: str | Path) -> ReindexReport:
    """Rebuild every ``<name>.index.csv`` of ``folder`` (see the module docstring)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: not a recording folder")
    _not_being_recorded(folder)
    mjpegs = sorted(folder.glob("*.mjpeg"))
    if not mjpegs:
        raise DataError(f"{folder}: no .mjpeg files to index")
    report = ReindexReport(folder)
    for path in mjpegs:
        report.cameras.append(reindex_camera(folder, path))
    with contextlib.suppress(OSError):
        (folder / RESERVE_NAME).unlink()
    _mark_reindexed(folder, report)
    return report


def _not_being_recorded(folder: Path) -> None:
    """UsageError (exit 2) when a running vts is recording into ``folder``: its files are not to
    be rebuilt under it (an unreadable manifest is reindex's own to handle)."""
    with contextlib.suppress(DataError):
        manifest = load_manifest(folder, missing_ok=True)
        if manifest is not None and manifest.get("status") == "recording" and manifest.get("unfinished"):
            raise UsageError(
                f"{folder}: {manifest['unfinished']}: reindex it once that recording has stopped; nothing was changed"
            )


def _mark_reindexed(folder: Path, report: ReindexReport) -> None:
    mpath = folder / MANIFEST
    try:
        manifest = load_manifest(folder, missing_ok=True)
    except DataError as exc:
        keep = folder / UNREADABLE_MANIFEST
        check_target(keep, f"{MANIFEST} is unchanged")  # a device, FIFO or link there is never replaced
        try:
            os.replace(mpath, keep)
        except OSError as err:
            raise WriteFailed(keep, os_reason(err), f"{MANIFEST} is unchanged") from None
        report.manifest_note = (
            f"{exc}; it is kept as {keep.name} and a fresh manifest was written from the "
            f".mjpeg files (camera times and frame counts only)"
        )
        manifest = None
    if manifest is None:
        manifest = {"format": "vts-recording/1", "status": "recovered", "cameras": {}}
    unfinished = manifest.pop("unfinished", None)  # load_manifest's word, not the file's
    if unfinished:
        manifest["status"] = "recovered"  # the recorder never closed it
        manifest["interrupted"] = unfinished
    for c in report.cameras:
        cam = manifest.setdefault("cameras", {}).setdefault(c.name, {})
        if c.replaced:
            cam["frames"] = c.frames
            cam["torn_at_end"] = c.torn
        else:
            cam["reindex_problem"] = c.note
    manifest["reindexed"] = time.time()
    write_json_atomic(mpath, manifest, kept=f"{MANIFEST} is unchanged; the indexes were rebuilt")
