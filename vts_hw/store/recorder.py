"""The one recorder of results: every QA result reaches the store this way.

    with ResultRecorder(store_or_url, "daily", rig="room1", tolerances=rig.tolerances) as rec:
        result = ...                 # measure; rec.run_id is the run's id (None: not storable)
        stored = rec.finish(result)  # one transaction; or the unsaved file when the store refuses

1. ``begin`` (or entering the ``with``): the tolerance windows in use (the defaults with the
   rig's on top) are synced into the store, then the run's "running" row is committed, so a run
   killed half-way is found and marked aborted.
2. ``finish(result)``: every measure, artifact and the run's state in ONE transaction
   (store.handle.RunHandle). A measure whose metric has a window, and whose state that window
   gives, is judged by the store and keeps the window's id; any other keeps the state its
   procedure gave it (a figure judged by another metric's window, a verdict of its own).
3. A store that cannot be opened or written, at the start or at the end, never costs a figure:
   the run goes to one unsaved format (store.unsaved) that ``vts qa import`` stores later, as
   it would have been stored.

An exception inside the ``with`` marks the run aborted with the reason. :func:`record` is
begin and finish at once, for a result analysed from files. Procedures never see a store: they
return their analyses, and receive what they need (a baseline, a calibration) from the caller.
See docs/decisions/0057-one-recorder-one-catalog.md.
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from vts_hw import __version__, catalog
from vts_hw.errors import DataError
from vts_hw.files import check_target
from vts_hw.results import Analysis, Measure
from vts_hw.store.errors import StoreError
from vts_hw.store.handle import RunHandle
from vts_hw.store.store import ResultsStore
from vts_hw.store.unsaved import load_unsaved, save_unsaved
from vts_hw.tolerance import State, Window

log = logging.getLogger(__name__)


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


def _write(h, measures, artifacts, windows: dict[str, Window], *, at: float) -> None:
    """A run's measures and artifacts onto its handle ``h``: a measure its metric's window
    judges (the window gives its state) keeps the window's id, any other its own state."""
    for m in measures:
        w = windows.get(m.metric)
        own = w is not None and w.state(m.value) == m.state
        h.measure(m.subject, m.metric, m.value, m.unit, status=None if own else str(m.state), at=at)
    for a in artifacts:
        h.artifact(a, kind="plot" if str(a).endswith(".png") else "frame")


class ResultRecorder:
    """One run of ``procedure`` on its way to the store ``target`` (a URL, a StoreTarget, None
    for the default, or an open ResultsStore, then left open). See the module docstring."""

    def __init__(
        self,
        target,
        procedure: str,
        *,
        rig: str = "",
        operator: str = "",
        config_digest: str = "",
        tolerances=None,
        started: float | None = None,
        notes: str = "",
        clock=time.time,
    ):
        self.target = target
        self.procedure = procedure
        self.rig, self.operator, self.config_digest, self.notes = rig, operator, config_digest, notes
        self.windows: dict[str, Window] = catalog.windows(tolerances)  # the catalog's, the rig's on top
        self.clock = clock
        self.started = clock() if started is None else float(started)
        self.error: str | None = None  # why the store could not be written (then: unsaved)
        self._store: ResultsStore | None = None
        self._own_store = False
        self._handle: RunHandle | None = None
        self._done = False

    @property
    def run_id(self) -> int | None:
        return self._handle.run_id if self._handle is not None else None

    @property
    def url(self):
        return self._store.url if self._store is not None else self.target

    def begin(self) -> ResultRecorder:
        """Sync the windows and commit the "running" row; a store that cannot take them is
        remembered (``error``), never raised: the figures go to the unsaved file at the end."""
        try:
            if isinstance(self.target, ResultsStore):
                self._store = self.target
            else:
                self._store, self._own_store = ResultsStore(self.target), True
            self._store.sync_tolerances(self.windows, at=self.started)
            self._handle = self._store.begin_run(
                self.procedure,
                rig=self.rig,
                operator=self.operator,
                started=self.started,
                config_digest=self.config_digest,
                notes=self.notes,
            )
        except StoreError as exc:
            self.error = str(exc)
        return self

    def finish(
        self, result: Analysis, *, artifacts=(), finished: float | None = None, notes: str | None = None
    ) -> Stored:
        """Store ``result`` in one transaction, else keep it in the unsaved file; never raises
        for a store that cannot be written."""
        if self._done:
            raise RuntimeError(f"the {self.procedure} run has already been recorded")
        finished = self.clock() if finished is None else float(finished)
        measures = [m if isinstance(m, Measure) else Measure(*m) for m in result.measures]
        state, artifacts = result.state, [str(a) for a in artifacts]
        if notes is not None:
            self.notes = notes
        h = self._handle
        if h is not None:
            try:
                _write(h, measures, artifacts, self.windows, at=self.started)
                run = h.finish(status=str(state), finished=finished, notes=notes)
                self._done = True
                self._close()
                return Stored(run_id=run.id)
            except StoreError as exc:
                self.error = str(exc)
                try:  # likely to fail too; else the next open marks it aborted (its process is gone)
                    h.abort(f"the run could not be stored ({exc}); its figures were kept elsewhere")
                except StoreError:
                    pass
        self._done = True
        if hasattr(result, "store_error"):  # a result that says whether it was stored hears it first
            result.store_error = self.error
        record = {
            "procedure": self.procedure,
            "rig": self.rig,
            "operator": self.operator,
            "config_digest": self.config_digest,
            "software_version": __version__,
            "started": self.started,
            "finished": finished,
            "state": str(state),
            "store_error": self.error,
            "notes": self.notes,
            "measurements": [m.as_dict() for m in measures],
            "tolerances": {k: w.as_dict() for k, w in self.windows.items()},
            "artifacts": artifacts,
            "results": result.results_data(),
        }
        path, tried = save_unsaved(self.url, record)
        self._close()
        return Stored(unsaved=path, error=self.error, tried=tuple(tried))

    def abort(self, reason: str) -> None:
        """Mark the running run aborted with ``reason`` (nothing of it is stored)."""
        if self._handle is not None and not self._handle.done:
            self._handle._abort_quietly(reason)
        self._done = True
        self._close()

    def _close(self) -> None:
        if self._own_store and self._store is not None:
            self._store.close()
            self._own_store = False

    def __enter__(self) -> ResultRecorder:
        return self.begin()

    def __exit__(self, exc_type, exc, tb) -> Literal[False]:
        if not self._done:
            if exc_type is None:
                self.abort("the procedure ended without a result to store")
            elif self._handle is not None and not self._handle.done:
                self._handle.__exit__(exc_type, exc, tb)  # aborted with the reason
                self._done = True
        self._close()
        return False


def record(
    target,
    result: Analysis,
    *,
    rig: str = "",
    operator: str = "",
    config_digest: str = "",
    tolerances=None,
    started: float | None = None,
    finished: float | None = None,
    notes: str = "",
    artifacts=(),
    clock=time.time,
) -> Stored:
    """Record an analysed ``result`` as a run of ``result.procedure``: begin and finish at once."""
    rec = ResultRecorder(
        target,
        result.procedure,
        rig=rig,
        operator=operator,
        config_digest=config_digest,
        tolerances=tolerances,
        started=started,
        notes=notes,
        clock=clock,
    ).begin()
    try:
        return rec.finish(result, artifacts=artifacts, finished=finished)
    except BaseException as exc:
        if not rec._done:
            rec.__exit__(type(exc), exc, exc.__traceback__)
        raise


def import_unsaved(store, path: str | Path) -> int:
    """Store an unsaved run with its own start and finish times, states and notes; return
    its run id. The tolerance windows it was judged by (when the file holds them) are synced
    at its start, and a measure its window judged keeps that window's id, as the recorder
    would have stored it. The file is renamed ``*.imported`` so that it is
    never stored twice."""
    p = Path(path)
    doc = load_unsaved(p)
    done = p.with_name(p.name + ".imported")
    check_target(done, "nothing was stored")  # a device, FIFO or link there: refused before it is stored
    try:
        procedure, started = str(doc["procedure"]), float(doc["started"])
        windows = {str(k): Window(**w) for k, w in (doc.get("tolerances") or {}).items()}
        if windows:
            store.sync_tolerances(windows, at=started)
        note = (
            f"imported from {p.name}: the store could not take it when it ran "
            f"({doc.get('store_error', 'unknown reason')})"
        )
        with store.begin_run(
            procedure,
            rig=doc.get("rig", ""),
            operator=doc.get("operator", ""),
            config_digest=doc.get("config_digest", ""),
            started=started,
            software_version=doc.get("software_version"),
            notes=f"{doc['notes']}\n{note}" if doc.get("notes") else note,
        ) as h:
            measures = [
                Measure(m["subject"], m["metric"], m["value"], m.get("unit", ""), State(m["state"]))
                for m in doc["measurements"]
            ]
            # an artifact gone since (or a folder named instead) is left out
            _write(h, measures, [a for a in doc.get("artifacts", []) if Path(a).is_file()], windows, at=started)
            run = h.finish(status=doc["state"], finished=float(doc.get("finished") or started))
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(f"{p}: not an unsaved run written by vts ({exc})") from None
    os.replace(p, done)
    return run.id
