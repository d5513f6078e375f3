"""Reading recording folders: per camera the JPEGs exactly as received, an index, and a manifest.

Layout (DESIGN.md "Recording"):

* ``manifest.json`` — cameras, times, software version, rig digest, frame counts and gaps;
* ``<name>.mjpeg`` — the JPEGs concatenated, append-only, written frame by frame;
* ``<name>.index.csv`` — ``frame,offset,length,camera_time,host_time``, a line per frame.

Writing them is ``recording_writer.py``; rebuilding an index from the ``.mjpeg`` alone is
``reindex.py``. This module reads: the index, the manifest (checked for its shape), and a
summary of the frames of a folder, an ``.mjpg`` capture or a JPEG file.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path

from .axis_jpeg import inspect_jpeg
from .errors import DataError
from .mjpeg import read_frames_file

INDEX_HEADER = ["frame", "offset", "length", "camera_time", "host_time"]


# -- reading -------------------------------------------------------------------------
MANIFEST = "manifest.json"


def load_manifest(folder: str | Path, *, missing_ok: bool = False) -> dict | None:
    """The manifest of a recording folder, checked for its shape; DataError naming the file
    when it cannot be read or is not a recording manifest (a mapping whose ``cameras`` is a
    mapping of camera name to a mapping). ``missing_ok``: None when there is no manifest."""
    path = Path(folder) / MANIFEST
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        if missing_ok:
            return None
        raise DataError(f"{Path(folder)}: not a recording folder (no {MANIFEST})") from None
    except OSError as exc:
        raise DataError(f"{path}: cannot read the manifest ({exc.strerror or exc})") from None
    try:
        data = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise DataError(f"{path}: not a recording manifest (not valid JSON)") from None
    if not isinstance(data, dict):
        raise DataError(f"{path}: not a recording manifest (expected a JSON object, got {_json_kind(data)})")
    cams = data.get("cameras", {})
    if not isinstance(cams, dict) or not all(isinstance(k, str) and isinstance(v, dict) for k, v in cams.items()):
        raise DataError(f"{path}: not a recording manifest (\"cameras\" must map each camera name to its entry)")
    return data


def _json_kind(v) -> str:
    return {list: "a list", str: "a string", int: "a number", float: "a number", bool: "true/false",
            type(None): "null"}.get(type(v), type(v).__name__)


@dataclass
class FrameRow:
    frame: int
    offset: int
    length: int
    camera_time: float | None
    host_time: float | None


def read_index(path: Path) -> list[FrameRow]:
    rows = []
    with open(path, newline="", encoding="ascii") as f:
        reader = csv.DictReader(f)
        if reader.fieldnames != INDEX_HEADER:
            raise DataError(f"{path}: not a recording index (expected columns {','.join(INDEX_HEADER)})")
        for r in reader:
            try:
                rows.append(FrameRow(int(r["frame"]), int(r["offset"]), int(r["length"]),
                                     float(r["camera_time"]) if r["camera_time"] else None,
                                     float(r["host_time"]) if r["host_time"] else None))
            except (TypeError, ValueError):
                break  # a line cut short by a kill: everything before it stands
    return rows


# -- info --------------------------------------------------------------------------
@dataclass
class FramesSummary:
    source: str
    frames: int
    with_time: int
    torn: int
    first_time: float | None
    last_time: float | None
    fps: float | None
    gaps: list[dict]
    problems: list[str]

    def as_dict(self) -> dict:
        return self.__dict__.copy()


def summarize_times(source: str, times: list[float | None], torn: int = 0, problems=None,
                    fps: float | None = None) -> FramesSummary:
    """Count, first/last camera time, frame rate and gaps (an interval over 1.5 × the median)."""
    ts = [t for t in times if t is not None]
    gaps = []
    est = fps
    if len(ts) >= 2:
        diffs = [b - a for a, b in zip(ts, ts[1:])]
        pos = sorted(d for d in diffs if d > 0)
        med = pos[len(pos) // 2] if pos else None
        if est is None and med:
            est = 1.0 / med
        if med:
            for i, d in enumerate(diffs):
                if d > 1.5 * med + 0.011:
                    gaps.append({"after_frame": i, "camera_t0": ts[i], "camera_t1": ts[i + 1],
                                 "seconds": round(d, 3), "missing": max(1, int(round(d / med)) - 1)})
                elif d < 0:
                    gaps.append({"after_frame": i, "camera_t0": ts[i], "camera_t1": ts[i + 1],
                                 "seconds": round(d, 3), "missing": 0, "note": "time went backwards"})
    return FramesSummary(source, len(times), len(ts), torn, ts[0] if ts else None, ts[-1] if ts else None,
                         round(est, 3) if est else None, gaps, list(problems or []))


def info(path: str | Path) -> list[FramesSummary]:
    """Frames of a recording folder (per camera), an .mjpeg/.mjpg file, or a JPEG file."""
    p = Path(path)
    if p.is_dir():
        indexes = sorted(p.glob("*.index.csv"))
        mjpegs = sorted(p.glob("*.mjpeg"))
        if not indexes and not mjpegs:
            raise DataError(f"{p}: not a recording folder (no .mjpeg or .index.csv files)")
        out = []
        for mj in mjpegs:
            name = mj.name[: -len(".mjpeg")]
            idx = p / f"{name}.index.csv"
            if idx.exists():
                rows = read_index(idx)
                size = mj.stat().st_size
                end = rows[-1].offset + rows[-1].length if rows else 0
                probs = []
                if size > end:
                    probs.append(f"{size - end} bytes after the last indexed frame: run 'vts recording reindex'")
                out.append(summarize_times(name, [r.camera_time for r in rows], problems=probs))
            else:
                out.append(_summarize_file(mj, name, ["no index: run 'vts recording reindex'"]))
        return out
    if not p.exists():
        raise DataError(f"{p}: no such file or folder")
    return [_summarize_file(p, p.name)]


def _summarize_file(p: Path, name: str, extra=None) -> FramesSummary:
    frames = read_frames_file(p)
    times, torn, problems = [], 0, list(extra or [])
    for i, (jpeg, probs) in enumerate(frames):
        if any("cut short" in x for x in probs):
            torn += 1
        try:
            jinfo = inspect_jpeg(jpeg)
            times.append(jinfo.timestamp)
            if jinfo.time is None:
                problems.append(f"frame {i}: no Axis time segment (not from an Axis camera?)")
        except DataError as exc:
            times.append(None)
            problems.append(f"frame {i}: {exc}")
        for q in probs:
            problems.append(f"frame {i}: {q}")
    return summarize_times(name, times, torn, problems)
