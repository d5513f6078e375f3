"""ResultsStore: QA runs, measurements, tolerance windows and artifacts in one database.

SQLite file by default (see paths.default_url), any SQLAlchemy URL in principle; everything
goes through SQLAlchemy Core with portable types (see schema.py, and docs/decisions/0007).

Opening a store creates or upgrades its schema (migrations.py), then marks "aborted" the runs
this host left "running" whose process is gone (liveness.py). The URL is shown only with the
password masked, and is never written into the database.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import logging
import os
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager

from sqlalchemy import Connection, CursorResult, insert, select, text, update
from sqlalchemy.exc import ArgumentError, DBAPIError, NoSuchModuleError, SQLAlchemyError

from vts_hw import __version__
from vts_hw.store.engine import WRITE_OPTION, make_engine
from vts_hw.store.errors import StoreError
from vts_hw.store.handle import RunHandle
from vts_hw.store.identity import allowed, connection_kind, sqlite_file_kind
from vts_hw.store.liveness import host_name, is_alive, process_start
from vts_hw.store.migrations import ensure_schema, stored_version
from vts_hw.store.paths import StoreTarget, masked, sqlite_file, to_url
from vts_hw.store.people import PeopleMixin
from vts_hw.store.queries import (
    count_runs,
    select_artifacts,
    select_measurements,
    select_rigs,
    select_running_runs,
    select_runs,
    select_runs_newest,
    select_tolerance_at,
    select_tolerances_at,
    select_tolerances_by_id,
)
from vts_hw.store.records import (
    OUTBOX_STATES,
    Artifact,
    Measurement,
    OutboxItem,
    Run,
    artifact_from_row,
    measurement_from_row,
    outbox_from_row,
    run_from_row,
)
from vts_hw.store.schema import SCHEMA_VERSION, outbox, runs, tolerances
from vts_hw.tolerance import Window

log = logging.getLogger(__name__)

#: PostgreSQL advisory lock keys: schema creation/upgrade, and tolerance-window writes
SCHEMA_LOCK = 7007007
WINDOWS_LOCK = 7007008

_BAD_URL = (
    "the results database URL is not valid (expected e.g. sqlite:////path/results.sqlite or postgresql://user@host/db)"
)


def _reason(exc: BaseException) -> str:
    """The driver's own message, short, without SQLAlchemy's statement dump."""
    if isinstance(exc, DBAPIError) and exc.orig is not None:
        return str(exc.orig).strip().splitlines()[0]
    if isinstance(exc, OSError):
        return exc.strerror or str(exc)
    return str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__


def _new_id(result: CursorResult) -> int:
    """The id of the one row an insert() just added (SQLAlchemy gives None, or None in the row
    for a key the database made without returning it)."""
    key = result.inserted_primary_key
    if key is None or key[0] is None:
        raise StoreError("the results store gave no id for the row just added")
    return int(key[0])


def _window(row) -> Window:
    return Window(row.action_low, row.tolerance_low, row.tolerance_high, row.action_high, row.unit)


class ResultsStore(PeopleMixin):
    """The results database. ``url`` None means default_url(); a plain path means a SQLite file.

    ``busy_timeout`` (seconds) is how long a SQLite writer waits for another writer.
    ``password_env`` (PostgreSQL) names the environment variable holding the password; a
    StoreTarget brings its own. ``mode`` says what may become a store (identity.py): ``read``
    only an existing vts-hw store, ``create`` (the default) also a new file (or an empty
    PostgreSQL database), ``init`` any empty database; a database that is not ours never is:
    StoreError, and it is left byte-identical. The console's users and action log are
    people.py's (PeopleMixin)."""

    def __init__(
        self,
        url: str | os.PathLike | StoreTarget | None = None,
        *,
        busy_timeout: float = 30.0,
        password_env: str | None = None,
        mode: str = "create",
    ):
        if isinstance(url, StoreTarget):
            password_env = password_env or url.password_env
        try:
            self._url = to_url(url)
        except ArgumentError:
            raise StoreError(_BAD_URL) from None
        self._closed = False
        self._engine = None
        backend = self._url.get_backend_name()
        path = sqlite_file(self._url)
        if path is not None:  # before any connection of ours: it would switch the file's journal
            allowed(sqlite_file_kind(path, busy_timeout), mode, str(path), backend)
        self._new_file = path if path is not None and not os.path.lexists(path) else None
        try:
            self._engine = make_engine(self._url, busy_timeout, password_env)
            # the common case, an up-to-date store, needs no write lock (a reader must be able
            # to open while a writer holds a long transaction)
            with self._read() as conn:
                if path is None and backend != "sqlite":
                    allowed(connection_kind(conn), mode, self.url, backend)
                found = now = stored_version(conn)
            if found != SCHEMA_VERSION:
                with self._write() as conn:
                    if conn.dialect.name == "postgresql":  # serialise concurrent first opens/upgrades
                        conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": SCHEMA_LOCK})
                    found, now = ensure_schema(conn, self.url)  # checks again under the lock
        except StoreError:
            self._close_failed()
            raise
        except NoSuchModuleError:
            self._close_failed()
            raise StoreError(f"{self.url}: no SQLAlchemy dialect for this kind of database") from None
        except ModuleNotFoundError as exc:
            self._close_failed()
            raise StoreError(f"{self.url}: the database driver {exc.name!r} is not installed") from None
        except (SQLAlchemyError, OSError) as exc:
            self._close_failed()
            raise StoreError(f"{self.url}: cannot open the results store ({_reason(exc)})") from exc
        self.created = found == 0  # this open made the database a store
        if found == 0:
            log.info("%s: created results store (schema version %d)", self.url, now)
        elif found != now:
            log.info("%s: upgraded results store schema from version %d to %d", self.url, found, now)
        try:
            self.mark_dead_runs_aborted()
        except (SQLAlchemyError, StoreError) as exc:  # e.g. another writer holds the lock, or the
            # disk is full: the next open retries
            log.warning("%s: could not check for runs left running (%s)", self.url, _reason(exc))

    # -- plumbing -------------------------------------------------------------------------

    @property
    def url(self) -> str:
        """The database URL with any password masked."""
        return masked(self._url)

    def __repr__(self) -> str:
        return f"ResultsStore({self.url!r})"

    __str__ = __repr__

    def _close_failed(self) -> None:
        """Closed after a failed first open: a SQLite file this open created and left empty (a
        full disk) is removed with its journal, so that no 0-byte "store" is left behind."""
        self.close()
        p = self._new_file
        if p is not None and os.path.isfile(p) and os.path.getsize(p) == 0:
            for q in (p, f"{p}-journal", f"{p}-wal", f"{p}-shm"):
                with contextlib.suppress(OSError):
                    os.unlink(q)

    def close(self) -> None:
        self._closed = True
        if self._engine is not None:
            self._engine.dispose()

    def __enter__(self) -> ResultsStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _connect(self) -> Connection:
        if self._closed or self._engine is None:
            raise RuntimeError(f"the results store {self.url} is closed")
        return self._engine.connect()

    @contextmanager
    def _read(self) -> Iterator[Connection]:
        """A connection for reads; on SQLite each read is one snapshot (BEGIN ... ROLLBACK).
        A database error is a StoreError naming the store."""
        try:
            with self._connect() as conn:
                yield conn
        except (SQLAlchemyError, OSError) as exc:
            raise StoreError(f"{self.url}: cannot read the results store ({_reason(exc)})") from exc

    @contextmanager
    def _write(self, windows: bool = False) -> Iterator[Connection]:
        """One write transaction (SQLite: BEGIN IMMEDIATE); committed on exit, rolled back on
        any exception including KeyboardInterrupt. A database error (disk full, read-only,
        locked for too long) is a StoreError naming the store; nothing of the transaction is
        stored. ``windows``: the transaction reads then adds tolerance windows; on PostgreSQL
        such transactions take one after the other (an advisory lock), as every SQLite write
        does, so two writers syncing the same windows add them once."""
        try:
            with self._connect() as conn:
                conn.execution_options(**{WRITE_OPTION: True})
                with conn.begin():
                    if windows and conn.dialect.name == "postgresql":
                        conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": WINDOWS_LOCK})
                    yield conn
        except (SQLAlchemyError, OSError) as exc:
            raise StoreError(f"{self.url}: cannot write to the results store ({_reason(exc)})") from exc

    @property
    def schema_version(self) -> int:
        with self._read() as conn:
            return stored_version(conn) or 0

    # -- tolerance windows ----------------------------------------------------------------

    @staticmethod
    def _set_tolerance(
        conn: Connection, metric: str, window: Window, effective_from: float, note: str
    ) -> tuple[int, bool]:
        if not isinstance(metric, str) or not metric:
            raise ValueError("a tolerance window needs a metric name")
        if not isinstance(window, Window):
            raise TypeError(f"expected a Window for {metric!r}, got {type(window).__name__}")
        current = conn.execute(select_tolerance_at(metric, effective_from)).first()
        if current is not None and _window(current) == window:
            return current.id, False
        new = conn.execute(
            insert(tolerances).values(
                metric=metric,
                action_low=window.action_low,
                tolerance_low=window.tolerance_low,
                tolerance_high=window.tolerance_high,
                action_high=window.action_high,
                unit=window.unit,
                effective_from=effective_from,
                recorded=time.time(),
                note=note,
            )
        )
        return _new_id(new), True

    def set_tolerance(self, metric: str, window: Window, effective_from: float | None = None, note: str = "") -> int:
        """Add a window for ``metric`` taking effect at ``effective_from`` (default now); return its id.

        History is append-only: nothing already stored changes. If the window in effect at
        that time is identical, nothing is added and its id is returned."""
        when = time.time() if effective_from is None else float(effective_from)
        with self._write(windows=True) as conn:
            return self._set_tolerance(conn, metric, window, when, note)[0]

    def tolerance(self, metric: str, at: float | None = None) -> tuple[int, Window] | None:
        """(id, window) of ``metric`` in effect at ``at`` (default now), None if there was none."""
        when = time.time() if at is None else float(at)
        with self._read() as conn:
            row = conn.execute(select_tolerance_at(metric, when)).first()
        return None if row is None else (row.id, _window(row))

    def tolerances(self, at: float | None = None) -> dict[str, tuple[int, Window]]:
        """Every metric's (id, window) in effect at ``at`` (default now)."""
        when = time.time() if at is None else float(at)
        with self._read() as conn:
            rows = conn.execute(select_tolerances_at(when)).all()
        return {r.metric: (r.id, _window(r)) for r in rows}

    def sync_tolerances(self, windows: dict[str, Window], at: float | None = None) -> list[str]:
        """Make ``windows`` the ones in effect from ``at`` (default now), in one transaction.

        Only metrics whose window differs from the one in effect are added; their names are
        returned. Metrics not in ``windows`` keep their window."""
        when = time.time() if at is None else float(at)
        changed = []
        with self._write(windows=True) as conn:
            for metric, window in windows.items():
                if self._set_tolerance(conn, metric, window, when, note="sync")[1]:
                    changed.append(metric)
        return changed

    # -- runs -----------------------------------------------------------------------------

    def begin_run(
        self,
        procedure: str,
        rig: str = "",
        operator: str = "",
        notes: str = "",
        config_digest: str = "",
        software_version: str | None = None,
        started: float | None = None,
    ) -> RunHandle:
        """Commit a "running" row for a new run (with this host, pid and process start, and a
        new uid) and return its handle. ``software_version`` None means vts_hw.__version__."""
        if not isinstance(procedure, str) or not procedure:
            raise ValueError("a run needs a procedure name")
        if software_version is None:
            software_version = __version__
        when = time.time() if started is None else float(started)
        with self._write() as conn:
            new = conn.execute(
                insert(runs).values(
                    procedure=procedure,
                    rig=rig,
                    started=when,
                    finished=None,
                    status="running",
                    software_version=software_version,
                    config_digest=config_digest,
                    operator=operator,
                    notes=notes,
                    host=host_name(),
                    pid=os.getpid(),
                    process_start=process_start(),
                    uid=uuid.uuid4().hex,
                )
            )
            run_id = _new_id(new)
        return RunHandle(self, run_id, when)

    def _end_run(self, run_id: int, status: str, note: str, finished: float | None) -> bool:
        """Set a still-running run's status, appending ``note`` to its notes; False if it was not running."""
        with self._write() as conn:
            row = conn.execute(select(runs.c.status, runs.c.notes).where(runs.c.id == run_id)).first()
            if row is None or row.status != "running":
                return False
            notes = f"{row.notes}\n{note}" if row.notes else note
            conn.execute(
                update(runs)
                .where(runs.c.id == run_id, runs.c.status == "running")
                .values(status=status, notes=notes, finished=finished)
            )
        return True

    def mark_dead_runs_aborted(self) -> int:
        """Mark "aborted" every run of this host still "running" whose process is gone; return how many.

        Their finished time stays empty (nobody knows when they died). Runs of other hosts,
        and runs whose process cannot be checked, are left alone."""
        me = host_name()
        with self._read() as conn:
            rows = conn.execute(select_running_runs(me)).all()
        n = 0
        for r in rows:
            if is_alive(r.pid, r.process_start) is False:
                stamp = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
                note = f"aborted: its process (pid {r.pid} on {me}) ended without finishing the run (found {stamp})"
                if self._end_run(r.id, "aborted", note, finished=None):
                    n += 1
                    log.warning("%s: run %d was left running by a process that is gone; marked aborted", self.url, r.id)
        return n

    def runs(self, procedure: str | tuple | None = None, since: float | None = None, status=None) -> list[Run]:
        """Runs, oldest first; procedure and status may be one value or a tuple."""
        with self._read() as conn:
            return [run_from_row(r) for r in conn.execute(select_runs(procedure, since, status))]

    def runs_page(
        self,
        procedure=None,
        status=None,
        start: float | None = None,
        end: float | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> tuple[list[Run], int]:
        """One page of runs, newest first, and how many runs the filters keep in all (one
        snapshot). ``procedure``/``status``: one value or a tuple; ``start``/``end``: the runs
        started in [start, end) (UTC epoch seconds)."""
        with self._read() as conn:
            total = conn.execute(count_runs(procedure, status, start, end)).scalar_one()
            rows = conn.execute(select_runs_newest(procedure, status, start, end, limit, offset)).all()
        return [run_from_row(r) for r in rows], int(total)

    def windows(self, ids) -> dict[int, Window]:
        """The tolerance windows with these ids (a measurement's ``tolerance_id``), by id."""
        ids = {int(i) for i in ids if i is not None}
        if not ids:
            return {}
        with self._read() as conn:
            return {r.id: _window(r) for r in conn.execute(select_tolerances_by_id(ids))}

    def rigs(self) -> list[str]:
        """The rig names of the store's runs, sorted ("" for runs stored without a rig name)."""
        with self._read() as conn:
            return [r[0] or "" for r in conn.execute(select_rigs())]

    def run(self, run_id: int) -> Run:
        """One run; KeyError if there is none with that id."""
        with self._read() as conn:
            row = conn.execute(select(runs).where(runs.c.id == run_id)).first()
        if row is None:
            raise KeyError(f"no run {run_id} in {self.url}")
        return run_from_row(row)

    def run_by_uid(self, uid: str) -> Run | None:
        """The run with this uid (its identity across stores), None when there is none."""
        with self._read() as conn:
            row = conn.execute(select(runs).where(runs.c.uid == str(uid))).first()
        return None if row is None else run_from_row(row)

    def measurements(
        self,
        procedure: str | tuple | None = None,
        metric: str | tuple | None = None,
        subject: str | None = None,
        since: float | None = None,
        run_id: int | None = None,
    ) -> list[Measurement]:
        """Measurements, ordered by their run's start, then id."""
        q = select_measurements(procedure, metric, subject, since, run_id)
        with self._read() as conn:
            return [measurement_from_row(r) for r in conn.execute(q)]

    def artifacts(self, run_id: int) -> list[Artifact]:
        with self._read() as conn:
            return [artifact_from_row(r) for r in conn.execute(select_artifacts(run_id))]

    # -- outbox: pushes to other systems ------------------------------------------------------

    def outbox_add(self, run_id: int, target: str, key: str) -> OutboxItem:
        """Put run ``run_id`` in the outbox for ``target`` ("pending"); the row already there
        (whatever its state) is returned unchanged when the run was added before."""
        now = time.time()
        with self._write() as conn:
            q = select(outbox).where(outbox.c.target == target, outbox.c.run_id == run_id)
            row = conn.execute(q).first()
            if row is None:
                conn.execute(
                    insert(outbox).values(
                        run_id=run_id,
                        target=target,
                        key=key,
                        state="pending",
                        attempts=0,
                        last_error="",
                        created=now,
                        updated=now,
                        remote="",
                    )
                )
                row = conn.execute(q).one()
        return outbox_from_row(row)

    def outbox_items(self, target: str, states=None, run_ids=None) -> list[OutboxItem]:
        """Outbox rows for ``target``, oldest first; ``states``/``run_ids`` filter when given."""
        q = select(outbox).where(outbox.c.target == target)
        if states is not None:
            q = q.where(outbox.c.state.in_([str(s) for s in states]))
        if run_ids is not None:
            q = q.where(outbox.c.run_id.in_([int(r) for r in run_ids]))
        with self._read() as conn:
            return [outbox_from_row(r) for r in conn.execute(q.order_by(outbox.c.id))]

    def outbox_record(self, item_id: int, state: str, error: str = "", remote: str | None = None) -> OutboxItem:
        """Record one attempt at pushing an outbox row: its new state, the error (or ""), and
        what it created there; ``attempts`` goes up by one."""
        if state not in OUTBOX_STATES:
            raise ValueError(f"an outbox state is one of {', '.join(OUTBOX_STATES)}, not {state!r}")
        values = dict(state=state, last_error=str(error), updated=time.time(), attempts=outbox.c.attempts + 1)
        if remote is not None:
            values["remote"] = str(remote)
        with self._write() as conn:
            done = conn.execute(update(outbox).where(outbox.c.id == item_id).values(**values))
            if done.rowcount != 1:
                raise KeyError(f"no outbox row {item_id} in {self.url}")
            return outbox_from_row(conn.execute(select(outbox).where(outbox.c.id == item_id)).one())
