"""CASToR's rigid involuntary-motion input, written from the motion states.

Two ASCII files (docs/motion-formats.md):

* the **dynamic file** -- ``nb_motion_triggers: N`` and ``timestamp_motion_triggers:`` the N
  state start times in seconds from the acquisition start, comma-separated, the first 0 (the
  reference state; CASToR refuses a first trigger that is not 0);
* the **rigid deformation file** -- ``Transformation_mode: 0``, ``Rotation_convention: XYZ``
  and ``Transformation_parameters:`` followed by one line per state: tx, ty, tz (mm), rx, ry,
  rz (deg), comma-separated, the state's pose from the reference state's.

The keywords of the dynamic file and how CASToR reads them (into an unsigned 32-bit integer of
seconds, then times 1000) come from CASToR's ``oDynamicDataManager``; the keywords of the
deformation file from the brief and CASToR's documentation as quoted there (docs/decisions/0035).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vts_hw.files import ensure_dir, write_atomic

__all__ = ["write_castor", "CASTOR_DYNAMIC", "CASTOR_RIGID"]

CASTOR_DYNAMIC = "castor_motion.dyn"
CASTOR_RIGID = "castor_motion_rigid.txt"


def _num(x: float, digits: int) -> str:
    s = f"{x:.{digits}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def write_castor(starts_s, params, out) -> tuple[Path, Path]:
    """Write both files into ``out``. ``starts_s``: each state's start (s from the acquisition
    start; the first is written as 0: the reference state holds from the start); ``params`` (N, 6): tx, ty, tz mm, rx, ry, rz deg. Nothing
    but keywords and numbers is written (no comment lines): what the files mean is in the 6-DOF
    JSON beside them."""
    starts = np.asarray(starts_s, float).reshape(-1)
    params = np.asarray(params, float).reshape(-1, 6)
    if len(starts) != len(params) or len(starts) == 0:
        raise ValueError("one start time and one set of parameters per motion state")
    if not np.all(np.isfinite(params)):
        raise ValueError("a motion state without a pose cannot be written for CASToR")
    if len(starts) > 1 and np.any(np.diff(starts) <= 0):
        raise ValueError("motion state start times must increase")
    starts = starts.copy()
    starts[0] = 0.0      # the reference state holds from the acquisition start
    out = ensure_dir(out, "export folder")
    dyn = (f"nb_motion_triggers: {len(starts)}\n"
           + "timestamp_motion_triggers: " + ",".join(_num(s, 3) for s in starts) + "\n")
    rig = ("Transformation_mode: 0\nRotation_convention: XYZ\nTransformation_parameters:\n"
           + "".join(",".join(_num(v, 4) for v in p) + "\n" for p in params))
    p1, p2 = out / CASTOR_DYNAMIC, out / CASTOR_RIGID
    write_atomic(p1, dyn.encode("ascii"))
    write_atomic(p2, rig.encode("ascii"))
    return p1, p2
