"""A run being written: measurements and artifacts collect in memory, finish() stores them.

The run's row is committed with status "running" when it begins (store.begin_run). finish()
then writes, in ONE transaction, every measurement and artifact and the run's final status
and time: a reader (or a later open after a crash) sees either the run complete or the run
with no measurements at all, never part of it.

abort() stores the status "aborted" and the reason, and NOT the measurements collected so
far: an aborted run never has measurements, whether it was aborted by an exception, by
Ctrl-C, or found dead after ``kill -9`` (whose measurements were only ever in memory). Trends
therefore read finished runs only and need no filtering. The number of measurements and
artifacts left out is written into the notes.
"""

from __future__ import annotations

import hashlib
import logging
import math
import os
import time
from contextlib import AbstractContextManager
from typing import Literal, Protocol

from sqlalchemy import insert, select, update

from vts_hw.errors import VtsError
from vts_hw.store.errors import StoreError
from vts_hw.store.records import FINISH_STATUSES, Run, run_from_row
from vts_hw.store.schema import artifacts, measurements, runs
from vts_hw.tolerance import State, Window, worst

log = logging.getLogger(__name__)


class RunStore(Protocol):
    """What a run handle needs of its store (vts_hw.store.store.ResultsStore is the one): its
    URL for messages, the tolerance window in effect, one write transaction, a run's end."""

    @property
    def url(self) -> str: ...

    def tolerance(self, metric: str, at: float | None = None) -> tuple[int, Window] | None: ...

    def _write(self, windows: bool = False) -> AbstractContextManager: ...

    def _end_run(self, run_id: int, status: str, note: str, finished: float | None) -> bool: ...


class RunHandle:
    """A run in progress (see the module docstring). Use as a context manager:
    an exception or KeyboardInterrupt inside aborts the run; a normal exit finishes it."""

    def __init__(self, store: RunStore, run_id: int, started: float):
        self._store = store
        self.run_id = run_id
        self.started = started
        self._measurements: list[dict] = []
        self._artifacts: list[dict] = []
        self._windows: dict[tuple[str, float], tuple[int, Window] | None] = {}
        self._done = False

    def __repr__(self) -> str:
        state = "done" if self._done else f"{len(self._measurements)} measurement(s) pending"
        return f"<RunHandle run {self.run_id}: {state}>"

    @property
    def done(self) -> bool:
        """True once finish() or abort() has stored the run's end."""
        return self._done

    def _check_open(self) -> None:
        if self._done:
            raise RuntimeError(f"run {self.run_id} has already ended")

    def measure(
        self,
        subject: str,
        metric: str,
        value: float | None,
        unit: str = "",
        status: State | str | None = None,
        at: float | None = None,
    ) -> State:
        """Buffer one measurement and return its state.

        With ``status`` None the state is judged with the window of ``metric`` in effect at
        ``at`` (default: the run's start) and that window's id is kept with it; no window
        means OK and no id. A given status is stored as is, with no window id. A unit left
        empty is taken from the window. NaN is stored as None (not measured)."""
        self._check_open()
        if not isinstance(metric, str) or not metric:
            raise ValueError("a measurement needs a metric name")
        v = None if value is None else float(value)
        if v is not None and math.isnan(v):
            v = None
        tolerance_id = None
        if status is None:
            when = self.started if at is None else float(at)
            key = (metric, when)
            if key not in self._windows:
                self._windows[key] = self._store.tolerance(metric, at=when)
            found = self._windows[key]
            if found is None:
                state = State.OK
            else:
                tolerance_id, window = found
                state = window.state(v)
                unit = unit or window.unit
        else:
            state = State(status)
        self._measurements.append(
            dict(
                subject=str(subject),
                metric=metric,
                value=v,
                unit=str(unit),
                status=state.value,
                tolerance_id=tolerance_id,
            )
        )
        return state

    def artifact(self, path, kind: str = "frame") -> str:
        """Buffer a saved file (its absolute path and sha256, computed now); return the sha256."""
        self._check_open()
        p = os.path.abspath(os.fspath(path))
        with open(p, "rb") as f:
            digest = hashlib.file_digest(f, "sha256").hexdigest()
        self._artifacts.append(dict(path=p, sha256=digest, kind=str(kind)))
        return digest

    def finish(self, status: State | str | None = None, finished: float | None = None, notes: str | None = None) -> Run:
        """Store everything in one transaction and return the run as stored.

        ``status`` defaults to the worst of the measurements' states (OK when none); it may
        also be "error". ``notes`` given replaces the notes given at begin. If the
        transaction fails nothing is stored, the run stays "running" and the handle stays
        open (finish may be retried, or abort called)."""
        self._check_open()
        if status is None:
            final = worst(m["status"] for m in self._measurements).value
        else:
            final = status.value if isinstance(status, State) else str(status)
            if final not in FINISH_STATUSES:
                raise ValueError(
                    f"finish status must be one of {', '.join(FINISH_STATUSES)}, not {final!r} (use abort() to abort)"
                )
        values = {"status": final, "finished": time.time() if finished is None else float(finished)}
        if notes is not None:
            values["notes"] = str(notes)
        with self._store._write() as conn:
            done = conn.execute(
                update(runs).where(runs.c.id == self.run_id, runs.c.status == "running").values(**values)
            )
            if done.rowcount != 1:
                now = conn.scalar(select(runs.c.status).where(runs.c.id == self.run_id))
                raise StoreError(
                    f"{self._store.url}: run {self.run_id} is no longer running (status {now}); nothing was stored"
                )
            if self._measurements:
                conn.execute(insert(measurements), [dict(m, run_id=self.run_id) for m in self._measurements])
            if self._artifacts:
                conn.execute(insert(artifacts), [dict(a, run_id=self.run_id) for a in self._artifacts])
            row = conn.execute(select(runs).where(runs.c.id == self.run_id)).one()
        self._done = True
        return run_from_row(row)

    def abort(self, reason: str) -> None:
        """Mark the run "aborted" with ``reason`` in its notes; buffered measurements are dropped."""
        self._check_open()
        dropped = []
        if self._measurements:
            dropped.append(f"{len(self._measurements)} measurement(s)")
        if self._artifacts:
            dropped.append(f"{len(self._artifacts)} artifact(s)")
        text = f"aborted: {reason}" + (f" ({' and '.join(dropped)} not stored)" if dropped else "")
        self._store._end_run(self.run_id, "aborted", text, finished=time.time())
        self._done = True

    def __enter__(self) -> RunHandle:
        return self

    def __exit__(self, exc_type, exc, tb) -> Literal[False]:
        if self._done:
            return False
        if exc_type is None:
            try:
                self.finish()
            except BaseException as err:
                self._abort_quietly(
                    f"finish failed: {err}"
                    if isinstance(err, VtsError)
                    else f"finish failed: unexpected error ({type(err).__name__}): {err}"
                )
                raise
            return False
        if issubclass(exc_type, KeyboardInterrupt):
            reason = "interrupted (KeyboardInterrupt)"
        elif isinstance(exc, VtsError):  # a user's error: its sentence says it all
            reason = str(exc) or "stopped by an error"
        else:  # a bug: its type helps whoever reads the notes
            reason = (
                f"unexpected error ({exc_type.__name__}): {exc}"
                if str(exc)
                else f"unexpected error ({exc_type.__name__})"
            )
        self._abort_quietly(reason)
        return False  # never swallow the exception

    def _abort_quietly(self, reason: str) -> None:
        """Abort while another exception is on its way out; a failure here must not mask it
        (the run then stays "running" and is marked aborted when its process is gone)."""
        try:
            self.abort(reason)
        except Exception:
            log.exception("could not mark run %s aborted", self.run_id)
