"""A QA run recorded the one way, for every application that runs one (`vts qa`, the console).

:func:`record_qa` takes a QA run (``procedures.daily.QARun``, given: this layer never imports
a procedure) and records it through the one recorder (:mod:`vts_hw.store.recorder`): the
drift baselines read from the store (NoBaseline, exit 5, before anything is touched), the
"running" row, the cameras measured, one transaction; or the unsaved file when the store
cannot be written. :func:`artifacts_dir` is where the run's saved frames and plots go.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from vts_hw.store.baselines import load_baselines
from vts_hw.store.recorder import ResultRecorder


def artifacts_dir(store) -> Path:
    """Saved frames go beside an SQLite file, else into the per-user data folder."""
    url = str(getattr(store, "url", ""))
    if url.startswith("sqlite:///"):
        return Path(url[len("sqlite:///") :]).parent / "artifacts"
    base = os.environ.get("XDG_DATA_HOME") or os.path.join(os.path.expanduser("~"), ".local", "share")
    return Path(base) / "vts-hw" / "artifacts"


def record_qa(store, qa, rig, *, operator: str = "", clock=time.time):
    """Run ``qa`` (procedures.daily.QARun) and record it the one way (store.recorder): the
    baselines read from ``store`` (NoBaseline, exit 5, before anything is touched), the
    "running" row, the cameras measured, one transaction — or the unsaved file when the store
    cannot be written. Returns the QAResult (``run_id``, ``store_error``) and where it went."""
    qa.preflight()
    if qa.needs_baselines:
        qa.baselines = {**load_baselines(store, qa.camera_names, rig.rig), **qa.baselines}
    now = clock()
    with ResultRecorder(
        store,
        qa.procedure,
        rig=rig.rig,
        operator=operator,
        config_digest=rig.digest,
        tolerances=rig.tolerances,
        started=now,
        clock=clock,
    ) as rec:
        result = qa.run(started=now, run_id=rec.run_id)
        stored = rec.finish(result, artifacts=result.artifacts, finished=result.finished)
    result.run_id, result.store_error = stored.run_id, stored.error
    return result, stored


__all__ = ["record_qa", "artifacts_dir"]
