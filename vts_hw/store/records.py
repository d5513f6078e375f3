"""What the store hands back: plain frozen records, no database objects.

``Run.status`` is a plain string (one of ``RUN_STATUSES``); ``Measurement.status`` is a
``State`` (a measurement is always OK, TOLERANCE or ACTION). Times are UTC epoch seconds.
"""

from __future__ import annotations

from dataclasses import dataclass

from vts_hw.tolerance import State

#: every status a run can have; "running" until finish() or abort() (or dead-run detection)
RUN_STATUSES = ("running", "OK", "TOLERANCE", "ACTION", "aborted", "error")
#: the statuses finish() accepts
FINISH_STATUSES = ("OK", "TOLERANCE", "ACTION", "error")
#: the states of an outbox row: waiting (new, or failed and to be retried), done, or refused
#: by the other system (kept for the user to fix, retried only when asked)
OUTBOX_STATES = ("pending", "sent", "refused")
#: the roles of the console's users, lowest first (vts_hw/console/guard.py orders them)
ROLES = ("operator", "physicist")
#: the statuses a measurement can have
MEASUREMENT_STATUSES = tuple(s.value for s in State)


@dataclass(frozen=True)
class Run:
    id: int
    procedure: str
    rig: str
    started: float
    finished: float | None
    status: str
    software_version: str
    config_digest: str
    operator: str
    notes: str
    uid: str = ""  # the run's identity across stores (32 hex digits)


@dataclass(frozen=True)
class Measurement:
    id: int
    run_id: int
    started: float  # the run's start, for trending without a second query
    subject: str
    metric: str
    value: float | None  # None: not measured (NaN is stored as None too)
    unit: str
    status: State
    tolerance_id: int | None  # the window the status was judged with (None: given, or no window)


@dataclass(frozen=True)
class Artifact:
    id: int
    run_id: int
    path: str
    sha256: str
    kind: str


@dataclass(frozen=True)
class OutboxItem:
    """A run to push to ``target``: its state, tries, the last error, and what it created there."""

    id: int
    run_id: int
    target: str
    key: str
    state: str  # one of OUTBOX_STATES
    attempts: int
    last_error: str
    created: float
    updated: float
    remote: str


def run_from_row(row) -> Run:
    """A Run from a ``runs`` row (any mapping-like row with those columns)."""
    return Run(
        id=row.id,
        procedure=row.procedure,
        rig=row.rig,
        started=row.started,
        finished=row.finished,
        status=row.status,
        software_version=row.software_version,
        config_digest=row.config_digest,
        operator=row.operator,
        notes=row.notes,
        uid=row.uid,
    )


def measurement_from_row(row) -> Measurement:
    return Measurement(
        id=row.id,
        run_id=row.run_id,
        started=row.started,
        subject=row.subject,
        metric=row.metric,
        value=row.value,
        unit=row.unit,
        status=State(row.status),
        tolerance_id=row.tolerance_id,
    )


def artifact_from_row(row) -> Artifact:
    return Artifact(id=row.id, run_id=row.run_id, path=row.path, sha256=row.sha256, kind=row.kind)


def outbox_from_row(row) -> OutboxItem:
    return OutboxItem(
        id=row.id,
        run_id=row.run_id,
        target=row.target,
        key=row.key,
        state=row.state,
        attempts=row.attempts,
        last_error=row.last_error,
        created=row.created,
        updated=row.updated,
        remote=row.remote,
    )


@dataclass(frozen=True)
class User:
    """A console user as stored: ``password`` is the salted hash, never the password."""

    id: int
    name: str
    role: str
    password: str
    created: float
    changed: float
    disabled: float | None  # when disabled; None: may log in

    @property
    def active(self) -> bool:
        return self.disabled is None


@dataclass(frozen=True)
class LoggedAction:
    """One row of the console's action log."""

    id: int
    at: float
    user: str
    role: str
    what: str
    detail: dict
    rig: str
