"""The results store's schema: its version and upgrades (v1 -> now, v3 -> v4 with the console's
users and actions), stores made at once by several processes, a newer or foreign database
refused and left alone, the SQLite settings, foreign keys; and its portability: the schema and
queries compiled for PostgreSQL without a server, a password in the URL never shown.

Tests taking ``store``/``store_url`` run on both back ends (tests/store_kit.py, conftest.store_url)."""

import logging
import subprocess
import sys
from pathlib import Path

import pytest
from sqlalchemy.dialects import postgresql
from sqlalchemy.schema import CreateIndex, CreateTable

from store_kit import _check_file, _raw, _sql
from vts_hw.store import SCHEMA_VERSION, ResultsStore, StoreError, migrations, queries, schema
from vts_hw.tolerance import State, Window

DRIFT = Window.symmetric(1.0, 2.0, "px")  # the v1 window of the V1 store below
T0 = 1_700_000_000.0  # a fixed epoch for reproducible histories


# -- schema version and upgrades --------------------------------------------------------------

V1 = """
CREATE TABLE schema_migrations (version INTEGER NOT NULL PRIMARY KEY, applied DOUBLE NOT NULL,
    description TEXT DEFAULT '' NOT NULL);
CREATE TABLE runs (id INTEGER NOT NULL PRIMARY KEY, procedure TEXT NOT NULL, rig TEXT DEFAULT '' NOT NULL,
    started DOUBLE NOT NULL, finished DOUBLE, status VARCHAR(16) NOT NULL,
    software_version TEXT DEFAULT '' NOT NULL, config_digest TEXT DEFAULT '' NOT NULL,
    operator TEXT DEFAULT '' NOT NULL, notes TEXT DEFAULT '' NOT NULL,
    CONSTRAINT ck_runs_status CHECK (status IN ('running', 'OK', 'TOLERANCE', 'ACTION', 'aborted', 'error')));
CREATE INDEX ix_runs_procedure_started ON runs (procedure, started);
CREATE TABLE tolerances (id INTEGER NOT NULL PRIMARY KEY, metric TEXT NOT NULL, action_low DOUBLE,
    tolerance_low DOUBLE, tolerance_high DOUBLE, action_high DOUBLE, unit TEXT DEFAULT '' NOT NULL,
    effective_from DOUBLE NOT NULL, recorded DOUBLE NOT NULL, note TEXT DEFAULT '' NOT NULL);
CREATE INDEX ix_tolerances_metric_effective_from ON tolerances (metric, effective_from);
CREATE TABLE measurements (id INTEGER NOT NULL PRIMARY KEY, run_id INTEGER NOT NULL REFERENCES runs (id),
    subject TEXT DEFAULT '' NOT NULL, metric TEXT NOT NULL, value DOUBLE, unit TEXT DEFAULT '' NOT NULL,
    status VARCHAR(16) NOT NULL, tolerance_id INTEGER REFERENCES tolerances (id),
    CONSTRAINT ck_measurements_status CHECK (status IN ('OK', 'TOLERANCE', 'ACTION')));
CREATE INDEX ix_measurements_run_id ON measurements (run_id);
CREATE INDEX ix_measurements_metric ON measurements (metric);
CREATE TABLE artifacts (id INTEGER NOT NULL PRIMARY KEY, run_id INTEGER NOT NULL REFERENCES runs (id),
    path TEXT NOT NULL, sha256 VARCHAR(64) NOT NULL, CONSTRAINT ck_artifacts_sha256 CHECK (length(sha256) = 64));
CREATE INDEX ix_artifacts_run_id ON artifacts (run_id);
INSERT INTO schema_migrations VALUES (1, 1600000000, 'created at version 1');
INSERT INTO tolerances VALUES (1, 'drift_x_px', -2, -1, 1, 2, 'px', 1600000000, 1600000000, 'v1 window');
INSERT INTO runs VALUES (1, 'drift', 'room3', 1600000100, 1600000160, 'TOLERANCE', '0.0.1', 'abc', 'ak', 'v1 run');
INSERT INTO runs VALUES (2, 'drift', 'room3', 1600000200, NULL, 'running', '0.0.1', 'abc', 'ak', '');
INSERT INTO measurements VALUES (1, 1, 'cam1', 'drift_x_px', 1.5, 'px', 'TOLERANCE', 1);
INSERT INTO measurements VALUES (2, 1, 'cam2', 'drift_x_px', 0.2, 'px', 'OK', 1);
INSERT INTO artifacts VALUES (1, 1, '/data/cam1.jpg', '%s');
""" % ("ab" * 32)


def _dump(db: Path) -> dict:
    con = _raw(db)
    try:
        return {
            t: con.execute(f"SELECT * FROM {t} ORDER BY 1").fetchall()
            for t in ("runs", "tolerances", "measurements", "artifacts")
        }
    finally:
        con.close()


def _layout(db: Path) -> dict:
    con = _raw(db)
    try:
        tables = [r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table' ORDER BY name")]
        return {
            t: (
                [r[1:6] for r in con.execute(f"PRAGMA table_info({t})")],
                sorted(r[1] for r in con.execute(f"PRAGMA index_list({t})")),
            )
            for t in tables
        }
    finally:
        con.close()


def test_a_version_1_database_is_upgraded_on_open_without_losing_rows(tmp_path, db):
    db.parent.mkdir(parents=True)
    con = _raw(db)
    con.executescript(V1)
    con.close()
    before = _dump(db)

    with ResultsStore(str(db)) as store:
        assert store.schema_version == SCHEMA_VERSION == 4
        after = _dump(db)
        # every old row is there with its old values; only the new columns were appended
        for table, rows in before.items():
            assert [row[: len(rows[0])] for row in after[table]] == rows, table
        assert store.artifacts(1)[0].kind == "frame"
        assert [m.status for m in store.measurements()] == [State.TOLERANCE, State.OK]
        assert store.tolerance("drift_x_px", at=1600000100) == (1, DRIFT)
        assert store.run(2).status == "running"  # written before runs had a pid: cannot be judged
        with store.begin_run("drift") as run:  # and the upgraded store takes new runs
            run.measure("cam1", "drift_x_px", 2.5)
        assert store.run(run.run_id).status == "ACTION"
        # every run has a uid of its own, the old ones given one by the upgrade
        uids = [r.uid for r in store.runs()]
        assert len(set(uids)) == len(uids) == 3 and all(len(u) == 32 for u in uids)
    con = _raw(db)
    assert [r[0] for r in con.execute("SELECT version FROM schema_migrations ORDER BY version")] == [1, 2, 3, 4]
    con.close()
    _check_file(db)
    # an upgraded store has exactly the layout of a fresh one
    fresh = tmp_path / "fresh.sqlite"
    ResultsStore(str(fresh)).close()
    assert _layout(db) == _layout(fresh)
    # and opening again changes nothing
    ResultsStore(str(db)).close()
    assert _dump(db)["runs"][:2] == after["runs"][:2]


def test_a_version_3_store_gets_users_and_actions_keeping_its_runs(tmp_path):
    """v3 -> v4: the console's users and action log are added; every run, measurement and
    outbox row stays as it was, and the upgraded store has a fresh store's layout."""
    db = tmp_path / "v3.sqlite"
    with ResultsStore(str(db)) as store:
        with store.begin_run("drift", rig="room3", operator="ak") as run:
            run.measure("cam1", "drift_x_px", 0.4, status="OK")
        store.outbox_add(run.run_id, "qatrack", "k1")
    con = _raw(db)  # back to version 3 as it was: version 4 only added these
    con.executescript("DROP TABLE actions; DROP TABLE users; UPDATE schema_migrations SET version = 3;")
    con.close()
    before = _dump(db)
    assert "users" not in _layout(db)
    with ResultsStore(str(db)) as store:
        assert store.schema_version == 4
        assert _dump(db) == before
        assert store.outbox_items("qatrack")[0].key == "k1"
        assert store.users() == [] and store.actions() == ([], 0)
        store.put_user("ann", "operator", "scrypt$hash-made-by-the-console")
        store.log_actions(
            [
                {
                    "at": 1.0,
                    "user": "ann",
                    "role": "operator",
                    "what": "LED on",
                    "detail": {"camera": "cam1"},
                    "rig": "room3",
                }
            ]
        )
        acts, n = store.actions()
        assert n == 1 and (acts[0].user, acts[0].what, acts[0].detail) == ("ann", "LED on", {"camera": "cam1"})
        with pytest.raises(ValueError, match="already exists"):
            store.put_user("ann", "physicist", "x")
        assert store.disable_user("ann").active is False
        assert store.put_user("ann", "physicist", "y")[1] == "enabled again"
    con = _raw(db)
    assert con.execute("SELECT description FROM schema_migrations WHERE version = 4").fetchone()[0].startswith("users")
    con.close()
    fresh = tmp_path / "fresh.sqlite"
    ResultsStore(str(fresh)).close()
    assert _layout(db) == _layout(fresh)


def test_processes_opening_a_new_store_at_once_create_it_once(store_url):
    code = "import sys; from vts_hw.store import ResultsStore; ResultsStore(sys.argv[1]).close()"
    procs = [
        subprocess.Popen([sys.executable, "-c", code, store_url], stderr=subprocess.PIPE, text=True) for _ in range(6)
    ]
    for p in procs:
        assert p.wait(timeout=60) == 0, p.stderr.read()
    assert _sql(store_url, "SELECT version FROM schema_migrations") == [(SCHEMA_VERSION,)]
    _check_file(store_url)


def test_a_newer_or_foreign_database_is_refused_and_left_alone(tmp_path):
    newer = tmp_path / "newer.sqlite"
    ResultsStore(str(newer)).close()
    con = _raw(newer)
    con.execute("INSERT INTO schema_migrations VALUES (?, 0, 'from the future')", (SCHEMA_VERSION + 1,))
    con.close()
    with pytest.raises(StoreError, match=f"schema version {SCHEMA_VERSION + 1} is newer"):
        ResultsStore(str(newer))

    foreign = tmp_path / "foreign.sqlite"
    con = _raw(foreign)
    con.execute("CREATE TABLE runs (x INTEGER)")
    con.close()
    with pytest.raises(StoreError, match="not a vts-hw results store"):
        ResultsStore(str(foreign))
    assert _layout(foreign) == {"runs": ([("x", "INTEGER", 0, None, 0)], [])}


def test_a_fresh_store_records_its_version_and_sqlite_settings(sqlite_store, db):
    store = sqlite_store
    assert store.schema_version == SCHEMA_VERSION
    con = _raw(db)
    assert con.execute("PRAGMA journal_mode").fetchone() == ("wal",)  # stored in the file
    con.close()
    with store._read() as conn:  # per-connection settings of the store's own connections
        assert conn.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
        assert conn.exec_driver_sql("PRAGMA busy_timeout").scalar() == 30000
        assert conn.exec_driver_sql("PRAGMA synchronous").scalar() == 2  # FULL


def test_foreign_keys_are_enforced(store):
    run = store.begin_run("drift")
    run.measure("cam1", "m", 1.0, status="OK")
    run._measurements[0]["tolerance_id"] = 12345  # no such window
    with pytest.raises(Exception, match="(?i)foreign key"):
        run.finish()
    assert store.measurements() == []


# -- portability: PostgreSQL, compiled without a server -------------------------------------------


def test_the_schema_and_queries_compile_for_postgresql():
    pg = postgresql.dialect()
    ddl = []
    for table in schema.metadata.sorted_tables:
        ddl.append(str(CreateTable(table).compile(dialect=pg)))
        ddl.extend(str(CreateIndex(ix).compile(dialect=pg)) for ix in table.indexes)
    text = "\n".join(ddl)
    for expected in (
        "CREATE TABLE runs",
        "id SERIAL NOT NULL",
        "started DOUBLE PRECISION NOT NULL",
        "CONSTRAINT ck_runs_status CHECK (status IN ('running', 'OK'",
        "FOREIGN KEY(run_id) REFERENCES runs (id)",
        "CHECK (length(sha256) = 64)",
        "CREATE INDEX ix_runs_procedure_started ON runs (procedure, started)",
    ):
        assert expected in text
    for sqlite_only in ("AUTOINCREMENT", "PRAGMA", "DOUBLE,", "IMMEDIATE", "WITHOUT ROWID"):
        assert sqlite_only not in text

    q = queries.select_measurements(
        procedure=("drift", "steps"), metric="drift_x_px", subject="cam1", since=T0, run_id=3
    )
    sql = str(q.compile(dialect=pg))
    assert "JOIN runs ON measurements.run_id = runs.id" in sql
    assert "runs.procedure IN (__[POSTCOMPILE_procedure_1])" in sql
    assert "ORDER BY runs.started, measurements.id" in sql
    sql = str(q.compile(dialect=pg, compile_kwargs={"literal_binds": True}))
    assert "runs.procedure IN ('drift', 'steps')" in sql and "measurements.metric = 'drift_x_px'" in sql
    sql = str(queries.select_tolerances_at(T0).compile(dialect=pg))
    assert "row_number() OVER (PARTITION BY tolerances.metric ORDER BY tolerances.effective_from DESC" in sql
    sql = str(queries.select_tolerance_at("m", T0).compile(dialect=pg))
    assert "LIMIT %(param_1)s" in sql
    for q in (
        queries.select_runs(("a", "b"), T0, "OK"),
        queries.select_artifacts(1),
        queries.select_running_runs("host"),
    ):
        assert str(q.compile(dialect=pg))

    # every migration step renders for PostgreSQL too
    for step in migrations.MIGRATIONS.values():
        for stmt in step.statements(pg):
            if callable(stmt) and not hasattr(stmt, "compile"):
                continue  # a fill of a new column: runs on a real server (tests/interop/test_store_postgres.py)
            rendered = stmt if isinstance(stmt, str) else str(stmt.compile(dialect=pg))
            assert rendered.strip().startswith(("ALTER TABLE", "CREATE")), rendered
    assert "ALTER TABLE runs ADD COLUMN host TEXT DEFAULT '' NOT NULL" in migrations.MIGRATIONS[2].statements(pg)
    v4 = "\n".join(str(st.compile(dialect=pg)) for st in migrations.MIGRATIONS[4].statements(pg))
    for expected in (
        "CREATE TABLE users",
        "id SERIAL NOT NULL",
        "CONSTRAINT uq_users_name UNIQUE (name)",
        "CONSTRAINT ck_users_role CHECK (role IN ('operator', 'physicist'))",
        "CREATE TABLE actions",
        "at DOUBLE PRECISION NOT NULL",
        "detail TEXT DEFAULT '{}' NOT NULL",
        "CREATE INDEX ix_actions_at ON actions (at)",
    ):
        assert expected in v4, v4
    # the step makes what schema.py makes for a fresh store
    assert str(CreateTable(schema.users).compile(dialect=pg)).strip() in v4
    assert str(CreateTable(schema.actions).compile(dialect=pg)).strip() in v4
    from vts_hw.store import people

    sql = str(people.select_actions(start=T0, end=T0 + 1, user="ann", limit=5, offset=5).compile(dialect=pg))
    assert "ORDER BY actions.at DESC, actions.id DESC" in sql and "actions.user_name = %(user_name_1)s" in sql
    assert str(people.count_actions(T0, None, "ann").compile(dialect=pg))


def test_a_password_in_the_url_never_shows(caplog):
    caplog.set_level(logging.DEBUG)
    with pytest.raises(StoreError) as info:
        ResultsStore("postgresql://vts:s3cret-pw@127.0.0.1:1/results", busy_timeout=1)
    assert "s3cret-pw" not in str(info.value) and "vts:***@127.0.0.1" in str(info.value)
    assert "s3cret-pw" not in caplog.text
    with pytest.raises(StoreError) as info:
        ResultsStore("notadialect://vts:s3cret-pw@host/db")
    assert "s3cret-pw" not in str(info.value)
