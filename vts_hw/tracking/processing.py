"""Process a recording folder: decode, detect, match and triangulate every frame, on every core.

:func:`process_recording` turns a recording folder (vts_hw/recording/folder.py) of two or more
calibrated cameras into :class:`~vts_hw.tracking.tracks.Tracks`: marker positions (mm) over host
time with identities, each point with the cameras it was seen by.

1. **Clocks.** Each camera's clock is fitted to host time from its index
   (:mod:`vts_hw.timing.camera_clock`); every frame gets a *mapped host time* from its JPEG stamp
   (a frame without a stamp: its receive time minus the median delay).
2. **Frame sets.** The frames of every camera are grouped by mapped host time with the live
   path's own rule (:class:`vts_hw.tracking.frame_sets.FrameGrouper`, run over the recording
   by :func:`~vts_hw.tracking.frame_sets.group_frames`): the oldest frame opens a set, the
   other cameras' next frames join it while within half a frame period of its mean time, and a
   set needs two cameras. Frames left over are reported (``Tracks.unpaired``) and not decoded.
   The cameras' own clocks may differ by seconds: only mapped host times are compared.
3. **Per chunk of frame sets, in worker processes** (:mod:`vts_hw.tracking.chunks`) (``workers`` = every core by default): the
   JPEGs are read from the ``.mjpeg`` files by the byte offsets of the index (one read per
   camera per chunk: no JPEG bytes go through pipes), decoded at full resolution
   (``cv2.imdecode``, grey), detected (:func:`vts_hw.vision.detect.detect`); two cameras: matched by the epipolar
   constraint (the rules of :func:`vts_hw.vision.triangulate.match_epipolar`; a fast path when
   every point has at most one candidate), and triangulated all at once: a linear solution on
   undistorted points, then one Gauss-Newton step on the reprojection error in pixels through
   the full camera model (``cv2.projectPoints``), vectorised over the chunk's points. Three
   or more cameras: :func:`vts_hw.vision.multiview.match_views` per frame set (every pair of
   cameras, ambiguities withheld, each point triangulated from every camera that sees it).
   OpenCV's own threads are set to 1 in the workers (no oversubscription).
4. **Identities** (main process, in time order): the live path's identity tracker
   (:class:`vts_hw.tracking.identities.MarkerTracks`, run over the frame sets by
   :func:`~vts_hw.tracking.identities.track_identities`): each set's points joined to the tracks
   alive within ``gate_mm`` (Hungarian when several compete); a point left over starts a new
   marker id; a track unseen for ``max_gap_s`` ends.

Clocks: every ``host_time`` here is the host's UTC epoch seconds as mapped from the cameras'
stamps (see camera_clock for what the mapping means: exposure plus the least delay).
Units: mm, px, s. See docs/decisions/0018-processing.md and docs/trajectory-format.md.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from vts_hw.errors import DataError
from vts_hw.lifeline import interrupts_deferred
from vts_hw.recording.extent import available_cameras, recording_extent
from vts_hw.recording.folder import load_manifest
from vts_hw.recording.frames import CameraFrames, load_camera_frames
from vts_hw.timing.camera_clock import ClockFit
from vts_hw.tracking import chunks
from vts_hw.tracking.chunks import triangulate_fast
from vts_hw.tracking.frame_sets import frame_period, group_frames, mapped_times
from vts_hw.tracking.identities import track_identities
from vts_hw.tracking.time_align import align_views
from vts_hw.tracking.tracks import TRACKS_FORMAT, Tracks
from vts_hw.vision.camera_set import named_cameras
from vts_hw.vision.detect import DEFAULT as DEFAULT_DETECTOR
from vts_hw.vision.detect import DetectorSettings
from vts_hw.vision.multiview import ViewGeometry
from vts_hw.vision.triangulate import PinholeCamera

__all__ = [
    "Tracks",
    "ProcessSettings",
    "process_recording",
    "cameras_from_calibration",
    "group_frames",
    "triangulate_fast",
    "track_identities",
    "CameraFrames",
    "load_camera_frames",
    "TRACKS_FORMAT",
]


@dataclass(frozen=True)
class ProcessSettings:
    """Parameters of :func:`process_recording`.

    ``max_px``, ``ratio``, ``min_sep_px``: epipolar matching (see ``match_epipolar``).
    ``pair_fraction``: a frame joins a set when its mapped host time is within this fraction
    of the frame period of the set's mean time (:class:`~vts_hw.tracking.frame_sets.FrameGrouper`). ``gate_mm``: tracking gate (mm) from a track's last
    position. ``max_gap_s``: a track not seen for this long ends (a later point gets a new id).
    ``latency_s``: known minimum exposure-to-receipt delay, subtracted from mapped times.
    ``chunk_pairs``: pairs per worker task (None: chosen from the pair count and workers).
    ``max_rms_px``: a point whose reprojection RMS is larger is not made, its detections count
    as seen by one camera (see :func:`vts_hw.vision.multiview.match_views`).
    ``views_min_sep_px``: with three or more cameras, the separation a rival group's RMS needs
    from the best to be clearly worse (0013 advises ~3x the centroid noise; two cameras keep
    ``min_sep_px``, 0 by default, so that their figures are 0018's).
    ``align_times``: bring each camera's view of a tracked marker to the frame set's time
    before the final triangulation (:mod:`vts_hw.tracking.time_align`, decision 0037).
    """

    max_px: float = 2.0
    ratio: float = 2.0
    min_sep_px: float = 0.0
    pair_fraction: float = 0.5
    gate_mm: float = 15.0
    max_gap_s: float = 1.0
    latency_s: float = 0.0
    chunk_pairs: int | None = None
    max_rms_px: float = 0.5  # a point's largest reprojection RMS (px)
    views_min_sep_px: float = 0.1  # three or more cameras: min_sep_px of match_views
    align_times: bool = True
    detector: DetectorSettings = DEFAULT_DETECTOR


# ------------------------------------------------------------------ inputs
def cameras_from_calibration(calib, names=("cam1", "cam2")) -> dict[str, PinholeCamera]:
    """The named cameras of a calibration (stereo: the VTS frame is camera 1's; T in mm)."""
    return named_cameras(calib, list(names))


# ------------------------------------------------------------------ entry point
def process_recording(
    folder,
    cameras,
    workers: int | None = None,
    mapping=None,
    host_to_spect: Callable | None = None,
    settings: ProcessSettings | None = None,
    progress: Callable[[int, int], None] | None = None,
    clock_fits: dict[str, ClockFit] | None = None,
) -> Tracks:
    """Marker tracks of a recording folder of two or more cameras (see the module docstring).

    ``cameras``: the calibrated cameras, any form :func:`vts_hw.vision.camera_set.named_cameras`
    takes -- a dict name → camera (K, dist, R, t), a list (named like the recording's cameras,
    else taken in the recording's order), or a calibration (the VTS frame is then its
    reference camera's, camera 1's). Every calibrated camera the recording has is used.
    ``workers``: processes (default ``os.cpu_count()``; 1 runs in this process).
    ``mapping``: a VTS → SPECT rigid transform (``RigidTransform`` or anything with
    ``apply``), adding SPECT-frame positions. ``host_to_spect``: host epoch s → SPECT time,
    adding a SPECT time column. ``progress(done_sets, total_sets)`` after each chunk.
    ``clock_fits``: camera clock fits to use instead of fitting them here.
    """
    s = settings or ProcessSettings()
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{folder}: not a recording folder")
    manifest = load_manifest(folder, missing_ok=True)  # a bad manifest is a DataError naming it
    available, missing = available_cameras(folder, manifest)
    cams = named_cameras(cameras, available)
    names = [n for n in cams if n in available]
    if len(names) < 2:
        lacks = "".join(f"; {why}" for why in missing.values())
        raise DataError(
            f"{folder}: the recording has cameras {', '.join(available) or 'none'}, "
            f"but calibrated cameras are {', '.join(cams)}: two must be in both{lacks}"
        )
    frames = [load_camera_frames(folder, n) for n in names]
    times, fits, warnings = [], {}, []
    for cf in frames:
        if clock_fits and cf.name in clock_fits:
            fit = clock_fits[cf.name]
            t = np.asarray(fit.host_time(cf.camera_time), float)
            t = np.where(np.isfinite(t), t, cf.host_time)
        else:
            t, fit, warn = mapped_times(cf, s.latency_s)
            warnings += warn
        times.append(t)
        fits[cf.name] = fit
    period = frame_period(times[0])
    extent = recording_extent(folder, manifest, frames, times, fits, missing, period)
    warnings += extent["problems"]
    sets = group_frames(times, s.pair_fraction * period)
    n_sets = len(sets)
    workers = max(1, int(workers or os.cpu_count() or 1))
    chunk = s.chunk_pairs or int(min(400, max(40, math.ceil(n_sets / (workers * 6)))))

    def span(c, rows):
        idx = sets[rows, c]
        return (np.where(idx >= 0, frames[c].offset[idx], -1), np.where(idx >= 0, frames[c].length[idx], 0))

    tasks = [(k, [span(c, slice(k, k + chunk)) for c in range(len(names))]) for k in range(0, n_sets, chunk)]
    state = {"cams": [cams[n] for n in names], "names": names, "settings": s, "paths": [str(cf.mjpeg) for cf in frames]}
    results = []
    done = 0
    if workers == 1 or len(tasks) <= 1:
        before = cv2.getNumThreads()
        chunks._init_worker(state, 1)
        try:
            for task in tasks:
                results.append(chunks._process_chunk(task))
                done += len(task[1][0][0])
                if progress:
                    progress(done, n_sets)
        finally:
            cv2.setNumThreads(before)
    else:
        pool = ProcessPoolExecutor(
            min(workers, len(tasks)),
            mp_context=_pool_context(),
            initializer=chunks._init_worker,
            initargs=({**state, "command_pid": os.getpid()}, 1),
        )
        try:
            with interrupts_deferred():  # Ctrl-C while the workers are started: raised once they are
                results_of = pool.map(chunks._process_chunk, tasks)
            for res in results_of:
                results.append(res)
                done += int(res[5].shape[0])
                if progress:
                    progress(done, n_sets)
        except BaseException:  # Ctrl-C, an error: the chunks not started are dropped
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        pool.shutdown(wait=True)
    tracks = _assemble(
        folder, names, frames, times, fits, sets, results, s, mapping, host_to_spect, period, cams, warnings
    )
    tracks.meta["extent"] = extent
    return tracks


def _pool_context():
    """Workers come from a fork server (its own clean process, with the worker module imported
    once), never by forking this process: a caller with threads (HTTP servers, recorders,
    OpenCV's pool) may hold a lock at the moment of a fork, and the forked worker would wait on
    it for ever. Where there is no fork server, spawn."""
    import multiprocessing as mp

    if "forkserver" in mp.get_all_start_methods():
        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload([chunks.__name__])
        return ctx
    return mp.get_context("spawn")


def _assemble(
    folder, names, frames, times, fits, sets, results, s, mapping, host_to_spect, period, cams, warnings
) -> Tracks:
    n_sets, C = sets.shape[0], len(names)
    results.sort(key=lambda r: r[0])

    def cat(i, shape):
        return np.concatenate([r[i] for r in results]) if results else np.zeros(shape)

    pair = cat(1, (0,)).astype(int)
    X = cat(2, (0, 3))
    rms = cat(3, (0,))
    uv = cat(4, (0, 2 * C))
    counts = cat(5, (0, C)).astype(int)
    failed = cat(6, (0, C)).astype(bool)
    ambiguous = cat(7, (0, C)).astype(int)
    single = cat(8, (0, C)).astype(int)
    present = sets >= 0
    t_sets = np.column_stack(
        [np.where(present[:, c], times[c][np.maximum(sets[:, c], 0)], np.nan) for c in range(C)]
    ).reshape(-1, C)
    host = np.nanmean(t_sets, axis=1) if n_sets else np.zeros(0)
    ids = track_identities(pair, host, X, s.gate_mm, s.max_gap_s)
    n_aligned = 0
    if s.align_times and len(X):
        geo = ViewGeometry([cams[n] for n in names], names)
        Xa, ra, _, n_aligned = align_views(geo, pair, ids, uv, t_sets, host, max_gap_s=2.5 * period)
        moved = ~np.isnan(Xa[:, 0])
        X, rms = X.copy(), rms.copy()
        X[moved], rms[moved] = Xa[moved], ra[moved]
    cam_time = np.column_stack(
        [np.where(present[:, c], frames[c].camera_time[np.maximum(sets[:, c], 0)], np.nan) for c in range(C)]
    ).reshape(-1, C)
    cam_frame = np.column_stack(
        [np.where(present[:, c], frames[c].frame[np.maximum(sets[:, c], 0)], -1) for c in range(C)]
    ).reshape(-1, C)
    unpaired = {}
    for c, cf in enumerate(frames):
        mask = np.ones(len(cf.frame), bool)
        mask[sets[present[:, c], c]] = False
        unpaired[cf.name] = cf.frame[mask]
    spread = np.nanmax(t_sets, axis=1) - np.nanmin(t_sets, axis=1) if n_sets else np.zeros(0)
    seen_by = (~np.isnan(uv[:, 0::2])).sum(axis=1) if len(uv) else np.zeros(0, int)
    meta = {
        "recording": str(folder),
        "cameras": names,
        "clock_fits": {n: None if fits[n] is None else fits[n].summary() for n in names},
        "warnings": list(warnings),
        "frame_period_s": period,
        "pair_tolerance_s": s.pair_fraction * period,
        "pair_time_difference_max_s": float(np.max(spread)) if n_sets else None,
        "frames": {cf.name: int(len(cf.frame)) for cf in frames},
        "frames_beyond_end_of_mjpeg": {cf.name: cf.beyond_end for cf in frames},
        "paired_frames": int(n_sets),
        "unpaired_frames": {k: int(len(v)) for k, v in unpaired.items()},
        "undecodable_frames": {names[c]: int(failed[:, c].sum()) for c in range(C)},
        "blobs_per_frame_mean": {
            names[c]: float(counts[present[:, c], c].mean()) if present[:, c].any() else None for c in range(C)
        },
        "ambiguous_points": int(ambiguous.sum()),
        "ambiguous_detections": {names[c]: int(ambiguous[:, c].sum()) for c in range(C)},
        "single_camera_detections": {names[c]: int(single[:, c].sum()) for c in range(C)},
        "views_time_aligned": int(n_aligned),
        "points_by_cameras_seen": {str(k): int((seen_by == k).sum()) for k in range(2, C + 1)},
        "markers": int(ids.max()) if len(ids) else 0,
        "settings": {
            "max_px": s.max_px,
            "ratio": s.ratio,
            "min_sep_px": s.min_sep_px,
            "pair_fraction": s.pair_fraction,
            "gate_mm": s.gate_mm,
            "max_gap_s": s.max_gap_s,
            "latency_s": s.latency_s,
            "max_rms_px": s.max_rms_px,
            "views_min_sep_px": s.views_min_sep_px,
            "align_times": s.align_times,
        },
        "calibration": {
            n: {
                "K": cams[n].K.tolist(),
                "dist": cams[n].dist.tolist(),
                "R": cams[n].R.tolist(),
                "t": cams[n].t.tolist(),
            }
            for n in names
        },
    }
    tracks = Tracks(
        host_time=host,
        camera_names=names,
        camera_time=cam_time,
        camera_frame=cam_frame,
        n_blobs=counts,
        point_frame=pair,
        marker=ids,
        xyz=X,
        reproj_px=rms,
        uv=uv,
        unpaired=unpaired,
        meta=meta,
        n_single=single,
    )
    if mapping is not None or host_to_spect is not None:
        tracks = tracks.with_spect(mapping, host_to_spect)
    return tracks
