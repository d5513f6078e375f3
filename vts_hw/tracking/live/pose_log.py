"""What the live path showed, kept in the scan's folder: the patient model it learned
(``live_model.json``, :class:`~vts_hw.motion.patient_model.PatientModel`) and every pose it
estimated (``live_poses.csv``), so that the offline analysis fits the same model and compares
its poses with the ones the technologist was shown (issue 33; docs/decisions/0092).

``live_poses.csv``: a header line, then one row per live pose, appended as the scan goes (a
kill loses at most the rows not yet flushed, never the earlier ones; a torn last row is
skipped on reading): ``time`` (host UTC epoch s of its frame set), ``r11`` ... ``r33`` (the
rotation, row-major) and ``tx, ty, tz`` (mm) of the pose reference -> now in the model's frame,
``s_mm`` (the respiratory signal), ``rms_mm`` (the fit's residual), ``markers`` (used),
``cameras`` (per marker used, mean), ``state`` (the alert rule's: still, off pose, moving,
ALERT), ``move_mm``/``turn_deg`` (from the alert reference pose), ``health`` (known, bounded,
not known) and ``confidence`` (0 to 1) when it was made (:mod:`vts_hw.pose_health`), ``frames``
(the frames it was made from: per camera of the manifest's ``live_motion.cameras``, in that
order, the frame's number in that camera's recording, ``-1`` none; separated by ``;``).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vts_hw.bounded import SMALL, read_text
from vts_hw.errors import DataError
from vts_hw.files import open_writable, os_reason, write_json_atomic
from vts_hw.motion.patient_model import PatientModel
from vts_hw.pose_health import pose_health

__all__ = ["POSES_FILE", "MODEL_FILE", "PoseLog", "LivePoses", "read_poses", "save_model", "load_model"]

POSES_FILE = "live_poses.csv"
MODEL_FILE = "live_model.json"
COLUMNS = (
    ["time"]
    + [f"r{i}{j}" for i in range(1, 4) for j in range(1, 4)]
    + [
        "tx",
        "ty",
        "tz",
        "s_mm",
        "rms_mm",
        "markers",
        "cameras",
        "state",
        "move_mm",
        "turn_deg",
        "health",
        "confidence",
        "frames",
    ]
)
STATES = ("still", "off pose", "moving", "ALERT")
HEALTH = ("known", "bounded", "not known")
TEXT = (COLUMNS.index("state"), COLUMNS.index("health"), COLUMNS.index("frames"))


class PoseLog:
    """Appends live poses (:class:`~vts_hw.tracking.live.estimator.LivePose`) to
    ``folder/live_poses.csv``: :meth:`write` what is new, flushed; :meth:`close` at the end."""

    def __init__(self, folder):
        self.path = Path(folder) / POSES_FILE
        self._f = open_writable(self.path, "a", encoding="utf-8", newline="")
        if self._f.tell() == 0:
            self._f.write(",".join(COLUMNS) + "\n")
            self._f.flush()
        self.written = 0

    def write(self, poses) -> int:
        """Append ``poses``; returns how many were written."""
        buf = io.StringIO()
        for p in poses:
            if not p.health and p.model_markers:  # its health, from what its fit saw (age 0: when made)
                h = pose_health(p.n_markers, p.model_markers, p.rms_mm, None if np.isnan(p.cameras) else p.cameras)
                p = dataclasses.replace(p, health=h.state, confidence=h.confidence)
            row = (
                [f"{p.time:.6f}"]
                + [f"{x:.9f}" for x in np.asarray(p.R).ravel()]
                + [f"{x:.5f}" for x in np.asarray(p.T)]
                + [
                    f"{p.s:.5f}",
                    f"{p.rms_mm:.5f}",
                    str(p.n_markers),
                    f"{p.cameras:.3f}",
                    p.state,
                    f"{p.move_mm:.4f}",
                    f"{p.turn_deg:.5f}",
                    p.health,
                    f"{p.confidence:.4f}",
                    ";".join(str(int(i)) for i in p.frames),
                ]
            )
            buf.write(",".join(row) + "\n")
        if buf.tell():
            self._f.write(buf.getvalue())
            self._f.flush()
        self.written += len(poses)
        return len(poses)

    def close(self) -> None:
        self._f.close()


@dataclass
class LivePoses:
    """The live pose series of a scan, read back: ``t`` (F,) host s, ``R`` (F,3,3), ``T`` (F,3)
    mm, ``s`` (F,), ``rms_mm``, ``markers``, ``cameras`` (F,), ``state`` (F,) str, ``move_mm``,
    ``turn_deg``, ``health`` (F,) str, ``confidence`` (F,), ``frames`` (F tuples: per camera its
    frame's number, -1 none); ``skipped``: rows that could not be read (a torn last row)."""

    t: np.ndarray
    R: np.ndarray
    T: np.ndarray
    s: np.ndarray
    rms_mm: np.ndarray
    markers: np.ndarray
    cameras: np.ndarray
    state: np.ndarray
    move_mm: np.ndarray
    turn_deg: np.ndarray
    health: np.ndarray
    confidence: np.ndarray
    frames: list
    skipped: int = 0

    def __len__(self) -> int:
        return len(self.t)


def read_poses(folder) -> LivePoses | None:
    """The scan's live poses (None: the scan has none). DataError naming the file when it is not
    a live pose file; rows that do not parse (a row torn by a kill) are counted and skipped."""
    path = Path(folder) / POSES_FILE
    if not path.exists():
        return None
    try:
        text = read_text(path, SMALL, "live pose file")
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot be read as a live pose file ({_reason(exc)})") from None
    rows = csv.reader(io.StringIO(text))
    header = next(rows, None)
    if header != COLUMNS:
        raise DataError(f"{path}: not a live pose file (its first line is not the header {','.join(COLUMNS[:3])},...)")
    num, state, health, frames, skipped = [], [], [], [], 0
    for row in rows:
        try:
            if len(row) != len(COLUMNS) or row[TEXT[0]] not in STATES or row[TEXT[1]] not in HEALTH:
                raise ValueError
            used = tuple(int(i) for i in row[TEXT[2]].split(";")) if row[TEXT[2]] else ()
            if len(used) > 64 or any(i < -1 for i in used):
                raise ValueError
            vals = [float(x) for i, x in enumerate(row) if i not in TEXT]
            if not all(np.isfinite(vals[:16] + vals[17:19])):  # cameras and confidence may be nan (not known)
                raise ValueError
        except ValueError:
            skipped += 1
            continue
        num.append(vals)
        state.append(row[TEXT[0]])
        health.append(row[TEXT[1]])
        frames.append(used)
    a = np.array(num, float).reshape(-1, len(COLUMNS) - 3)
    return LivePoses(
        a[:, 0],
        a[:, 1:10].reshape(-1, 3, 3),
        a[:, 10:13],
        a[:, 13],
        a[:, 14],
        a[:, 15].astype(int),
        a[:, 16],
        np.array(state, dtype=object),
        a[:, 17],
        a[:, 18],
        np.array(health, dtype=object),
        a[:, 19],
        frames,
        skipped,
    )


def _reason(exc: BaseException) -> str:
    return "not UTF-8 text" if isinstance(exc, UnicodeDecodeError) else os_reason(exc)


def save_model(folder, model: PatientModel) -> Path:
    """``folder/live_model.json``, written whole (a temporary file and a rename)."""
    return write_json_atomic(Path(folder) / MODEL_FILE, model.to_dict())


def load_model(folder) -> PatientModel | None:
    """The model the scan's live path learned (None: it learned none)."""
    path = Path(folder) / MODEL_FILE
    if not path.exists():
        return None
    try:
        return PatientModel.from_dict(json.loads(read_text(path, SMALL, "live patient model")))
    except (OSError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot be read as a live patient model ({_reason(exc)})") from None
    except json.JSONDecodeError as exc:
        raise DataError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    except DataError as exc:
        raise DataError(f"{path}: {exc}") from None
