"""What a recording should hold against what its files hold: the scan's time span, per camera.

A recording can hold less than it says: a ``.mjpeg`` cut short (its index lists frames whose
bytes are gone), an index cut short (the manifest counts more frames, up to a later camera
time), a camera of the manifest with no files, stream gaps the recorder wrote into the
manifest. An analysis of such a recording must count the missing time as time without data,
never leave it out of the scan's duration (issue 20). :func:`recording_extent` says, in host
time mapped like the frames' (exposure, through each camera's clock fit):

* ``first_s``/``last_s``: the first and last frame the recording should hold, any camera (its
  index rows, with or without bytes, and the manifest's first/last camera times; for a scan
  session, from the trigger's fire to the recording's stop, ``scan.times`` of the manifest);
* per camera: frames counted by the manifest, listed by the index, readable; first/last
  readable and expected times; the manifest's gaps and the frames they miss;
* ``cameras_missing``: cameras of the manifest left out, and why;
* ``problems``: one sentence per shortfall, for every output to carry (first: a recording never
  closed, interrupted or still being recorded, as :func:`~vts_hw.recording.folder.load_manifest` says).

JSON-ready (it goes into ``Tracks.meta["extent"]`` and so into trajectories.json).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["recording_extent", "available_cameras"]


def available_cameras(folder: Path, manifest: dict | None) -> tuple[list[str], dict[str, str]]:
    """``(names, missing)``: the cameras whose ``.index.csv`` and ``.mjpeg`` are both in the
    folder (the manifest's order first), and per camera of the manifest (or with one file of
    the two) the sentence saying what is missing."""
    names = list((manifest or {}).get("cameras", {}))
    idx = {p.name[: -len(".index.csv")] for p in folder.glob("*.index.csv")}
    mj = {p.name[: -len(".mjpeg")] for p in folder.glob("*.mjpeg")}
    found = sorted(idx & mj)
    missing = {}
    for n in sorted(set(names) | idx | mj):
        if n in idx and n in mj:
            continue
        lacks = [f"{n}{ext}" for ext, have in ((".mjpeg", n in mj), (".index.csv", n in idx)) if not have]
        listed = (manifest or {}).get("cameras", {}).get(n, {}).get("frames")
        if n in mj and n not in idx:
            why = f"camera {n}: no {n}.index.csv (run 'vts recording reindex'): left out"
        else:
            why = (
                f"camera {n}: {' and '.join(lacks)} missing"
                + (f" (the manifest lists {listed} frames)" if isinstance(listed, int) else "")
                + ": left out"
            )
        missing[n] = why
    return [n for n in names if n in found] + [n for n in found if n not in names], missing


def _map(fit, camera_time, receive_time):
    """Host times of frames from their stamps through ``fit`` (else their receive times)."""
    c = np.asarray(camera_time, float)
    r = np.asarray(receive_time, float)
    if fit is None:
        return r
    m = np.asarray(fit.host_time(c), float)
    return np.where(np.isfinite(m), m, r)


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _fin(v):
    return None if v is None or not math.isfinite(v) else float(v)


def recording_extent(
    folder, manifest: dict | None, frames, times, fits, missing: dict[str, str], period: float
) -> dict:
    """See the module. ``frames``: the :class:`~vts_hw.recording.frames.CameraFrames` used;
    ``times``: their mapped host times; ``fits``: per camera its ClockFit or None;
    ``missing``: :func:`available_cameras`'s sentences; ``period``: the frame period (s)."""
    mcams = (manifest or {}).get("cameras", {})
    cams, problems = {}, list(missing.values())
    unfinished = (manifest or {}).get("unfinished")  # load_manifest's word: being recorded, or interrupted
    if unfinished:
        problems.insert(0, f"{unfinished}; analysed up to the last frame written")
    firsts, lasts = [], []
    for cf, t in zip(frames, times):
        fit = fits.get(cf.name)
        entry = mcams.get(cf.name, {})
        t = np.asarray(t, float)
        ok = t[np.isfinite(t)]
        beyond = _map(fit, cf.beyond_camera_time, cf.beyond_host_time)
        beyond = beyond[np.isfinite(beyond)]
        first = float(ok.min()) if ok.size else math.nan
        last_read = float(ok.max()) if ok.size else math.nan
        last = max([last_read, *beyond.tolist()]) if (ok.size or beyond.size) else math.nan
        indexed = len(cf.frame) + cf.beyond_end
        listed = entry.get("frames") if isinstance(entry.get("frames"), int) else None
        mfirst, mlast = entry.get("first_camera_time"), entry.get("last_camera_time")
        if fit is not None and isinstance(mlast, (int, float)) and listed is not None and listed > indexed:
            last = max(last, float(fit.host_time(float(mlast))))
        if fit is not None and isinstance(mfirst, (int, float)):
            first = (
                min(first, float(fit.host_time(float(mfirst))))
                if math.isfinite(first)
                else float(fit.host_time(float(mfirst)))
            )
        gaps = [g for g in entry.get("gaps") or [] if isinstance(g, dict)]
        cams[cf.name] = {
            "frames_manifest": listed,
            "frames_indexed": indexed,
            "frames_readable": len(cf.frame),
            "first_s": _fin(first),
            "last_readable_s": _fin(last_read),
            "last_s": _fin(last),
            "gaps": len(gaps),
            "frames_missing_in_gaps": int(sum(g.get("missing") or 0 for g in gaps)),
        }
        if math.isfinite(first):
            firsts.append(first)
        if math.isfinite(last):
            lasts.append(last)
        span = (last - first) if math.isfinite(first) and math.isfinite(last) else math.nan
        if cf.beyond_end:
            problems.append(
                f"{cf.mjpeg.name} holds {len(cf.frame)} of the {indexed} frames its index lists "
                f"(cut short): its last {last - last_read:.1f} s of {span:.1f} s are not readable"
            )
        if listed is not None and listed > indexed:
            problems.append(
                f"{cf.name}.index.csv lists {indexed} frames, the manifest {listed}: "
                f"{listed - indexed} frame(s) of {cf.name} are not in the folder"
            )
    start = min(firsts) if firsts else math.nan
    end = max(lasts) if lasts else math.nan
    # a scan session says when the scan began (the trigger fired) and when the recording stopped:
    # time between those and the first/last frame is scan time without frames
    times = ((manifest or {}).get("scan") or {}).get("times") or {}
    fire, stopped = times.get("scan_started"), times.get("stopped")
    if _number(fire) and math.isfinite(start) and fire < start - 1.5 * period:
        problems.append(f"no frames for the first {start - fire:.1f} s after the scan started (the trigger fired)")
        start = float(fire)
    if _number(stopped) and math.isfinite(end) and stopped > end + 1.5 * period:
        problems.append(f"no frames for the last {stopped - end:.1f} s before the recording stopped")
        end = float(stopped) - 0.5 * period
    return {
        "first_s": _fin(start),
        "last_s": _fin(end),
        "frame_period_s": float(period),
        "cameras": cams,
        "cameras_missing": dict(missing),
        "problems": problems,
    }
