"""The store's queries as SQLAlchemy Core statements, built without a connection.

Keeping them here, as functions returning statements, lets a test compile each one for
PostgreSQL (no server needed) and lets reports reuse them.
"""

from __future__ import annotations

from collections.abc import Iterable

from sqlalchemy import Select, and_, func, select

from vts_hw.store.schema import artifacts, measurements, runs, tolerances


def _one_or_many(col, value):
    """``col = v`` for one value, ``col IN (...)`` for a tuple/list/set."""
    if isinstance(value, (str, bytes)) or not isinstance(value, Iterable):
        return col == str(value)
    return col.in_([str(v) for v in value])


def select_runs(procedure=None, since: float | None = None, status=None) -> Select:
    """Runs, oldest first; each filter is one value or a tuple of values."""
    q = select(runs)
    if procedure is not None:
        q = q.where(_one_or_many(runs.c.procedure, procedure))
    if since is not None:
        q = q.where(runs.c.started >= since)
    if status is not None:
        q = q.where(_one_or_many(runs.c.status, status))
    return q.order_by(runs.c.started, runs.c.id)


def _history_filter(q, procedure=None, status=None, start: float | None = None, end: float | None = None):
    if procedure is not None:
        q = q.where(_one_or_many(runs.c.procedure, procedure))
    if status is not None:
        q = q.where(_one_or_many(runs.c.status, status))
    if start is not None:
        q = q.where(runs.c.started >= start)
    if end is not None:
        q = q.where(runs.c.started < end)
    return q


def select_runs_newest(
    procedure=None, status=None, start: float | None = None, end: float | None = None, limit: int = 50, offset: int = 0
) -> Select:
    """One page of runs, newest first (by start, then id), started in [start, end) when given."""
    q = _history_filter(select(runs), procedure, status, start, end)
    return q.order_by(runs.c.started.desc(), runs.c.id.desc()).limit(int(limit)).offset(int(offset))


def count_runs(procedure=None, status=None, start: float | None = None, end: float | None = None) -> Select:
    """How many runs :func:`select_runs_newest` pages through."""
    return _history_filter(select(func.count()).select_from(runs), procedure, status, start, end)


def select_tolerances_by_id(ids: Iterable[int]) -> Select:
    """The tolerance windows with these ids (the ones measurements were judged by)."""
    return select(tolerances).where(tolerances.c.id.in_([int(i) for i in ids])).order_by(tolerances.c.id)


def select_rigs() -> Select:
    """Every rig name that has a run, in order (an empty name too: runs stored without a rig config)."""
    return select(runs.c.rig).distinct().order_by(runs.c.rig)


def select_measurements(
    procedure=None, metric=None, subject: str | None = None, since: float | None = None, run_id: int | None = None
) -> Select:
    """Measurements with their run's start time, ordered by run start, then id."""
    q = select(measurements, runs.c.started).join_from(measurements, runs, measurements.c.run_id == runs.c.id)
    if procedure is not None:
        q = q.where(_one_or_many(runs.c.procedure, procedure))
    if metric is not None:
        q = q.where(_one_or_many(measurements.c.metric, metric))
    if subject is not None:
        q = q.where(measurements.c.subject == subject)
    if since is not None:
        q = q.where(runs.c.started >= since)
    if run_id is not None:
        q = q.where(measurements.c.run_id == run_id)
    return q.order_by(runs.c.started, measurements.c.id)


def select_artifacts(run_id: int) -> Select:
    return select(artifacts).where(artifacts.c.run_id == run_id).order_by(artifacts.c.id)


def select_tolerance_at(metric: str, at: float) -> Select:
    """The window of one metric in effect at ``at``: the latest effective_from <= at
    (the later-recorded row wins a tie)."""
    return (
        select(tolerances)
        .where(tolerances.c.metric == metric, tolerances.c.effective_from <= at)
        .order_by(tolerances.c.effective_from.desc(), tolerances.c.id.desc())
        .limit(1)
    )


def select_tolerances_at(at: float) -> Select:
    """The window in effect at ``at`` for every metric (a window function: SQLite >= 3.25, PostgreSQL)."""
    rank = (
        func.row_number()
        .over(partition_by=tolerances.c.metric, order_by=(tolerances.c.effective_from.desc(), tolerances.c.id.desc()))
        .label("rank")
    )
    inner = select(tolerances, rank).where(tolerances.c.effective_from <= at).subquery()
    return select(*[inner.c[c.name] for c in tolerances.c]).where(inner.c.rank == 1).order_by(inner.c.metric)


def select_running_runs(host: str) -> Select:
    return (
        select(runs.c.id, runs.c.pid, runs.c.process_start)
        .where(and_(runs.c.status == "running", runs.c.host == host))
        .order_by(runs.c.id)
    )
