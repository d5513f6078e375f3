"""Storing a QA result, the one way: a run with a measurement per measure, or — when the store
cannot take it — a file beside the store that ``vts qa import`` stores later."""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from vts_hw import __version__
from vts_hw.results import Analysis
from vts_hw.store.errors import StoreError
from vts_hw.store.unsaved import save_unsaved


@dataclass
class Stored:
    """Where a result went: its run id, or the fallback file and why the store refused it."""

    run_id: int | None = None
    unsaved: Path | None = None
    error: str | None = None
    tried: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        return self.run_id is not None


def store_result(store_url, result: Analysis, *, rig: str = "", operator: str = "",
                 config_digest: str = "", started: float | None = None, notes: str = "",
                 artifacts=()) -> Stored:
    """Store ``result`` as a run of ``result.procedure`` in ``store_url`` (a URL, a StoreTarget or
    None for the default); never raises for a store that cannot
    be opened or written — the figures then go to an unsaved-run file (see :class:`Stored`)."""
    from vts_hw.store import ResultsStore

    started = time.time() if started is None else float(started)
    measures = list(result.measures)
    try:
        with ResultsStore(store_url) as store, store.begin_run(
                result.procedure, rig=rig, operator=operator, config_digest=config_digest,
                started=started, notes=notes) as h:
            for m in measures:
                h.measure(m.subject, m.metric, m.value, m.unit, status=str(m.state), at=started)
            for a in artifacts:
                h.artifact(a, kind="plot" if str(a).endswith(".png") else "frame")
            run = h.finish(status=str(result.state))
        return Stored(run_id=run.id)
    except StoreError as exc:
        error = str(exc)
    record = {"procedure": result.procedure, "rig": rig, "operator": operator, "config_digest": config_digest,
              "software_version": __version__, "started": started, "finished": time.time(),
              "state": str(result.state), "store_error": error,
              "measurements": [m.as_dict() for m in measures], "artifacts": [str(a) for a in artifacts],
              "results": result.results_data()}
    path, tried = save_unsaved(store_url, record)
    return Stored(unsaved=path, error=error, tried=tuple(tried))
