"""Schema versioning: create a fresh store, or upgrade an older one in place, on open.

The version lives in the database (``schema_migrations``: one row per version applied, the
current version is the highest). On open, in one write transaction:

* no tables at all -> create the current schema and record SCHEMA_VERSION (whether an empty
  database may become a store is decided before, by identity.py and the caller's mode);
* an older version -> apply each step after it in order, recording each;
* a newer version -> refuse (this vts-hw does not know that layout; upgrade vts-hw);
* anything that is not a vts-hw store (other tables, ours without the version table) -> refuse
  (not a store we created; touch nothing).

A step is a function of the dialect returning DDL (and, where a new column needs a value in
the rows already there, a function of the connection that fills it), so the same step runs on SQLite and
PostgreSQL (and tests compile it for PostgreSQL without a server). Steps describe the schema
*as it was at that version*, never the current ``schema.py`` tables, so a later change to
``schema.py`` cannot change what an old step does. Steps only add (columns with defaults,
tables, indexes, and the first value of a column they add); they never rewrite stored values. DDL is transactional on both databases, so a
kill during an upgrade leaves the old version intact.

Version history:
  1  runs, measurements, tolerances, artifacts (path, sha256), schema_migrations
  2  runs.host, runs.pid, runs.process_start (dead-run detection); artifacts.kind;
     index on runs.status
  3  runs.uid (unique; the rows already there get a fresh uuid4 each), index on runs (rig,
     procedure, started); the outbox table (pushes to QATrack+)
"""

from __future__ import annotations

import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass

from sqlalchemy import (
    CheckConstraint,
    Column,
    Connection,
    Double,
    ForeignKey,
    Index,
    Integer,
    MetaData,
    String,
    Table,
    Text,
    UniqueConstraint,
    func,
    insert,
    inspect,
    select,
    update,
)
from sqlalchemy.engine import Dialect
from sqlalchemy.schema import CreateColumn, CreateIndex, CreateTable, DDLElement

from vts_hw.store import schema
from vts_hw.store.errors import StoreError
from vts_hw.store.identity import EMPTY, FOREIGN, connection_kind


@dataclass(frozen=True)
class Migration:
    version: int
    description: str
    statements: Callable[[Dialect], list]  # DDL strings, DDLElements or fill(conn) functions, in order


def add_column(dialect: Dialect, table: str, column: Column) -> str:
    """``ALTER TABLE t ADD COLUMN ...`` rendered for a dialect (the syntax SQLite and PostgreSQL share).

    A NOT NULL column needs a server default (SQLite requires it, and old rows need a value)."""
    if not column.nullable and column.server_default is None:
        raise ValueError(f"migration adds NOT NULL column {table}.{column.name} without a default")
    prep = dialect.identifier_preparer
    return f"ALTER TABLE {prep.quote(table)} ADD COLUMN {CreateColumn(column).compile(dialect=dialect)}"


def _v2(dialect: Dialect) -> list:
    runs_v2 = Table("runs", MetaData(), Column("status", String(16)))
    return [
        add_column(dialect, "runs", Column("host", Text, nullable=False, server_default="")),
        add_column(dialect, "runs", Column("pid", Integer)),
        add_column(dialect, "runs", Column("process_start", Text, nullable=False, server_default="")),
        add_column(dialect, "artifacts", Column("kind", Text, nullable=False, server_default="frame")),
        CreateIndex(Index("ix_runs_status", runs_v2.c.status)),
    ]


def _v3(dialect: Dialect) -> list:
    md = MetaData(naming_convention=schema.NAMING)
    runs_v3 = Table(
        "runs",
        md,
        Column("id", Integer, primary_key=True),
        Column("uid", String(32)),
        Column("rig", Text),
        Column("procedure", Text),
        Column("started", Double),
    )
    outbox_v3 = Table(
        "outbox",
        md,
        Column("id", Integer, primary_key=True),
        Column("run_id", Integer, ForeignKey(runs_v3.c.id), nullable=False),
        Column("target", Text, nullable=False),
        Column("key", Text, nullable=False),
        Column("state", String(16), nullable=False),
        Column("attempts", Integer, nullable=False, server_default="0"),
        Column("last_error", Text, nullable=False, server_default=""),
        Column("created", Double, nullable=False),
        Column("updated", Double, nullable=False),
        Column("remote", Text, nullable=False, server_default=""),
        CheckConstraint(Column("state").in_(("pending", "sent", "refused")), name="state"),
        UniqueConstraint("target", "run_id", name="uq_outbox_target_run_id"),
    )

    def fill_uids(conn: Connection) -> None:
        ids = conn.scalars(select(runs_v3.c.id).where(runs_v3.c.uid == "")).all()
        for run_id in ids:
            conn.execute(update(runs_v3).where(runs_v3.c.id == run_id).values(uid=uuid.uuid4().hex))

    return [
        add_column(dialect, "runs", Column("uid", String(32), nullable=False, server_default="")),
        fill_uids,
        CreateIndex(Index("uq_runs_uid", runs_v3.c.uid, unique=True)),
        CreateIndex(Index("ix_runs_rig_procedure_started", runs_v3.c.rig, runs_v3.c.procedure, runs_v3.c.started)),
        CreateTable(outbox_v3),
        CreateIndex(Index("ix_outbox_state", outbox_v3.c.state)),
    ]


def _v4(dialect: Dialect) -> list:
    md = MetaData(naming_convention=schema.NAMING)
    users_v4 = Table(
        "users",
        md,
        Column("id", Integer, primary_key=True),
        Column("name", Text, nullable=False),
        Column("role", String(16), nullable=False),
        Column("password", Text, nullable=False),
        Column("created", Double, nullable=False),
        Column("changed", Double, nullable=False),
        Column("disabled", Double),
        CheckConstraint(Column("role").in_(("operator", "physicist")), name="role"),
        UniqueConstraint("name", name="uq_users_name"),
    )
    actions_v4 = Table(
        "actions",
        md,
        Column("id", Integer, primary_key=True),
        Column("at", Double, nullable=False),
        Column("user_name", Text, nullable=False),
        Column("role", Text, nullable=False, server_default=""),
        Column("what", Text, nullable=False),
        Column("detail", Text, nullable=False, server_default="{}"),
        Column("rig", Text, nullable=False, server_default=""),
    )
    return [CreateTable(users_v4), CreateTable(actions_v4), CreateIndex(Index("ix_actions_at", actions_v4.c.at))]


#: version -> the step that upgrades version-1 to it (version 1 is the first layout)
MIGRATIONS: dict[int, Migration] = {
    2: Migration(2, "runs: host, pid, process_start for dead-run detection; artifacts: kind", _v2),
    3: Migration(3, "runs: uid (identity across stores), index on rig; outbox (pushes to QATrack+)", _v3),
    4: Migration(4, "users (the console's, salted password hashes) and actions (who did what)", _v4),
}

assert sorted(MIGRATIONS) == list(range(2, schema.SCHEMA_VERSION + 1)), "a migration step is missing"


def stored_version(conn: Connection) -> int | None:
    """The schema version recorded in the database, None when there is no version table."""
    if not inspect(conn).has_table(schema.schema_migrations.name):
        return None
    return conn.scalar(select(func.max(schema.schema_migrations.c.version)))


def _record(conn: Connection, version: int, description: str) -> None:
    conn.execute(insert(schema.schema_migrations).values(version=version, applied=time.time(), description=description))


def ensure_schema(conn: Connection, where: str) -> tuple[int, int]:
    """Create or upgrade the schema inside the caller's write transaction.

    Returns (version found, version now); found is 0 for a fresh database. ``where`` (the
    masked URL) names the database in errors."""
    kind = connection_kind(conn)  # again, under the write lock
    if kind.kind == FOREIGN:
        raise StoreError(f"{where} is not a vts-hw results store ({kind.detail}), so it was left untouched")
    if kind.kind == EMPTY:
        schema.metadata.create_all(conn)
        _record(conn, schema.SCHEMA_VERSION, f"created at version {schema.SCHEMA_VERSION}")
        return 0, schema.SCHEMA_VERSION
    found = stored_version(conn)
    if found is None or found < 1:
        raise StoreError(f"{where}: its schema_migrations table is empty; cannot tell its schema version")
    if found > schema.SCHEMA_VERSION:
        raise StoreError(
            f"{where}: schema version {found} is newer than this vts-hw understands "
            f"({schema.SCHEMA_VERSION}); upgrade vts-hw to use it"
        )
    for version in range(found + 1, schema.SCHEMA_VERSION + 1):
        step = MIGRATIONS[version]
        for stmt in step.statements(conn.dialect):
            if isinstance(stmt, str):
                conn.exec_driver_sql(stmt)
            elif callable(stmt) and not isinstance(stmt, DDLElement):
                stmt(conn)
            else:
                assert isinstance(stmt, DDLElement)
                conn.execute(stmt)
        _record(conn, version, step.description)
    return found, schema.SCHEMA_VERSION
