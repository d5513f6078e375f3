"""CASToR's rigid involuntary-motion input, written from the motion states.

Two ASCII files (docs/motion-formats.md):

* the **dynamic file** -- ``nb_motion_triggers: N`` and ``timestamp_motion_triggers:`` the N
  state start times in seconds from the acquisition start, comma-separated, the first 0 (the
  reference state; CASToR refuses a first trigger that is not 0);
* the **rigid deformation file** -- ``Transformation_mode: 0`` (each line from the reference, not
  from the line before: CASToR's own default composes them), ``Rotation_convention: XYZ`` and
  ``Transformation_parameters:`` followed by one line per state: tx, ty, tz (mm), rA, rB, rC
  (deg), comma-separated.

What CASToR does with them (``iDeformationRigid``, CASToR 3.1.1, read for this module): it builds
``M = Translation(-t) . Rx(rA) . Ry(rB) . Rz(rC)`` (``XYZ``: the rotations multiplied in that
order) and deforms an image by *pulling*: the output voxel at ``x`` takes the input's value at
``M x``; its forward deformation takes the reference image into motion state n. For the image to
follow the body (``x_state = R x_ref + T``), ``M`` must be the body pose's inverse:
:func:`castor_parameters` gives ``t = R^T T`` and the angles of ``R^T`` in that convention. These
are **not** the 6-DOF of motion_6dof.csv (the pose itself, extrinsic x-y-z). The keywords of the
dynamic file and how CASToR reads them (into an unsigned 32-bit integer of seconds, then times
1000) come from CASToR's ``oDynamicDataManager``. See docs/decisions/0035.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from vts_hw.files import ensure_dir, write_atomic

__all__ = ["write_castor", "castor_parameters", "castor_matrix", "CASTOR_DYNAMIC", "CASTOR_RIGID"]

CASTOR_DYNAMIC = "castor_motion.dyn"
CASTOR_RIGID = "castor_motion_rigid.txt"


def _num(x: float, digits: int) -> str:
    s = f"{x:.{digits}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def castor_parameters(R, T) -> np.ndarray:
    """CASToR's six parameters (tx, ty, tz mm, rA, rB, rC deg; ``Rotation_convention: XYZ``) whose
    matrix (:func:`castor_matrix`) is the inverse of the body pose ``x -> R x + T``."""
    from scipy.spatial.transform import Rotation
    R = np.asarray(R, float)
    Rc = R.T
    t = Rc @ np.asarray(T, float)          # M x = Rc x - t = R^T (x - T)
    return np.concatenate([t, Rotation.from_matrix(Rc).as_euler("XYZ", degrees=True)])


def castor_matrix(params) -> np.ndarray:
    """The 4x4 matrix CASToR builds from six parameters (see the module): Translation(-t) . Rx . Ry . Rz."""
    tx, ty, tz, a, b, c = np.asarray(params, float)
    a, b, c = np.radians([a, b, c])
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    M = np.eye(4)
    M[:3, :3] = rx @ ry @ rz
    M[:3, 3] = [-tx, -ty, -tz]
    return M


def write_castor(starts_s, params, out) -> tuple[Path, Path]:
    """Write both files into ``out``. ``starts_s``: each state's start (s from the acquisition
    start; the first is written as 0: the reference state holds from the start); ``params`` (N, 6):
    CASToR's parameters (:func:`castor_parameters`). Nothing
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
