"""What `vts recording info` says of a recording folder: per camera, what its files hold
against what its index and the manifest promised.

A ``.mjpeg`` cut short still has an index listing every frame; a camera whose files were deleted
is still in the manifest. Counting the index's rows, or listing only the files that are there,
would call such a recording whole. Here the frames counted are the readable ones (their bytes
in the ``.mjpeg``), ``promised`` is the most the index or the manifest says the camera recorded,
and a camera of the manifest without its files is a summary of its own naming them
(:mod:`vts_hw.recording.extent` measures the same shortfalls for the analyses). A folder whose
manifest is gone, unreadable, or left ``recording`` by a writer that died promises what no one
knows: :func:`manifest_problem` says so in one sentence.
"""

from __future__ import annotations

import math
from pathlib import Path

from vts_hw.errors import DataError
from vts_hw.recording.extent import available_cameras
from vts_hw.recording.folder import MANIFEST, FramesSummary, _summarize_file, load_manifest, read_index, summarize_times
from vts_hw.recording.frames import load_camera_frames

__all__ = ["info", "folder_summaries", "shortfall", "manifest_problem"]


def _listed(manifest: dict | None, name: str) -> int | None:
    n = ((manifest or {}).get("cameras", {}).get(name) or {}).get("frames")
    return n if isinstance(n, int) and not isinstance(n, bool) and n >= 0 else None


def folder_summaries(folder: Path) -> list[FramesSummary]:
    """Per camera of the folder and of its manifest: frames readable, times, gaps, ``promised``
    and ``missing_files``, and one sentence per shortfall in ``problems``."""
    folder = Path(folder)
    note = []
    try:
        manifest = load_manifest(folder, missing_ok=True)
    except DataError as exc:  # the frames are still worth counting; the manifest's promise is unknown
        manifest, note = None, [f"manifest not read: {exc}"]
    if manifest is None and not note:
        note = [f"no {MANIFEST}: what the recording promised is not known"]
    elif manifest is not None and manifest.get("unfinished"):
        note = [manifest["unfinished"]]
    names, missing = available_cameras(folder, manifest)
    out = []
    for name in names:
        cf = load_camera_frames(folder, name)
        times = [None if not math.isfinite(t) else float(t) for t in cf.camera_time]
        indexed = len(cf.frame) + cf.beyond_end
        listed = _listed(manifest, name)
        probs = list(note)
        rows = read_index(folder / f"{name}.index.csv")
        end = max((r.offset + r.length for r in rows), default=0)
        size = cf.mjpeg.stat().st_size
        if size > end:
            probs.append(f"{size - end} bytes after the last indexed frame: run 'vts recording reindex'")
        if cf.beyond_end:
            probs.append(f"{name}.mjpeg holds {len(cf.frame)} of the {indexed} frames its index lists (cut short)")
        if listed is not None and listed > indexed:
            probs.append(f"{name}.index.csv lists {indexed} frames, the manifest {listed}")
        s = summarize_times(name, times, problems=probs)
        s.promised = max(indexed, listed or 0)
        out.append(s)
    for name in missing:
        mj, idx = folder / f"{name}.mjpeg", folder / f"{name}.index.csv"
        if mj.exists() and not idx.exists():  # the frames are there, only the index is gone
            s = _summarize_file(mj, name, [*note, "no index: run 'vts recording reindex'"])
            s.promised = _listed(manifest, name)
        else:
            s = summarize_times(name, [])
            s.promised = _listed(manifest, name)
            s.missing_files = [p.name for p in (mj, idx) if not p.exists()]
            s.problems = [
                *note,
                f"{' and '.join(s.missing_files)} missing"
                + (f" (the manifest lists {s.promised} frames)" if s.promised is not None else ""),
            ]
        out.append(s)
    return out


def manifest_problem(folder: str | Path) -> str:
    """One sentence naming the folder when its manifest does not vouch for the recording: gone,
    unreadable, or left ``recording`` by a writer that died (interrupted); '' when it is there
    and closed, or being recorded now."""
    folder = Path(folder)
    try:
        manifest = load_manifest(folder, missing_ok=True)
    except DataError as exc:
        return f"{exc} ('vts recording reindex {folder}' keeps it aside and writes a fresh one)"
    if manifest is None:
        return (
            f"{folder}: no {MANIFEST}, so what the recording promised is not known ('vts recording reindex "
            f"{folder}' writes a fresh one from the frames)"
        )
    if manifest.get("unfinished") and manifest.get("status") != "recording":
        return f"{folder}: {manifest['unfinished']} ('vts recording reindex {folder}' marks it recovered)"
    return ""


def shortfall(summaries: list[FramesSummary]) -> str:
    """One sentence of what the recording promised and does not hold ('' when whole)."""
    parts = []
    for s in summaries:
        if s.whole:
            continue
        if s.missing_files:
            parts.append(
                f"{s.source}: {' and '.join(s.missing_files)} missing"
                + (f" ({s.promised} frames promised)" if s.promised is not None else "")
            )
        else:
            parts.append(f"{s.source}: {s.frames} of {s.promised} frames promised are readable")
    return "; ".join(parts)


def info(path: str | Path) -> list[FramesSummary]:
    """Frames of a recording folder (per camera), an .mjpeg/.mjpg file, or a JPEG file."""
    p = Path(path)
    if p.is_dir():
        indexes = sorted(p.glob("*.index.csv"))
        mjpegs = sorted(p.glob("*.mjpeg"))
        if not indexes and not mjpegs:
            raise DataError(f"{p}: not a recording folder (no .mjpeg or .index.csv files)")
        return folder_summaries(p)
    if not p.exists():
        raise DataError(f"{p}: no such file or folder")
    return [_summarize_file(p, p.name)]
