"""CASToR's rigid involuntary-motion input, written from the motion states, as CASToR reads it.

Two ASCII files (docs/motion-formats.md, docs/decisions/0035 and 0043):

* the **dynamic file** -- ``nb_motion_triggers: N`` and ``timestamp_motion_triggers:`` the N
  trigger times, comma-separated, **whole seconds** from the acquisition start, the first 0;
* the **rigid deformation file** -- ``Transformation_mode: 0`` (each line from the reference, not
  from the line before: CASToR's own default composes them), ``Rotation_convention: XYZ`` and
  ``Transformation_parameters:`` followed by one line per trigger: tx, ty, tz (mm), rA, rB, rC
  (deg), comma-separated.

How CASToR 3.1.1 reads them (its sources, read for this module):

* **Time** (``oDynamicDataManager``, ``gOptions``): each trigger is parsed into an unsigned 32-bit
  integer by ``strtol`` -- ``25.9`` silently becomes ``25`` -- then times 1000; an event (list-mode
  time in ms) belongs to trigger k when its time is ``>= 1000 * trigger_k`` and below the next.
  Two triggers in the same second make CASToR jump over a state, and its backward deformation
  then undoes the data with the next line's transform (``vDeformation::PerformDeformation`` uses
  ``index - 1``). So :func:`castor_schedule` writes integers only: each whole second of the scan
  goes to the state that holds most of it (a boundary moves at most 0.5 s); a state that holds
  no second's majority is merged into its neighbours and said so (never silently dropped).
  ``#`` starts a comment in both files (text after it is dropped before any keyword is looked
  for), which the header lines use; the parameter lines themselves are read raw.
* **Transform** (``iDeformationRigid``, ``oMatrix``): ``M = Translation(-t) . Rx(rA) . Ry(rB) .
  Rz(rC)``, and an image is deformed by *pulling*: the output voxel at ``x`` takes the input's value
  at ``M x``; the forward deformation takes the reconstructed (reference) image into the state of
  line n. For it to follow the body (``x_state = R x_ref + T``), ``M`` is the pose's inverse:
  :func:`castor_parameters` gives ``t = R^T T`` and the angles of ``R^T``. CASToR's *backward*
  deformation is ``Translation(+t) . Rx(-rA) . Ry(-rB) . Rz(-rC)``, the exact inverse only for a
  pure translation or a turn about one axis through the origin (:func:`castor_backward_matrix`).
* **Frame** (``iDeformationRigid::TransformImage``): a voxel's position is ``(i + 0.5 - N/2) * s``
  along each matrix axis -- origin at the **centre of the image matrix**, x, y, z along CASToR's
  matrix [1], [2], [3]. CASToR's documented frame is left-handed: x to the right seen from the
  front of the gantry, y up, z into the gantry; for a head-first supine patient x is the patient's
  left, y anterior, z towards the head (:data:`CASTOR_FRAME`). From the SPECT frame
  (vts_hw.spect.frame: X left, Y anterior, Z feet, right-handed) that is ``x = A (X - c)`` with
  ``A = diag(1, 1, -1)`` and ``c`` the centre of the volume the VTS -> SPECT mapping was made from
  (a reconstruction is centred on the field of view, as CASToR centres its images):
  :func:`castor_frame`.
* **Reference**: line 1 (the state at the acquisition start) is the identity, as CASToR's
  documentation asks; every line is that state's pose taken to the line's state, so the image
  CASToR reconstructs is the patient as at the acquisition start (not the pose of motion_6dof's
  reference, the first still period).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vts_hw.files import ensure_dir, write_atomic

__all__ = [
    "write_castor",
    "castor_parameters",
    "castor_matrix",
    "castor_backward_matrix",
    "castor_schedule",
    "castor_frame",
    "fov_centre",
    "to_castor_frame",
    "plan_castor",
    "CastorPlan",
    "CASTOR_DYNAMIC",
    "CASTOR_RIGID",
    "CASTOR_FRAME",
    "CASTOR_FROM_SPECT",
]

CASTOR_DYNAMIC = "castor_motion.dyn"
CASTOR_RIGID = "castor_motion_rigid.txt"
CASTOR_FROM_SPECT = np.diag([1.0, 1.0, -1.0])  # CASToR axes from SPECT axes (both origin-free)
CASTOR_FRAME = (
    "CASToR image frame: mm, left-handed as CASToR documents it; x towards the patient's left "
    "(right as seen from the front of the gantry), y anterior (up), z towards the head (into the "
    "gantry), for a head-first supine patient; origin at the centre of CASToR's image matrix, "
    "taken as the centre of the volume the VTS -> SPECT mapping was made from; x = SPECT X, "
    "y = SPECT Y, z = -SPECT Z"
)


def _num(x: float, digits: int) -> str:
    s = f"{x:.{digits}f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def castor_parameters(R, T) -> np.ndarray:
    """CASToR's six parameters (tx, ty, tz mm, rA, rB, rC deg; ``Rotation_convention: XYZ``) whose
    matrix (:func:`castor_matrix`) is the inverse of the body pose ``x -> R x + T`` (both in
    CASToR's image frame)."""
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, float)
    Rc = R.T
    t = Rc @ np.asarray(T, float)  # M x = Rc x - t = R^T (x - T)
    return np.concatenate([t, Rotation.from_matrix(Rc).as_euler("XYZ", degrees=True)])


def _rot(a, b, c) -> np.ndarray:
    a, b, c = np.radians([a, b, c])
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return rx @ ry @ rz


def castor_matrix(params) -> np.ndarray:
    """The 4x4 forward matrix CASToR builds from six parameters: Translation(-t) . Rx . Ry . Rz."""
    tx, ty, tz, a, b, c = np.asarray(params, float)
    M = np.eye(4)
    M[:3, :3] = _rot(a, b, c)
    M[:3, 3] = [-tx, -ty, -tz]
    return M


def castor_backward_matrix(params) -> np.ndarray:
    """The 4x4 backward matrix CASToR 3.1.1 builds: Translation(+t) . Rx(-rA) . Ry(-rB) . Rz(-rC)
    -- the inverse of :func:`castor_matrix` only for a pure translation or a turn about one axis."""
    tx, ty, tz, a, b, c = np.asarray(params, float)
    M = np.eye(4)
    M[:3, :3] = _rot(-a, -b, -c)
    M[:3, 3] = [tx, ty, tz]
    return M


def fov_centre(volume: dict | None, program: str = "CASToR's image") -> np.ndarray:
    """The SPECT-frame centre of the volume the mapping was made from (where a reconstruction's
    field of view is centred), for a head-first supine patient; ValueError with one sentence
    naming ``program``'s frame when it is not known (also for vts_hw.motion.yrtpet)."""
    if not volume or volume.get("centre_mm") is None:
        raise ValueError(
            "the VTS -> SPECT mapping does not say which SPECT volume it was made from (it was "
            f"made before mappings recorded it), so the centre of {program} is not known in "
            "its frame: make the mapping again with `vts calibrate spect`"
        )
    position = volume.get("patient_position")
    if position not in (None, "HFS"):
        raise ValueError(
            f"the mapping volume {volume.get('file')} says PatientPosition {position}; the turn "
            f"into {program} frame is known here for head-first supine (HFS) only"
        )
    c = np.asarray(volume["centre_mm"], float).reshape(3)
    if not np.all(np.isfinite(c)):
        raise ValueError(f"the mapping volume's centre {volume['centre_mm']} is not three finite numbers")
    return c


def castor_frame(volume: dict | None) -> tuple[np.ndarray, np.ndarray]:
    """``(A, c)``: a SPECT-frame point ``X`` is ``A (X - c)`` in CASToR's image frame (see the
    module). ``volume``: what the mapping kept of its volume (vts_hw.spect.frame.volume_record).
    ValueError with one sentence when the conversion is not known."""
    return CASTOR_FROM_SPECT.copy(), fov_centre(volume, "CASToR's image")


def to_castor_frame(R, T, A, c) -> tuple[np.ndarray, np.ndarray]:
    """The pose ``x -> R x + T`` (SPECT frame) in CASToR's frame ``y = A (x - c)``: ``y -> A R A^T y
    + A (R c + T - c)``."""
    R, T, A, c = (np.asarray(v, float) for v in (R, T, A, c))
    return A @ R @ A.T, A @ (R @ c + T - c)


def castor_schedule(starts) -> tuple[list[tuple[int, int]], list[int]]:
    """Whole-second triggers for states starting at ``starts`` (s from the acquisition start,
    increasing; state k holds [starts[k], starts[k+1]), the first from -inf, the last to +inf).

    Each whole second ``[n, n+1)`` (n >= 0) goes to the state holding most of it (a tie to the
    earlier state). Returns ``(lines, merged)``: ``lines`` the (state position, trigger second) of
    every state that holds some second, in time order, the first at 0; ``merged`` the positions of
    the states that hold none (shorter than a second where they start, or ended before 0)."""
    s = np.asarray(starts, float).reshape(-1)
    if len(s) == 0:
        raise ValueError("no motion state to schedule")
    if len(s) > 1 and np.any(np.diff(s) <= 0):
        raise ValueError("motion state start times must increase")
    lo = np.concatenate([[-np.inf], s[1:]])
    hi = np.concatenate([s[1:], [np.inf]])
    seconds = {0}
    for b in s[1:]:
        n = math.floor(b)
        seconds.update(x for x in (n, n + 1) if x >= 0)
    first: dict[int, int] = {}
    for n in sorted(seconds):
        held = np.clip(np.minimum(hi, n + 1) - np.maximum(lo, n), 0.0, None)
        k = int(np.argmax(held))  # the first of equal holders: the earlier state
        first.setdefault(k, n)
    lines = sorted(((k, n) for k, n in first.items()), key=lambda kn: kn[1])
    merged = [k for k in range(len(s)) if k not in first]
    return lines, merged


@dataclass
class CastorPlan:
    """What :func:`plan_castor` decided: ``why`` (one sentence) when no CASToR file is written,
    else the lines (``states``: indices, ``triggers``: whole seconds, ``params``: CASToR's six
    numbers) and the states merged into their neighbours (``merged``: sentences)."""

    why: str | None = None
    states: list = field(default_factory=list)
    triggers: list = field(default_factory=list)
    params: list = field(default_factory=list)
    merged: list = field(default_factory=list)
    reference: int | None = None
    A: np.ndarray | None = None
    c: np.ndarray | None = None

    def to_json(self, files=()) -> dict:
        if self.why:
            return {"written": False, "why": self.why}
        if self.A is None or self.c is None:  # set whenever there is no why
            raise ValueError("a CASToR motion without its frame to write")
        nxt = self.triggers[1:] + [None]
        return {
            "written": True,
            "files": [str(Path(f).name) for f in files],
            "frame": CASTOR_FRAME,
            "from_spect": {
                "axes": self.A.tolist(),
                "centre_mm": self.c.tolist(),
                "rule": "x_castor = axes @ (x_spect - centre_mm)",
            },
            "reference_state": self.reference,
            "time": "triggers in whole seconds of the SPECT list-mode from the acquisition start: CASToR "
            "reads them as integers; each whole second goes to the state that holds most of it",
            "lines": [
                {"line": i + 1, "state": k, "trigger_s": n, "interval_s": [n, m], "parameters": list(p)}
                for i, (k, n, m, p) in enumerate(zip(self.states, self.triggers, nxt, self.params))
            ],
            "merged": list(self.merged),
        }


def not_on_the_scanner(what: str, clock: str, frame: str, takes: str, its_frame: str) -> str:
    """Why a reconstruction program's file (``what``) is not written: its times not on the SPECT
    list-mode clock (the program ``takes`` them so), or its poses not in the SPECT frame (not
    ``its_frame``); "" when both are. The one rule of CASToR's files and YRT-PET's."""
    if clock != "spect":
        return (
            f"{what} not written: the times are host-clock seconds (no --listmode), and {takes}; give the "
            f"scan's list-mode"
        )
    if frame != "spect":
        return f"{what} not written: no VTS -> SPECT mapping, so the poses are in the VTS frame, not {its_frame}"
    return ""


def plan_castor(states, t0: float, *, clock: str, frame: str, volume: dict | None) -> CastorPlan:
    """Decide the CASToR files for ``states`` (MotionState, times on ``clock``; ``t0`` the
    acquisition start on it): the whole-second schedule, each line's parameters in CASToR's
    image frame from the pose at the acquisition start; or why none are written."""
    why = not_on_the_scanner(
        "CASToR files", clock, frame, "CASToR takes its triggers as SPECT list-mode seconds", "CASToR's image frame"
    )
    if why:
        return CastorPlan(why=why)
    try:
        A, c = castor_frame(volume)
    except ValueError as e:
        return CastorPlan(why=f"CASToR files not written: {e}")
    try:
        lines, merged = castor_schedule([s.t_start - t0 for s in states])
    except ValueError as e:  # no state, or two starting at once
        return CastorPlan(why=f"CASToR files not written: {e}")
    for k, _ in lines:
        if states[k].R is None:
            s = states[k]
            return CastorPlan(
                why=f"CASToR files not written: state {s.index} ({s.t_start - t0:.2f}-{s.t_end - t0:.2f} s) "
                "has no pose (no frame with 3 markers)"
            )
    ref = states[lines[0][0]]
    notes = []
    for k in merged:
        s = states[k]
        a, b = s.t_start - t0, s.t_end - t0
        if b <= 0:
            notes.append(f"state {s.index} ({a:.2f}-{b:.2f} s) ended before the acquisition start: no CASToR line")
        else:
            notes.append(
                f"state {s.index} ({a:.2f}-{b:.2f} s) holds most of no whole second: CASToR's triggers "
                "are whole seconds, so its data go to its neighbours' lines"
            )
    params = []
    for k, _ in lines:
        s = states[k]
        R = s.R @ ref.R.T  # the pose at the acquisition start -> state k
        T = s.T - R @ ref.T
        Rc, Tc = to_castor_frame(R, T, A, c)
        params.append([round(float(v), 4) + 0.0 for v in castor_parameters(Rc, Tc)])  # + 0.0: no -0.0
    return CastorPlan(None, [states[k].index for k, _ in lines], [n for _, n in lines], params, notes, ref.index, A, c)


def write_castor(triggers, params, out, *, comment: str | None = None) -> tuple[Path, Path]:
    """Write both files into ``out``. ``triggers``: whole seconds from the acquisition start, the
    first 0, increasing; ``params`` (N, 6): CASToR's parameters (:func:`castor_parameters`).
    ``comment``: one header line (after ``#``) in each file."""
    trig = list(triggers)
    params = np.asarray(params, float).reshape(-1, 6)
    if len(trig) != len(params) or len(trig) == 0:
        raise ValueError("one trigger and one set of parameters per CASToR line")
    if any(int(n) != n or n < 0 for n in trig) or trig[0] != 0:
        raise ValueError(f"CASToR triggers must be whole seconds from 0 (CASToR reads integers): {trig}")
    if len(trig) > 1 and any(b <= a for a, b in zip(trig, trig[1:])):
        raise ValueError("CASToR triggers must increase")
    if not np.all(np.isfinite(params)):
        raise ValueError("a motion state without a pose cannot be written for CASToR")
    out = ensure_dir(out, "export folder")
    head = "" if not comment else "# " + " ".join(comment.replace("#", " ").split()) + "\n"
    dyn = (
        head
        + f"nb_motion_triggers: {len(trig)}\n"
        + "timestamp_motion_triggers: "
        + ",".join(str(int(n)) for n in trig)
        + "\n"
    )
    rig = (
        head
        + "Transformation_mode: 0\nRotation_convention: XYZ\nTransformation_parameters:\n"
        + "".join(",".join(_num(v, 4) for v in p) + "\n" for p in params)
    )
    p1, p2 = out / CASTOR_DYNAMIC, out / CASTOR_RIGID
    write_atomic(p1, dyn.encode("ascii"))
    write_atomic(p2, rig.encode("ascii"))
    return p1, p2
