"""Loss injected into a complete recording, through the recording's own files.

The simulated cameras of a busy machine skip frames (issue 20: about a third, in bursts of about
a second, in every camera at the same moments). To test the offline analysis against such a
recording without depending on a machine's load, a complete simulated recording is copied
frame by frame through the project's own writer (:class:`~vts_hw.recording.writer.Recording`)
leaving frames out, and every run of frames left out is put in the manifest the way the recorder
puts a stream gap (``vts_hw/recording/capture.py``: ``after_frame``, ``camera_t0``,
``camera_t1``, ``missing``, ``reason``, ``host_time``). As with the recorder, frames missing
before a camera's first frame or after its last leave no gap entry (the stream cannot know).

Patterns (per camera a mask of the frames to leave out, by the index's host receive time):
:func:`bursts` (the same moments in every camera), :func:`random_frames`, :func:`camera_gone`.
Other damage: :func:`cut_mjpeg` (a ``.mjpeg`` cut short, its index whole) and
:func:`remove_camera` (a camera's files missing).
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from vts_hw.recording.folder import load_manifest, read_index
from vts_hw.recording.writer import Recording

__all__ = [
    "lossy_copy",
    "bursts",
    "random_frames",
    "camera_gone",
    "cut_mjpeg",
    "remove_camera",
    "host_times",
    "slots_lost",
    "copy_recording",
]

REASON = "simulated: camera skipped frames under load"


def host_times(folder) -> dict[str, np.ndarray]:
    """Per camera of the manifest, its index's host receive times."""
    folder = Path(folder)
    m = load_manifest(folder)
    return {n: np.array([r.host_time for r in read_index(folder / f"{n}.index.csv")], float) for n in m["cameras"]}


def bursts(
    folder, loss: float, burst_s: float = 1.0, seed: int = 0, start_after_s: float = 0.0, end_before_s: float = 1.0
) -> tuple:
    """``(masks, intervals)``: bursts of about ``burst_s`` (0.7-1.3 x) in which every camera
    loses its frames, spaced (0.6-1.4 x the mean) so that about ``loss`` of the time is lost;
    the first at least ``start_after_s`` after the first frame, the last ending at least
    ``end_before_s`` before the last (frames lost at the very end leave no trace in a
    recording: see :func:`cut_mjpeg` for that). ``intervals``: host [t0, t1)."""
    times = host_times(folder)
    t0 = min(float(t[0]) for t in times.values())
    t1 = max(float(t[-1]) for t in times.values())
    rng = np.random.default_rng([seed, 20])
    intervals = []
    if loss > 0:
        mean_gap = burst_s / loss
        t = t0 + start_after_s + rng.uniform(0.2, 1.0) * (mean_gap - burst_s)
        while True:
            length = burst_s * rng.uniform(0.7, 1.3)
            if t + length > t1 - end_before_s:
                break
            intervals.append((t, t + length))
            t += length + (mean_gap - burst_s) * rng.uniform(0.6, 1.4)
    masks = {n: np.zeros(len(ht), bool) for n, ht in times.items()}
    for n, ht in times.items():
        for a, b in intervals:
            masks[n] |= (ht >= a) & (ht < b)
    return masks, intervals


def random_frames(folder, loss: float, seed: int = 0) -> dict:
    """Single frames left out at random, each camera on its own."""
    rng = np.random.default_rng([seed, 21])
    return {n: rng.random(len(ht)) < loss for n, ht in host_times(folder).items()}


def camera_gone(folder, camera: str, a_s: float, b_s: float) -> dict:
    """``camera`` has no frames from ``a_s`` to ``b_s`` seconds after the recording's first frame."""
    times = host_times(folder)
    t0 = min(float(t[0]) for t in times.values())
    return {
        n: ((ht >= t0 + a_s) & (ht < t0 + b_s)) if n == camera else np.zeros(len(ht), bool) for n, ht in times.items()
    }


def lossy_copy(src, dst, drop: dict, reason: str = REASON) -> dict:
    """Copy the recording ``src`` to ``dst`` without the frames ``drop[camera]`` marks (a bool per
    index row), with a manifest gap for every run of frames left out between two kept frames.
    Returns per camera the number of frames left out."""
    src, dst = Path(src), Path(dst)
    manifest = load_manifest(src)
    names = list(manifest["cameras"])
    meta = {
        k: v
        for k, v in manifest.items()
        if k not in ("cameras", "status", "started", "finished", "format", "software", "problems")
    }
    out = {}
    with Recording(dst, names, meta) as rec:
        for name in names:
            rows = read_index(src / f"{name}.index.csv")
            data = (src / f"{name}.mjpeg").read_bytes()
            mask = np.asarray(drop.get(name, np.zeros(len(rows), bool)), bool)
            written, last, pending = 0, None, 0
            for row, gone in zip(rows, mask):
                if gone:
                    pending += 1
                    continue
                if pending and last is not None:
                    rec.add_gap(
                        name,
                        {
                            "after_frame": written - 1,
                            "camera_t0": last.camera_time,
                            "camera_t1": row.camera_time,
                            "missing": pending,
                            "reason": reason,
                            "host_time": row.host_time,
                        },
                    )
                pending = 0
                rec.write_frame(name, data[row.offset : row.offset + row.length], row.camera_time, row.host_time)
                written += 1
                last = row
            out[name] = int(mask.sum())
    return out


def cut_mjpeg(folder, camera: str, keep: float) -> int:
    """Cut ``camera``'s ``.mjpeg`` to the first ``keep`` of its bytes (its index stays whole, as
    when a copy was interrupted). Returns the bytes kept."""
    path = Path(folder) / f"{camera}.mjpeg"
    size = int(path.stat().st_size * keep)
    with open(path, "r+b") as f:
        f.truncate(size)
    return size


def remove_camera(folder, camera: str) -> None:
    """``camera``'s ``.mjpeg`` and index gone (its manifest entry stays)."""
    for ext in (".mjpeg", ".index.csv"):
        (Path(folder) / f"{camera}{ext}").unlink()


def copy_recording(src, dst) -> Path:
    shutil.copytree(src, dst)
    return Path(dst)


def slots_lost(full, damaged, cameras=("cam1", "cam2")) -> np.ndarray:
    """The truth of what a damaged copy lacks: per frame slot of the complete recording ``full``
    (its cameras' frames k, free-running but at one rate), whether any of ``cameras`` has no
    readable frame k in ``damaged`` (missing from the index, or bytes past the end of the
    .mjpeg). With two cameras, a slot lost is a frame set lost: time without frames."""
    full, damaged = Path(full), Path(damaged)
    lost = None
    for cam in cameras:
        rows = read_index(full / f"{cam}.index.csv")
        have = set()
        if (damaged / f"{cam}.mjpeg").exists():
            size = (damaged / f"{cam}.mjpeg").stat().st_size
            have = {r.camera_time for r in read_index(damaged / f"{cam}.index.csv") if r.offset + r.length <= size}
        gone = np.array([r.camera_time not in have for r in rows])
        lost = gone if lost is None else lost[: len(gone)] | gone[: len(lost)]
    return lost
