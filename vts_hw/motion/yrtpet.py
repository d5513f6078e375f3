"""YRT-PET's LOR motion file, written per frame of the scan with each pose's error (issue 33 §2;
docs/motion-formats.md; docs/decisions/0091-every-pose-says-how-sure-it-is.md).

YRT-PET (the Yale reconstruction toolkit, github.com/YaleBioImaging/yrt-pet) corrects list-mode
data for rigid motion from a CSV given as ``lor_motion`` (``yrtpet_reconstruct --lor_motion``);
its ``docs/source/usage/motion_file.md`` and ``LORMotion::readFromFile`` (read for this module, at
commit ec8cf3b) say:

* one line per motion frame, **no header**: ``t,r00,r01,r02,tx,r10,r11,r12,ty,r20,r21,r22,tz,e``;
  ``t`` the frame's **start**, an **unsigned 32-bit integer** of **milliseconds** on the list-mode's
  own clock (``std::from_chars`` into ``uint32_t``: a minus sign or a ``#`` comment makes the line
  "invalid" and it is skipped with a warning; a fraction would shift every column after it);
  then 12 floats, the 3x4 ``[R|t]`` **row-major**, then the error ``e`` "between 0 and 1"; values
  separated by commas or spaces; nothing after ``e``. Its own writer prints each float fixed with 9
  decimals, comma-separated, no spaces: this module writes the same;
* an event belongs to the last frame whose ``t`` it has reached (frames in time order); events
  before the first frame are not moved (identity), the last frame holds to the end;
* the transform moves each event's **LOR**: both detector positions ``p -> R p + t``, in the
  scanner's frame, so that every event lands where it would have been in the reference pose. It
  is the **inverse of the body's pose**: for ``x_now = R_b x_ref + T_b`` (motion_6dof's pose, about
  the FOV centre ``c``) the file holds ``R = R_b^T`` and ``t = -R_b^T (R_b c + T_b - c)`` -- the
  image is then the patient as in motion_6dof's reference (the first still period);
* ``e`` is kept per frame (``LORMotion::getError``); YRT-PET reads it but, at that commit, weighs
  nothing by it. Here ``e = 1 - confidence`` (:mod:`vts_hw.pose_health`): 0 a pose fully trusted,
  1 no pose.

A row per frame time of the scan (docs/motion-formats.md, Time). A row without a pose (no frames,
fewer than 3 markers) cannot be left empty in this format: it holds the last pose known before it
(the first known, before any) with ``e = 1``. Only on the SPECT list-mode clock and in the SPECT
frame with the mapping volume's centre known (the FOV centre, the scanner's origin); else one
sentence says why not.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from vts_hw.files import write_atomic
from vts_hw.motion.castor import fov_centre, not_on_the_scanner

__all__ = [
    "LOR_MOTION_CSV",
    "YRTPET_FRAME",
    "LorMotionPlan",
    "plan_lor_motion",
    "lor_motion_text",
    "write_lor_motion",
    "UINT32_MAX",
]

LOR_MOTION_CSV = "yrtpet_lor_motion.csv"
UINT32_MAX = 2**32 - 1
YRTPET_FRAME = (
    "YRT-PET's scanner frame, as the list-mode's detector positions have it: mm, the SPECT frame's "
    "axes (right-handed; X towards the patient's left, Y anterior, Z towards the feet, for a head-first "
    "supine patient), origin at the centre of the field of view, taken as the centre of the volume "
    "the VTS -> SPECT mapping was made from"
)


@dataclass
class LorMotionPlan:
    """What :func:`plan_lor_motion` decided: ``why`` (one sentence) when no file is written, else
    per line ``ms`` (uint32 ms), ``matrix`` (N, 12) the row-major [R|t], ``error`` (N,) in [0, 1];
    ``held``: lines without a pose of their own; ``centre``: the FOV centre (SPECT frame, mm)."""

    why: str | None = None
    ms: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    matrix: np.ndarray = field(default_factory=lambda: np.zeros((0, 12)))
    error: np.ndarray = field(default_factory=lambda: np.zeros(0))
    held: int = 0
    centre: np.ndarray | None = None

    def to_json(self, written: bool) -> dict:
        if self.why:
            return {"written": False, "why": self.why}
        if self.centre is None:  # set whenever there is no why
            raise ValueError("a YRT-PET motion without its centre")
        return {
            "written": written,
            "file": LOR_MOTION_CSV,
            "reader": "YRT-PET (lor_motion)",
            "frame": YRTPET_FRAME,
            "centre_mm": [float(v) for v in self.centre],
            "transform": "per line the inverse of the body pose about the FOV centre: each LOR's detector "
            "positions p -> R p + t land where they were in the reference pose",
            "time": "each line's start, integer ms of the SPECT list-mode from the acquisition start",
            "error": "1 - confidence (vts_hw.pose_health); 1 where the line has no pose of its own",
            "lines": int(len(self.ms)),
            "held_lines": int(self.held),
        }


def plan_lor_motion(t, R, T, confidence, *, clock: str, frame: str, volume: dict | None) -> LorMotionPlan:
    """The lines for the pose ``R`` (F,3,3), ``T`` (F,3) (reference -> now, SPECT frame, NaN without
    a pose) at ``t`` (F,) list-mode s from the acquisition start, each with its ``confidence``; or why
    none are written."""
    why = not_on_the_scanner(
        "YRT-PET LOR motion file", clock, frame, "YRT-PET takes list-mode milliseconds", "the scanner's"
    )
    if why:
        return LorMotionPlan(why=why)
    try:
        c = fov_centre(volume, "YRT-PET's scanner")
    except ValueError as e:
        return LorMotionPlan(why=f"YRT-PET LOR motion file not written: {e}")
    t = np.asarray(t, float)
    R, T = np.asarray(R, float), np.asarray(T, float)
    valid = np.isfinite(T).all(axis=1) & np.isfinite(R).all(axis=(1, 2))
    if not valid.any():
        return LorMotionPlan(why="YRT-PET LOR motion file not written: no frame has a pose")
    # rows without a pose hold the last pose before them (the first, before any), with error 1
    idx = np.where(valid, np.arange(len(t)), -1)
    idx = np.maximum.accumulate(idx)
    idx = np.where(idx < 0, int(np.flatnonzero(valid)[0]), idx)
    err = np.where(valid, 1.0 - np.clip(np.nan_to_num(np.asarray(confidence, float), nan=0.0), 0.0, 1.0), 1.0)
    Rb, Tb = R[idx], T[idx]
    Ri = Rb.transpose(0, 2, 1)
    ti = -np.einsum("fij,fj->fi", Ri, np.einsum("fij,j->fi", Rb, c) + Tb - c)
    ms = np.rint(t * 1000.0).astype(np.int64)
    # the line that covers the acquisition start starts at 0; earlier lines go (uint32 has no sign)
    before = np.flatnonzero(ms <= 0)
    keep = np.arange(len(t)) >= (before[-1] if len(before) else 0)
    ms, Ri, ti, err, own = ms[keep], Ri[keep], ti[keep], err[keep], valid[keep]
    if len(before):
        ms[0] = 0
    else:  # no frame before the first: the time to it has no pose
        ms, Ri, ti = np.concatenate([[0], ms]), np.concatenate([Ri[:1], Ri]), np.concatenate([ti[:1], ti])
        err, own = np.concatenate([[1.0], err]), np.concatenate([[False], own])
    first = np.concatenate([[True], np.diff(ms) > 0])  # two frames in one ms: the first
    ms, Ri, ti, err, own = ms[first], Ri[first], ti[first], err[first], own[first]
    if ms[-1] > UINT32_MAX:
        return LorMotionPlan(
            why=f"YRT-PET LOR motion file not written: the scan lasts {ms[-1] / 1000:.0f} s, "
            "past what its unsigned 32-bit milliseconds hold"
        )
    M = np.concatenate([Ri, ti[:, :, None]], axis=2).reshape(-1, 12)
    return LorMotionPlan(None, ms, M, err, int(np.count_nonzero(~own)), c)


def lor_motion_text(ms, matrix, error) -> str:
    """The file's text: per line the integer ms, the 12 numbers and the error, each fixed with 9
    decimals (as YRT-PET's own ``LORMotion::writeToFile``), comma-separated, no header.
    ValueError for what YRT-PET would misread."""
    ms = np.asarray(ms)
    matrix = np.asarray(matrix, float).reshape(-1, 12)
    error = np.asarray(error, float).reshape(-1)
    if len(ms) == 0 or not (len(ms) == len(matrix) == len(error)):
        raise ValueError("one time, one 3x4 matrix and one error per line, and at least one line")
    if not np.issubdtype(ms.dtype, np.integer) or ms.min() < 0 or ms.max() > UINT32_MAX:
        raise ValueError("YRT-PET reads each time as an unsigned 32-bit integer of milliseconds")
    if np.any(np.diff(ms) <= 0):
        raise ValueError("the times must increase (YRT-PET gives an event the last frame it has reached)")
    if not (np.all(np.isfinite(matrix)) and np.all(np.isfinite(error))):
        raise ValueError("a line without a pose cannot be written for YRT-PET")
    if error.min() < 0 or error.max() > 1:
        raise ValueError("YRT-PET's error is between 0 and 1")
    return "".join(
        f"{int(m)}," + ",".join(f"{v:.9f}" for v in row) + f",{e:.9f}\n" for m, row, e in zip(ms, matrix, error)
    )


def write_lor_motion(path, plan: LorMotionPlan):
    """Write the planned file (whole or not at all; :func:`vts_hw.files.write_atomic` refuses a
    target that is not a regular file)."""
    return write_atomic(path, lor_motion_text(plan.ms, plan.matrix, plan.error).encode("ascii"))
