"""The motion analysis's files for reconstruction and research (docs/motion-formats.md):

* ``motion_6dof.csv`` / ``motion_6dof.json`` -- per frame: time, translation (mm), rotation
  as Euler angles (deg, extrinsic x-y-z) and as a quaternion (x, y, z, w), motion state,
  quality (markers used, fit RMS, moving);
* ``respiration.csv`` -- per frame: time, amplitude (mm), phase (0-1), rate (/min);
* ``subsets.json`` -- list-mode subsets: the time intervals of every motion state and of
  ``n_bins`` respiratory bins by amplitude (equal counts of frames) and by phase (equal
  widths), still frames only for the respiratory bins;
* ``castor_motion.dyn`` and ``castor_motion_rigid.txt`` (:mod:`.castor`) -- only on the SPECT
  clock, in the SPECT frame, with a mapping that says which volume placed that frame: else one
  sentence says why not (``ExportedFiles.notes``, and ``castor`` in motion_6dof.json);
* ``yrtpet_lor_motion.csv`` (:mod:`.yrtpet`) -- YRT-PET's per-frame [R|t] with each pose's error,
  on the same conditions (``yrtpet`` in motion_6dof.json).

Every pose says how sure it is (:mod:`vts_hw.pose_health`, :mod:`.health`): per row its health
(``known``, ``bounded``, ``not known``), why, and a confidence in [0, 1], in the 6-DOF series; per
motion state and respiratory bin in subsets.json; as the error in YRT-PET's file.

Times are seconds from the acquisition start on the SPECT list-mode clock when the session was
synced, else seconds from the first frame on the host clock; every JSON says which (``clock``),
and which frame (``frame``: its name, definition and the volume that placed it).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np

from vts_hw.errors import DataError
from vts_hw.files import ensure_dir, kind_of, write_atomic, write_json_atomic
from vts_hw.motion.castor import CASTOR_DYNAMIC, CASTOR_RIGID, plan_castor, write_castor
from vts_hw.motion.health import result_health
from vts_hw.motion.yrtpet import LOR_MOTION_CSV, plan_lor_motion, write_lor_motion
from vts_hw.pose_health import HealthSeries
from vts_hw.spect.frame import frame_description

__all__ = [
    "export_motion",
    "ExportedFiles",
    "time_origin",
    "clock_text",
    "respiratory_bins",
    "state_of_frames",
    "frame_quality",
    "unknown_intervals",
    "coverage_json",
    "health_summary",
    "SIXDOF_CSV",
    "SIXDOF_JSON",
    "RESP_CSV",
    "SUBSETS_JSON",
    "MOTION_FORMAT",
]

SIXDOF_CSV, SIXDOF_JSON = "motion_6dof.csv", "motion_6dof.json"
RESP_CSV, SUBSETS_JSON = "respiration.csv", "subsets.json"
MOTION_FORMAT = "vts-motion/1"


class ExportedFiles(list):
    """The paths written (a list), and ``notes``: sentences for the person who asked (a file not
    written and why, motion states CASToR's whole-second triggers cannot hold)."""

    def __init__(self, paths=(), notes=()):
        super().__init__(paths)
        self.notes = list(notes)


def time_origin(result) -> float:
    """0 on the SPECT clock (list-mode seconds are from the acquisition start), else the first
    frame's host time."""
    return 0.0 if result.series.clock == "spect" else float(result.series.t[0])


def clock_text(result) -> str:
    if result.series.clock == "spect":
        return "SPECT list-mode seconds since the acquisition start (synced through the gating signal)"
    return (
        f"host clock, seconds since the first frame (UTC epoch {result.series.t[0]:.3f}); not synced "
        "to the SPECT: give the list-mode to put the times on its clock"
    )


def state_of_frames(result) -> np.ndarray:
    """(F,) per row the motion state that covers it, -1 where none does (time without a pose
    that no state may claim: docs/motion-formats.md)."""
    t = result.pose.t
    out = np.full(len(t), -1)
    for s in result.states:
        out[(t >= s.t_start) & (t < s.t_end)] = s.index
    if result.covered is not None:
        out[~result.covered] = -1
    return out


def frame_quality(result) -> np.ndarray:
    """(F,) ``no frames`` (no frame set recorded), ``no pose`` (fewer than 3 markers),
    ``moving`` (inside a body-motion event), ``poor fit`` (the body model leaves more than
    POOR_FIT_MM of residual: the pose is degraded, not measured to its goal) or ``ok``."""
    pose = result.pose
    frames = result.timeline.frames if result.timeline is not None else np.ones(len(pose.t), bool)
    return np.where(
        ~frames,
        "no frames",
        np.where(~pose.valid, "no pose", np.where(result.moving, "moving", np.where(pose.poor_fit, "poor fit", "ok"))),
    )


def unknown_intervals(result, t0: float = 0.0) -> list[dict]:
    """The stretches without a pose that no state covers: ``interval_s``, ``seconds``, ``why``."""
    covered = result.covered if result.covered is not None else result.pose.valid
    out = []
    for u in result.unknown:
        a, b = u["rows"]
        if covered[a:b].all():
            continue
        out.append({"interval_s": [u["t_start"] - t0, u["t_end"] - t0], "seconds": u["seconds"], "why": u["why"]})
    return out


def coverage_json(result, t0: float = 0.0) -> dict:
    """The scan's time: duration, pose known, without frames, with fewer than 3 markers, what
    the recording lacks, the stretches no state covers and those bridged."""
    return {
        **result.coverage,
        "missing": list(result.timeline.missing),
        "unknown_s": unknown_intervals(result, t0),
        "bridged_s": [[a - t0, b - t0] for a, b in result.bridged],
    }


def _intervals(t, mask, t0, dt):
    m = np.concatenate([[False], mask, [False]])
    d = np.diff(m.astype(int))
    return [
        [round(float(t[a] - t0 - dt / 2), 4), round(float(t[b - 1] - t0 + dt / 2), 4)]
        for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1))
    ]


def _confidence(conf, sel) -> float | None:
    return None if conf is None or not np.any(sel) else round(float(np.mean(conf[sel])), 4)


def health_summary(health: HealthSeries, sel=None) -> dict:
    """Rows per health state and the confidence (mean, least) over the rows ``sel`` (all: None)."""
    sel = np.ones(len(health), bool) if sel is None else np.asarray(sel, bool)
    h = HealthSeries(health.state[sel], health.why[sel], health.confidence[sel])
    c = h.confidence
    return {
        "rows": h.counts(),
        "confidence_mean": round(float(c.mean()), 4) if len(c) else None,
        "confidence_min": round(float(c.min()), 4) if len(c) else None,
    }


def respiratory_bins(result, n_bins: int = 4, t0: float = 0.0, confidence=None) -> dict:
    """Intervals per respiratory bin by amplitude (still frames with a pose) and by phase (still
    frames inside breaths seen whole). None of either when no breathing was found: bins made
    from noise would split the counts at random. ``confidence`` (F,): each bin's mean is given."""
    t = result.pose.t
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.04
    fig = result.respiration.figures
    if fig is not None and fig.status == "none":
        return {"status": "none", "why": fig.why, "amplitude": [], "phase": []}
    a = result.respiration.amplitude
    ph = result.respiration.phase
    use = result.pose.valid & ~result.moving & np.isfinite(a)
    edges = np.quantile(a[use], np.linspace(0, 1, n_bins + 1)) if use.any() else np.zeros(n_bins + 1)
    amp = []
    for k in range(n_bins):
        hi_ok = a <= edges[k + 1] if k == n_bins - 1 else a < edges[k + 1]
        sel = use & (a >= edges[k]) & hi_ok
        amp.append(
            {
                "bin": k,
                "amplitude_mm": [float(edges[k]), float(edges[k + 1])],
                "frames": int(sel.sum()),
                "confidence_mean": _confidence(confidence, sel),
                "intervals": _intervals(t, sel, t0, dt),
            }
        )
    phase = []
    for k in range(n_bins):
        lo, hi = k / n_bins, (k + 1) / n_bins
        sel = use & np.isfinite(ph) & (ph >= lo) & (ph < hi)
        phase.append(
            {
                "bin": k,
                "phase": [lo, hi],
                "frames": int(sel.sum()),
                "confidence_mean": _confidence(confidence, sel),
                "intervals": _intervals(t, sel, t0, dt),
            }
        )
    out = {"status": fig.status if fig is not None else "measured", "amplitude": amp, "phase": phase}
    if not any(b["frames"] for b in phase):
        out["phase_note"] = "no breath was seen whole: no phase, no phase bins"
    return out


def _remove_stale(out: Path, names=(CASTOR_DYNAMIC, CASTOR_RIGID)) -> str:
    """Files for another program an earlier export left in ``out`` would not match the files
    written now: remove them, and say so (the other files are replaced the same way). Only a
    regular file is removed: anything else of that name (a folder, a FIFO, a device, a link) is no
    earlier export's and is left as it is, and said."""
    gone, left = [], []
    for name in names:
        try:
            st = os.lstat(out / name)
            if not stat.S_ISREG(st.st_mode):
                left.append(f"{name} there is {kind_of(out / name, st)}, no earlier export's file: left as it is")
                continue
            (out / name).unlink()
            gone.append(name)
        except FileNotFoundError:
            pass
        except OSError as e:
            raise DataError(
                f"{out / name}: an earlier export's file could not be removed ({e.strerror}); "
                "it does not match this export"
            ) from None
    said = [f"removed {' and '.join(gone)}, which an earlier export left there"] if gone else []
    return f" ({'; '.join(said + left)})" if said or left else ""


def export_motion(
    result, out, *, n_bins: int = 4, extra: dict | None = None, volume: dict | None = None
) -> ExportedFiles:
    """Write every file above into ``out``; returns their paths (and notes). ``volume``: what the
    VTS -> SPECT mapping kept of the volume it was made from (vts_hw.spect.frame.volume_record)."""
    out = ensure_dir(out, "export folder")
    t0 = time_origin(result)
    clock = clock_text(result)
    castor = plan_castor(result.states, t0, clock=result.series.clock, frame=result.series.frame, volume=volume)
    castor_files = (out / CASTOR_DYNAMIC, out / CASTOR_RIGID) if castor.why is None else ()
    if castor.why is not None:
        castor.why += _remove_stale(out)
    pose = result.pose
    health = result_health(result)
    lor = plan_lor_motion(
        pose.t - t0,
        pose.R,
        pose.T,
        health.confidence,
        clock=result.series.clock,
        frame=result.series.frame,
        volume=volume,
    )
    if lor.why is not None:
        lor.why += _remove_stale(out, (LOR_MOTION_CSV,))
    t = pose.t - t0
    six = pose.six_dof()
    q = pose.quaternions()
    state = state_of_frames(result)
    n = pose.n_markers
    quality = frame_quality(result)
    st_txt = lambda k: "" if state[k] < 0 else str(int(state[k]))  # noqa: E731
    frame = frame_description(result.series.frame, volume)
    cols = [
        "time_s",
        "tx_mm",
        "ty_mm",
        "tz_mm",
        "rx_deg",
        "ry_deg",
        "rz_deg",
        "qx",
        "qy",
        "qz",
        "qw",
        "state",
        "markers",
        "fit_rms_mm",
        "quality",
        "health",
        "confidence",
        "health_why",
    ]
    f = lambda v, d: "" if not np.isfinite(v) else f"{v:.{d}f}"  # noqa: E731
    lines = [",".join(cols)]
    for k in range(len(t)):
        lines.append(
            ",".join(
                [f"{t[k]:.4f}"]
                + [f(x, 4) for x in six[k]]
                + [f(x, 7) for x in q[k]]
                + [
                    st_txt(k),
                    str(int(n[k])),
                    f(pose.rms_mm[k], 4),
                    str(quality[k]),
                    str(health.state[k]),
                    f"{health.confidence[k]:.4f}",
                    str(health.why[k]).replace(",", ";"),
                ]
            )
        )
    p_csv = out / SIXDOF_CSV
    write_atomic(p_csv, "\n".join(lines) + "\n")
    p_lor = Path(write_lor_motion(out / LOR_MOTION_CSV, lor)) if lor.why is None else None  # before the
    # JSON that says it was written
    nan = lambda a: [None if not np.isfinite(x) else round(float(x), 6) for x in a]  # noqa: E731
    meta = {
        "format": MOTION_FORMAT,
        "clock": clock,
        "time_origin": t0,
        "frame": frame,
        "transform": "reference pose -> pose at t, x -> R x + t (breathing excluded); rotations deg, "
        "extrinsic x-y-z (scipy 'xyz'); quaternion x, y, z, w",
        "reference_period_s": [result.reference_period[0] - t0, result.reference_period[1] - t0],
        "coverage": coverage_json(result, t0),
        "states": [s.to_json(t0) for s in result.states],
        "events": [e.to_json(t0) for e in result.events],
        "castor": castor.to_json(castor_files),
        "yrtpet": lor.to_json(True),
        "health": {**health_summary(health), "rule": "vts_hw.pose_health; docs/decisions/0091"},
        **(extra or {}),
    }
    doc = {
        **meta,
        "columns": {
            "time_s": nan(t),
            "tx_mm": nan(six[:, 0]),
            "ty_mm": nan(six[:, 1]),
            "tz_mm": nan(six[:, 2]),
            "rx_deg": nan(six[:, 3]),
            "ry_deg": nan(six[:, 4]),
            "rz_deg": nan(six[:, 5]),
            "qx": nan(q[:, 0]),
            "qy": nan(q[:, 1]),
            "qz": nan(q[:, 2]),
            "qw": nan(q[:, 3]),
            "state": [None if x < 0 else int(x) for x in state],
            "markers": n.tolist(),
            "fit_rms_mm": nan(pose.rms_mm),
            "quality": quality.tolist(),
            "health": health.state.tolist(),
            "confidence": [round(float(x), 4) for x in health.confidence],
            "health_why": health.why.tolist(),
        },
    }
    p_json = write_json_atomic(out / SIXDOF_JSON, doc, indent=None)
    r = result.respiration
    cyc = np.full(len(t), -1)
    for i, c in enumerate(r.cycles):
        cyc[(pose.t >= c.t_start) & (pose.t < c.t_end)] = i
    rl = ["time_s,amplitude_mm,phase,rate_per_min,cycle,quality"]
    for k in range(len(t)):
        rl.append(
            f"{t[k]:.4f},{f(r.amplitude[k], 4)},{f(r.phase[k], 4)},{f(r.rate[k], 3)},"
            f"{'' if cyc[k] < 0 else cyc[k]},{quality[k]}"
        )
    p_resp = out / RESP_CSV
    write_atomic(p_resp, "\n".join(rl) + "\n")
    subsets = {
        "format": MOTION_FORMAT,
        "clock": clock,
        "time_origin": t0,
        "frame": frame,
        "motion_states": [
            {
                "state": s.index,
                "interval_s": [s.t_start - t0, s.t_end - t0],
                "intervals_s": [[a - t0, b - t0] for a, b in s.intervals],
                "unknown_s": s.unknown_s,
                "six_dof": s.six_dof,
                "health": health_summary(health, state == s.index),
            }
            for s in result.states
        ],
        "unknown_s": unknown_intervals(result, t0),
        "coverage": {k: v for k, v in coverage_json(result, t0).items() if k != "unknown_s"},
        "breathing": result.respiration.figures.to_json() if result.respiration.figures else None,
        "respiratory_bins": respiratory_bins(result, n_bins, t0, health.confidence),
        "health": health_summary(health),
        "note": "intervals [start, end) s. A state's interval_s is its span; it covers only its intervals_s "
        "(time without a pose is in no state unless bridged: docs/motion-formats.md). "
        "Respiratory bins hold still frames with a pose only, phase bins only frames inside "
        "breaths seen whole",
    }
    p_sub = write_json_atomic(out / SUBSETS_JSON, subsets)
    paths = [p_csv, Path(p_json), p_resp, Path(p_sub)]
    notes = [lor.why] if lor.why is not None else []
    if lor.why is None:
        paths.append(p_lor)
    if castor.why is not None:
        return ExportedFiles(paths, [castor.why] + notes)
    comment = (
        "vts-hw motion states for CASToR: triggers in whole seconds of the SPECT list-mode from the "
        "acquisition start; parameters in CASToR's image frame (x patient left, y anterior, z head, origin "
        "at the image centre) from the pose at the acquisition start; motion_6dof.json 'castor' says more"
    )
    paths += write_castor(castor.triggers, castor.params, out, comment=comment)
    return ExportedFiles(paths, castor.merged + notes)
