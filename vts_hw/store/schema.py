"""The results schema, in portable SQLAlchemy Core (SQLite today, PostgreSQL later).

Portable types only: Integer keys, Double for values and UTC epoch times (SQLite REAL,
PostgreSQL DOUBLE PRECISION), Text for free text, short VARCHARs only where a CHECK bounds
them. Constraints are named (naming convention) so that a later migration can address them
on PostgreSQL.

Tables:
  schema_migrations  one row per schema version applied (current version = the highest)
  runs               one row per QA run, written "running" at begin and completed at finish
  measurements       the run's values with the status judged at the time and the window used
  tolerances         append-only history of windows per metric, each with effective_from
  artifacts          saved files (frames) of a run, by path and sha256
  outbox             results waiting to be (or already) pushed to another system (QATrack+)
  users              the room console's users: name, role, salted password hash (version 4)
  actions            what people did on the console: who, role, when, what, detail (version 4)

Every run has a ``uid`` (32 hex digits, unique in every store): a run copied into another
store (``vts store migrate``) keeps it, so a copy made twice, or a push to QATrack+ from
either store, is recognised as the same run.

Rows are never updated except a run's status/finished/notes when it ends (and an outbox row's
state as its push progresses, and a console user's password, role or disabled time), and
never deleted (a user who leaves is disabled, so the actions' names stay theirs):
a change of tolerance is a new row, so old statuses and the windows behind them stay as
they were.
"""

from __future__ import annotations

from sqlalchemy import (
    CheckConstraint,
    Column,
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
)

from vts_hw.store.records import MEASUREMENT_STATUSES, OUTBOX_STATES, ROLES, RUN_STATUSES

#: the version a fresh database is created at; migrations.py upgrades older ones to it
SCHEMA_VERSION = 4

NAMING = {
    "ix": "ix_%(table_name)s_%(column_0_N_name)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

metadata = MetaData(naming_convention=NAMING)

schema_migrations = Table(
    "schema_migrations",
    metadata,
    Column("version", Integer, primary_key=True, autoincrement=False),
    Column("applied", Double, nullable=False),
    Column("description", Text, nullable=False, server_default=""),
)

runs = Table(
    "runs",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("procedure", Text, nullable=False),
    Column("rig", Text, nullable=False, server_default=""),
    Column("started", Double, nullable=False),
    Column("finished", Double),
    Column("status", String(16), nullable=False),
    Column("software_version", Text, nullable=False, server_default=""),
    Column("config_digest", Text, nullable=False, server_default=""),
    Column("operator", Text, nullable=False, server_default=""),
    Column("notes", Text, nullable=False, server_default=""),
    # version 2: who wrote the "running" row, so that a later open can tell it died
    Column("host", Text, nullable=False, server_default=""),
    Column("pid", Integer),
    Column("process_start", Text, nullable=False, server_default=""),
    # version 3: the run's identity across stores (uuid4 hex)
    Column("uid", String(32), nullable=False, server_default=""),
    CheckConstraint(Column("status").in_(RUN_STATUSES), name="status"),
)
Index(None, runs.c.procedure, runs.c.started)
Index(None, runs.c.status)  # version 2
Index("uq_runs_uid", runs.c.uid, unique=True)  # version 3
Index(None, runs.c.rig, runs.c.procedure, runs.c.started)  # version 3

tolerances = Table(
    "tolerances",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("metric", Text, nullable=False),
    Column("action_low", Double),
    Column("tolerance_low", Double),
    Column("tolerance_high", Double),
    Column("action_high", Double),
    Column("unit", Text, nullable=False, server_default=""),
    Column("effective_from", Double, nullable=False),
    Column("recorded", Double, nullable=False),  # when the row was written (audit)
    Column("note", Text, nullable=False, server_default=""),
)
Index(None, tolerances.c.metric, tolerances.c.effective_from)

measurements = Table(
    "measurements",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("run_id", Integer, ForeignKey(runs.c.id), nullable=False),
    Column("subject", Text, nullable=False, server_default=""),
    Column("metric", Text, nullable=False),
    Column("value", Double),
    Column("unit", Text, nullable=False, server_default=""),
    Column("status", String(16), nullable=False),
    Column("tolerance_id", Integer, ForeignKey(tolerances.c.id)),
    CheckConstraint(Column("status").in_(MEASUREMENT_STATUSES), name="status"),
)
Index(None, measurements.c.run_id)
Index(None, measurements.c.metric)

artifacts = Table(
    "artifacts",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("run_id", Integer, ForeignKey(runs.c.id), nullable=False),
    Column("path", Text, nullable=False),
    Column("sha256", String(64), nullable=False),
    # version 2: what the file is
    Column("kind", Text, nullable=False, server_default="frame"),
    CheckConstraint(func.length(Column("sha256")) == 64, name="sha256"),
)
Index(None, artifacts.c.run_id)

# version 3: one row per (run, target) to push; its state changes as the push progresses
outbox = Table(
    "outbox",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("run_id", Integer, ForeignKey(runs.c.id), nullable=False),
    Column("target", Text, nullable=False),  # e.g. "qatrack"
    Column("key", Text, nullable=False),  # idempotency key sent with the push
    Column("state", String(16), nullable=False),
    Column("attempts", Integer, nullable=False, server_default="0"),
    Column("last_error", Text, nullable=False, server_default=""),
    Column("created", Double, nullable=False),
    Column("updated", Double, nullable=False),
    Column("remote", Text, nullable=False, server_default=""),  # what the push created there (URL)
    CheckConstraint(Column("state").in_(OUTBOX_STATES), name="state"),
    UniqueConstraint("target", "run_id", name="uq_outbox_target_run_id"),
)
Index(None, outbox.c.state)

# version 4: the room console's users (docs/decisions/0063-console-users.md). ``password`` is
# "scrypt$N$r$p$salt$hash" (base64), never the password; ``disabled`` the time a user was
# disabled (None: may log in)
users = Table(
    "users",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("name", Text, nullable=False),
    Column("role", String(16), nullable=False),
    Column("password", Text, nullable=False),
    Column("created", Double, nullable=False),
    Column("changed", Double, nullable=False),
    Column("disabled", Double),
    CheckConstraint(Column("role").in_(ROLES), name="role"),
    UniqueConstraint("name", name="uq_users_name"),
)

# version 4: the console's action log, append-only (who did what, with the role they had)
actions = Table(
    "actions",
    metadata,
    Column("id", Integer, primary_key=True),
    Column("at", Double, nullable=False),
    Column("user_name", Text, nullable=False),
    Column("role", Text, nullable=False, server_default=""),
    Column("what", Text, nullable=False),
    Column("detail", Text, nullable=False, server_default="{}"),  # JSON; never a secret
    Column("rig", Text, nullable=False, server_default=""),
)
Index(None, actions.c.at)

#: the tables of a vts-hw results store (a database holding some of them but no
#: schema_migrations is not one we created, and is not touched)
TABLES = (schema_migrations, runs, tolerances, measurements, artifacts, outbox, users, actions)
