"""Reading recording folders: per camera the JPEGs exactly as received, an index, and a manifest.

Layout (docs/design.md "Recording"):

* ``manifest.json`` — cameras, times, software version, rig digest, frame counts and gaps;
* ``<name>.mjpeg`` — the JPEGs concatenated, append-only, written frame by frame;
* ``<name>.index.csv`` — ``frame,offset,length,camera_time,host_time``, a line per frame.

Writing them is ``recording_writer.py``; rebuilding an index from the ``.mjpeg`` alone is
``reindex.py``. This module reads: the index, the manifest (checked for its shape), and a
summary of the frames of a folder, an ``.mjpg`` capture or a JPEG file.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw.bounded import SMALL, TABLE, read_bytes
from vts_hw.errors import DataError
from vts_hw.recording.axis_jpeg import inspect_jpeg
from vts_hw.recording.mjpeg import read_frames_file
from vts_hw.recording.unfinished import judge

INDEX_HEADER = ["frame", "offset", "length", "camera_time", "host_time"]


# -- reading -------------------------------------------------------------------------
MANIFEST = "manifest.json"


def load_manifest(folder: str | Path, *, missing_ok: bool = False) -> dict | None:
    """The manifest of a recording folder, checked for its shape; DataError naming the file
    when it cannot be read or is not a recording manifest (a mapping whose ``cameras`` is a
    mapping of camera name to a mapping). ``missing_ok``: None when there is no manifest.

    A manifest left ``status: recording`` is read for what it is (unfinished.py): its status
    stays ``recording`` while its writer runs, and is ``interrupted`` once it is gone (killed,
    the computer stopped) or cannot be asked; ``unfinished`` then says which, in one sentence.
    On disk nothing changes (``vts recording reindex`` marks it recovered)."""
    path = Path(folder) / MANIFEST
    try:
        raw = read_bytes(path, SMALL, "recording manifest")
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
        raise DataError(f'{path}: not a recording manifest ("cameras" must map each camera name to its entry)')
    for name, cam in cams.items():
        gaps = cam.get("gaps", [])
        if not isinstance(gaps, list) or not all(
            isinstance(g, dict) and _count_or_none(g.get("missing")) for g in gaps
        ):
            raise DataError(
                f"{path}: not a recording manifest (cameras.{name}.gaps must be a list of "
                f"gaps, each with a whole number of frames missing)"
            )
    data.pop("unfinished", None)  # said by this reader only, never taken from the file
    state = judge(data)
    if state is not None:
        data["status"], data["unfinished"] = state.status, state.why
    return data


def _count_or_none(v) -> bool:
    return v is None or (isinstance(v, int) and not isinstance(v, bool) and v >= 0)


def _json_kind(v) -> str:
    return {
        list: "a list",
        str: "a string",
        int: "a number",
        float: "a number",
        bool: "true/false",
        type(None): "null",
    }.get(type(v), type(v).__name__)


@dataclass
class FrameRow:
    frame: int
    offset: int
    length: int
    camera_time: float | None
    host_time: float | None


def read_index(path: Path, *, lenient: bool = False) -> list[FrameRow]:
    """The rows of a ``<name>.index.csv``. A last line that is not a whole row is the frame in
    flight when the recorder was killed: it is left out and everything before it stands. Any
    other bad line, or a file that is not an index, is a DataError naming the file (and line).
    ``lenient`` (for rebuilding an index): bad lines are skipped, every whole row is kept."""
    path = Path(path)
    try:
        raw = read_bytes(path, TABLE, "recording index")
    except OSError as exc:
        raise DataError(f"{path}: cannot read the index ({exc.strerror or exc})") from None
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not a recording index (byte {exc.start} is not ASCII text)") from None
    lines = [ln[:-1] if ln.endswith("\r") else ln for ln in text.split("\n")]
    if lines[0].split(",") != INDEX_HEADER:
        raise DataError(f"{path}: not a recording index (expected columns {','.join(INDEX_HEADER)})")
    body = [(i + 2, ln) for i, ln in enumerate(lines[1:]) if ln.strip()]
    rows = []
    for k, (lineno, line) in enumerate(body):
        row = _index_row(line)
        if row is None:
            if lenient or k == len(body) - 1:
                continue  # the last: a line cut short by a kill; everything before it stands
            shown = line if len(line) <= 60 else line[:57] + "..."
            raise DataError(
                f"{path}: line {lineno} is not a frame,offset,length,camera_time,"
                f"host_time row ({shown!r}); run 'vts recording reindex'"
            )
        rows.append(row)
    return rows


_MAX_TIME = 1e11  # epoch seconds (year 5138): beyond it a time is garbage, not a stamp


def _index_row(line: str) -> FrameRow | None:
    """One index line, or None when it is not a whole, sane row."""
    parts = line.split(",")
    if len(parts) != len(INDEX_HEADER):
        return None
    try:
        frame, offset, length = (int(x) for x in parts[:3])
        times = [float(x) if x.strip() else None for x in parts[3:]]
    except ValueError:
        return None
    if frame < 0 or offset < 0 or length <= 0:
        return None
    if any(t is not None and not (math.isfinite(t) and 0.0 <= t < _MAX_TIME) for t in times):
        return None
    return FrameRow(frame, offset, length, times[0], times[1])


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
    #: frames the index or the manifest promised (None: nothing promised, e.g. a loose .mjpeg)
    promised: int | None = None
    #: the camera's files of a recording folder that are not there
    missing_files: list[str] = field(default_factory=list)

    @property
    def whole(self) -> bool:
        """Everything promised is readable (and no file is missing)."""
        return not self.missing_files and (self.promised is None or self.frames >= self.promised)

    def as_dict(self) -> dict:
        return {**self.__dict__, "whole": self.whole}


def summarize_times(
    source: str, times: list[float | None], torn: int = 0, problems=None, fps: float | None = None
) -> FramesSummary:
    """Count, first/last camera time, frame rate and gaps (an interval over 1.5 × the median)."""
    ts = [t for t in times if t is not None]
    gaps: list[dict] = []
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
                    frames = d / med  # huge (not finite) for a median step of 1e-300 s
                    missing = int(round(frames)) - 1 if math.isfinite(frames) else len(times)
                    gaps.append(
                        {
                            "after_frame": i,
                            "camera_t0": ts[i],
                            "camera_t1": ts[i + 1],
                            "seconds": round(d, 3),
                            "missing": max(1, missing),
                        }
                    )
                elif d < 0:
                    gaps.append(
                        {
                            "after_frame": i,
                            "camera_t0": ts[i],
                            "camera_t1": ts[i + 1],
                            "seconds": round(d, 3),
                            "missing": 0,
                            "note": "time went backwards",
                        }
                    )
    return FramesSummary(
        source,
        len(times),
        len(ts),
        torn,
        ts[0] if ts else None,
        ts[-1] if ts else None,
        round(est, 3) if est else None,
        gaps,
        list(problems or []),
    )


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
