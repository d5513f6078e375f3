"""The class "session files" of bench/bad_inputs.py (issue 33): what the live path leaves in a scan's
folder -- its patient model (``live_model.json``) and its poses (``live_poses.csv``) -- read back
by `vts motion analyze`, given every kind of bad file a clumsy user, a full disk, a kill or a
hand-edit can leave there: endless (``/dev/zero``), a FIFO nobody writes, 8 GiB sparse, a folder,
binary bytes, JSON that is not a model, a model with numbers no room has, a model of another
patient, a model in the other frame, a pose file with another header, rows of NaN and a row torn
by a kill.

The recording is the sweep's simulated patient session (its parts linked, not copied). A case
passes when the command ends within the time limit, with no traceback, with the analysis done
(exit 0, 10 or 20: a bad live file never stops the offline analysis) and the bad file named in
the analysis' problems (``live model not used`` / ``live poses not compared`` / ``live poses:``).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from badkit.classes import Case, Verdict, common
from vts_hw.tracking.live.pose_log import COLUMNS
from vts_hw.tracking.live.pose_log import MODEL_FILE as MODEL
from vts_hw.tracking.live.pose_log import POSES_FILE as POSES

CLASS = "session files"
HEADER = ",".join(COLUMNS)


def _model(**change) -> str:
    d = {
        "format": "vts-hw patient model v1",
        "frame": "spect",
        "clock": "host",
        "reference_mm": [[9000.0 + 100 * k, 9000.0, 9000.0] for k in range(4)],
        "breathing_vectors": [[0.0, 1.0, 0.0]] * 4,
        "bands": [[0, 1, 2, 3]],
        "band_names": ["band 1"],
        "period": [1.0, 2.0],
        "noise_mm": 0.1,
        "pose_noise_mm": 0.05,
        "pose_noise_deg": 0.01,
        "breathes": True,
    }
    d.update(change)
    return json.dumps(d)


def _write(name: str, text: str | bytes):
    def make(folder: Path) -> None:
        p = folder / name
        p.write_bytes(text) if isinstance(text, bytes) else p.write_text(text)

    return make


def _link(name: str, target: str):
    return lambda folder: (folder / name).symlink_to(target)


def _fifo(name: str):
    return lambda folder: os.mkfifo(folder / name)


def _folder(name: str):
    return lambda folder: (folder / name).mkdir()


def _sparse(name: str):
    def make(folder: Path) -> None:
        with open(folder / name, "wb") as f:
            f.truncate(8 * 2**30)

    return make


#: (what, the problem's words in the analysis, how the bad file is made)
KINDS = [
    ("model /dev/zero", "live model not used", _link(MODEL, "/dev/zero")),
    ("model FIFO", "live model not used", _fifo(MODEL)),
    ("model 8 GiB sparse", "live model not used", _sparse(MODEL)),
    ("model a folder", "live model not used", _folder(MODEL)),
    ("model binary", "live model not used", _write(MODEL, bytes(range(256)) * 4)),
    ("model JSON not a model", "live model not used", _write(MODEL, '{"format": "something else"}')),
    ("model numbers no room has", "live model not used", _write(MODEL, _model(reference_mm=[[1e308, 0, 0]] * 4))),
    ("model NaN vectors", "live model not used", _write(MODEL, _model(breathing_vectors=[[None, 0, 0]] * 4))),
    ("model of another patient", "live model not used", _write(MODEL, _model())),
    ("model in the VTS frame", "live model not used", _write(MODEL, _model(frame="vts"))),
    ("poses /dev/zero", "live poses not compared", _link(POSES, "/dev/zero")),
    ("poses FIFO", "live poses not compared", _fifo(POSES)),
    ("poses 8 GiB sparse", "live poses not compared", _sparse(POSES)),
    ("poses a folder", "live poses not compared", _folder(POSES)),
    ("poses binary", "live poses not compared", _write(POSES, b"\xff\xfe" + bytes(range(256)) * 8)),
    ("poses another header", "live poses not compared", _write(POSES, "t,x,y\n1,2,3\n")),
    (
        "poses NaN rows and a torn row",
        "live poses:",
        _write(POSES, HEADER + "\n" + ",".join(["nan"] * len(COLUMNS)) + "\n" + "1790000010.0,1,0,0"),
    ),
]


def _judge(words: str):
    def judge(wd: Path, code, out, err) -> Verdict:
        v = common(code, err)
        if not v.passed:
            return v
        if code not in (0, 10, 20):
            v.other, v.why = True, f"the analysis stopped (exit {code}) on a bad live file: {err.strip()[-200:]}"
        elif words not in out:
            v.other, v.why = True, f"the bad live file is not named among the analysis' problems ({words!r} not said)"
        return v

    return judge


def cases(inp, only: str | None) -> list[Case]:
    """`vts motion analyze` on the sweep's patient session with each bad live file beside it."""
    if only and not "motion analyze".startswith(only) and not only.startswith("motion analyze"):
        return []
    session, cams, mapping = Path(inp.session), str(inp.cameras), str(inp.mapping)
    out = []
    for what, words, bad in KINDS:

        def make(wd: Path, bad=bad) -> list[str]:
            folder = wd / "session"
            folder.mkdir()
            for part in session.iterdir():
                if part.name not in (MODEL, POSES):
                    (folder / part.name).symlink_to(part.resolve())
            bad(folder)
            return [
                "motion",
                "analyze",
                str(folder),
                "--calibration",
                cams,
                "--mapping",
                mapping,
                "--workers",
                "1",
                "--json",
            ]

        out.append(Case(CLASS, f"motion analyze: {what}", make, _judge(words)))
    return out


__all__ = ["CLASS", "cases", "KINDS"]
