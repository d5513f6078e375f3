"""The store on a real PostgreSQL server (the session's throwaway one, tests/pgserver.py):
the version-1 upgrade, foreign and newer databases, readers beside an open write, the
password from an environment variable, and which store a command uses (--store, $VTS_STORE,
rig.yaml's store: or its old name results:)."""

from __future__ import annotations

import json
import logging
import os

import pytest
from sqlalchemy import create_engine, inspect, text

from inprocess_cli import run
from pgserver import PASSWORD_ENV
from test_store import DRIFT
from test_store_schema import V1
from vts_hw.config import parse_rig
from vts_hw.errors import ConfigError, UsageError
from vts_hw.store import SCHEMA_VERSION, ResultsStore, StoreError
from vts_hw.store.paths import to_url
from vts_hw.store.target import ENV_STORE, ENV_STORE_PASSWORD_ENV, resolve_target
from vts_hw.tolerance import State

# version 1 as vts-hw created it on PostgreSQL (SERIAL keys, named constraints), with the rows
# of the SQLite version-1 test; the sequences continue after the ids given explicitly
V1_PG = (
    V1.replace("id INTEGER NOT NULL PRIMARY KEY", "id SERIAL NOT NULL")
    .replace("version INTEGER NOT NULL PRIMARY KEY", "version INTEGER NOT NULL")
    .replace("DOUBLE", "DOUBLE PRECISION")
    .replace("run_id INTEGER NOT NULL REFERENCES runs (id)", "run_id INTEGER NOT NULL")
    .replace("tolerance_id INTEGER REFERENCES tolerances (id)", "tolerance_id INTEGER")
    + """
ALTER TABLE schema_migrations ADD CONSTRAINT pk_schema_migrations PRIMARY KEY (version);
ALTER TABLE runs ADD CONSTRAINT pk_runs PRIMARY KEY (id);
ALTER TABLE tolerances ADD CONSTRAINT pk_tolerances PRIMARY KEY (id);
ALTER TABLE measurements ADD CONSTRAINT pk_measurements PRIMARY KEY (id);
ALTER TABLE artifacts ADD CONSTRAINT pk_artifacts PRIMARY KEY (id);
ALTER TABLE measurements ADD CONSTRAINT fk_measurements_run_id_runs FOREIGN KEY (run_id) REFERENCES runs (id);
ALTER TABLE measurements ADD CONSTRAINT fk_measurements_tolerance_id_tolerances
    FOREIGN KEY (tolerance_id) REFERENCES tolerances (id);
ALTER TABLE artifacts ADD CONSTRAINT fk_artifacts_run_id_runs FOREIGN KEY (run_id) REFERENCES runs (id);
SELECT setval('runs_id_seq', 2); SELECT setval('tolerances_id_seq', 1);
SELECT setval('measurements_id_seq', 2); SELECT setval('artifacts_id_seq', 1);
"""
)


def _exec(url: str, script: str) -> None:
    engine = create_engine(to_url(url))
    try:
        with engine.begin() as conn:
            conn.exec_driver_sql(script)
    finally:
        engine.dispose()


def _rows(url: str, sql: str) -> list:
    engine = create_engine(to_url(url))
    try:
        with engine.connect() as conn:
            return conn.execute(text(sql)).all()
    finally:
        engine.dispose()


def _dump(url: str) -> dict:
    return {t: _rows(url, f"SELECT * FROM {t} ORDER BY 1") for t in ("runs", "tolerances", "measurements", "artifacts")}


def _layout(url: str) -> dict:
    """Tables, columns (name, type, nullable, default), keys, indexes and checks, by name."""
    engine = create_engine(to_url(url))
    try:
        with engine.connect() as conn:
            ins = inspect(conn)
            out = {}
            for t in sorted(ins.get_table_names()):
                out[t] = dict(
                    columns=[(c["name"], str(c["type"]), c["nullable"], c["default"]) for c in ins.get_columns(t)],
                    pk=ins.get_pk_constraint(t),
                    fks=sorted(
                        (f["name"], tuple(f["constrained_columns"]), f["referred_table"])
                        for f in ins.get_foreign_keys(t)
                    ),
                    indexes=sorted(
                        (i["name"], tuple(i["column_names"]), bool(i["unique"])) for i in ins.get_indexes(t)
                    ),
                    uniques=sorted((u["name"], tuple(u["column_names"])) for u in ins.get_unique_constraints(t)),
                    checks=sorted((c["name"], c["sqltext"]) for c in ins.get_check_constraints(t)),
                )
            return out
    finally:
        engine.dispose()


def test_a_version_1_store_on_postgresql_is_upgraded_without_losing_rows(pg_server):
    url = pg_server.url(pg_server.new_database())
    _exec(url, V1_PG)
    before = _dump(url)
    assert len(before["runs"]) == 2 and len(before["measurements"]) == 2

    with ResultsStore(url) as store:
        assert store.schema_version == SCHEMA_VERSION == 4
        after = _dump(url)
        for table, rows in before.items():  # every old row with its old values; new columns appended
            assert [row[: len(rows[0])] for row in after[table]] == rows, table
        assert store.artifacts(1)[0].kind == "frame"
        assert [m.status for m in store.measurements()] == [State.TOLERANCE, State.OK]
        assert store.tolerance("drift_x_px", at=1600000100) == (1, DRIFT)
        assert store.run(2).status == "running"  # no pid: cannot be judged
        with store.begin_run("drift") as run:  # new rows take the next ids
            run.measure("cam1", "drift_x_px", 2.5)
        assert run.run_id == 3 and store.run(3).status == "ACTION"
        uids = [r.uid for r in store.runs()]
        assert len(set(uids)) == len(uids) == 3 and all(len(u) == 32 for u in uids)
        # version 4: the console's users and action log
        store.put_user("ann", "operator", "scrypt$hash")
        store.log_actions([{"at": 1600000300.0, "user": "ann", "role": "operator", "what": "LED on"}])
        assert [u.name for u in store.users()] == ["ann"] and store.actions()[0][0].what == "LED on"
    assert _rows(url, "SELECT version FROM schema_migrations ORDER BY version") == [(1,), (2,), (3,), (4,)]
    # an upgraded store has exactly the layout of a fresh one
    fresh = pg_server.url(pg_server.new_database())
    ResultsStore(fresh).close()
    assert _layout(url) == _layout(fresh)
    ResultsStore(url).close()  # opening again changes nothing
    assert _dump(url)["runs"][:2] == after["runs"][:2]


def test_a_newer_or_foreign_postgresql_database_is_refused_and_left_alone(pg_server):
    newer = pg_server.url(pg_server.new_database())
    ResultsStore(newer).close()
    _exec(newer, f"INSERT INTO schema_migrations VALUES ({SCHEMA_VERSION + 1}, 0, 'from the future')")
    with pytest.raises(StoreError, match=f"schema version {SCHEMA_VERSION + 1} is newer"):
        ResultsStore(newer)
    foreign = pg_server.url(pg_server.new_database())
    _exec(foreign, "CREATE TABLE runs (x INTEGER)")
    with pytest.raises(StoreError, match="not a vts-hw results store"):
        ResultsStore(foreign)
    assert list(_layout(foreign)) == ["runs"] and [c[0] for c in _layout(foreign)["runs"]["columns"]] == ["x"]


def test_readers_see_only_committed_runs_beside_an_open_write(pg_url):
    with ResultsStore(pg_url) as store:
        with store.begin_run("drift") as run:
            run.measure("cam1", "m", 1.0)
        engine = create_engine(to_url(pg_url))
        try:
            with engine.connect() as writer:
                writer.begin()
                writer.execute(
                    text(
                        "INSERT INTO runs (procedure, started, status, uid) "
                        "SELECT 'big', 0, 'OK', 'big' || g FROM generate_series(1, 3000) g"
                    )
                )
                with ResultsStore(pg_url, busy_timeout=1) as reader:  # not blocked, sees the committed state
                    assert [r.procedure for r in reader.runs()] == ["drift"]
                writer.commit()
        finally:
            engine.dispose()
        assert len(store.runs(procedure="big")) == 3000


# -- the password --------------------------------------------------------------------------------


def test_the_password_comes_from_the_named_variable_and_shows_nowhere(pg_server, monkeypatch, caplog):
    caplog.set_level(logging.DEBUG)
    url = pg_server.password_url(pg_server.new_database(owner="vts"))
    monkeypatch.setenv(PASSWORD_ENV, pg_server.password)
    with ResultsStore(url, password_env=PASSWORD_ENV) as store:
        with store.begin_run("drift", rig="room1") as run:
            run.measure("cam1", "drift_x_px", 0.1)
        assert store.url == url.replace("postgresql://", "postgresql+psycopg://")
        assert pg_server.password not in repr(store)
        assert [r.rig for r in store.runs()] == ["room1"]
        dumped = json.dumps([r.__dict__ for r in store.runs()])
    assert pg_server.password not in dumped + caplog.text
    # a wrong password: the server's refusal, one sentence, no password in it
    monkeypatch.setenv(PASSWORD_ENV, "not-the-password")
    with pytest.raises(StoreError, match="password authentication failed") as info:
        ResultsStore(url, password_env=PASSWORD_ENV)
    assert "not-the-password" not in str(info.value)
    # unset: one sentence naming the variable, before any connection
    monkeypatch.delenv(PASSWORD_ENV)
    with pytest.raises(StoreError, match=f"environment variable {PASSWORD_ENV}, named to hold") as info:
        ResultsStore(url, password_env=PASSWORD_ENV)
    assert info.value.exit_code == 3


def test_rig_yaml_store_section_with_password_env_through_the_cli(pg_server, tmp_path):
    url = pg_server.password_url(pg_server.new_database(owner="vts"))
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        f"rig: room7\ncameras:\n  - name: cam1\n    host: 127.0.0.1\n"
        f"store:\n  url: {url}\n  password_env: ROOM7_DB_PW\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in (ENV_STORE, ENV_STORE_PASSWORD_ENV)}
    env["VTS_CONFIG"] = str(cfg)
    p = run("store", "info", env=dict(env, ROOM7_DB_PW=pg_server.password))
    assert p.returncode == 3 and "is an empty database" in p.stderr  # reading makes no store (`store init` does)
    p = run("store", "init", url, "--password-env", "ROOM7_DB_PW", env=dict(env, ROOM7_DB_PW=pg_server.password))
    assert p.returncode == 0 and "results store created" in p.stdout, p.stderr
    p = run("store", "info", "--json", env=dict(env, ROOM7_DB_PW=pg_server.password))
    assert p.returncode == 0, p.stderr
    info = json.loads(p.stdout)
    assert info["schema_version"] == SCHEMA_VERSION and info["from"] == "rig.yaml store.url"
    assert info["url"].endswith(url.split("://")[1]) and pg_server.password not in p.stdout
    p = run("store", "info", env=env)
    assert p.returncode == 3 and "ROOM7_DB_PW" in p.stderr and "Traceback" not in p.stderr
    assert len(p.stderr.strip().splitlines()) == 1


# -- which store ----------------------------------------------------------------------------------


def _rig(**section):
    return parse_rig({"rig": "r", "cameras": [{"name": "cam1", "host": "127.0.0.1"}], **section})


def test_store_section_its_old_name_and_both(monkeypatch):
    monkeypatch.delenv(ENV_STORE, raising=False)
    monkeypatch.delenv(ENV_STORE_PASSWORD_ENV, raising=False)
    new = _rig(store={"url": "postgresql://vts@db.example/qa", "password_env": "QA_PW"})
    old = _rig(results={"url": "postgresql://vts@db.example/qa", "password_env": "QA_PW"})
    assert new.store == old.store == old.results
    t = resolve_target(rig=new)
    assert (t.url, t.password_env, t.source) == ("postgresql://vts@db.example/qa", "QA_PW", "rig.yaml store.url")
    with pytest.raises(ConfigError, match="store and results .the old name of store. are both given"):
        _rig(store={"url": "sqlite:////a.sqlite"}, results={"url": "sqlite:////b.sqlite"})
    with pytest.raises(ConfigError, match="store.url holds a password") as info:
        _rig(store={"url": "postgresql://vts:hunter2@db.example/qa"})
    assert "hunter2" not in str(info.value)
    with pytest.raises(ConfigError, match="store.password_env"):
        _rig(store={"url": "postgresql://vts@db.example/qa", "password_env": "not a name"})


def test_precedence_cli_then_env_then_rig_then_default(monkeypatch):
    rig = _rig(store={"url": "sqlite:////rig.sqlite", "password_env": "RIG_PW"})
    monkeypatch.delenv(ENV_STORE, raising=False)
    monkeypatch.delenv(ENV_STORE_PASSWORD_ENV, raising=False)
    assert resolve_target(rig=None).url is None  # the per-user default
    assert resolve_target(rig=rig).url == "sqlite:////rig.sqlite"
    monkeypatch.setenv(ENV_STORE, "postgresql://vts@env/qa")
    monkeypatch.setenv(ENV_STORE_PASSWORD_ENV, "ENV_PW")
    t = resolve_target(rig=rig)
    assert (t.url, t.password_env, t.source) == ("postgresql://vts@env/qa", "ENV_PW", "$VTS_STORE")
    t = resolve_target("postgresql://vts@cli/qa", "CLI_PW", rig=rig)
    assert (t.url, t.password_env, t.source) == ("postgresql://vts@cli/qa", "CLI_PW", "--store")
    with pytest.raises(UsageError, match="--store: the database URL holds a password") as info:
        resolve_target("postgresql://vts:hunter2@cli/qa", rig=rig)
    assert "hunter2" not in str(info.value) and info.value.exit_code == 2
    monkeypatch.setenv(ENV_STORE, "postgresql://vts:hunter2@env/qa")
    with pytest.raises(UsageError, match=r"\$VTS_STORE: the database URL holds a password"):
        resolve_target(rig=rig)


def test_vts_store_option_and_env_pick_the_store(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in (ENV_STORE, ENV_STORE_PASSWORD_ENV, "VTS_CONFIG")}
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(
        f"rig: r\ncameras:\n  - name: cam1\n    host: 127.0.0.1\nresults:\n  url: sqlite:///{tmp_path}/rig.sqlite\n"
    )

    def info(*args, **extra):
        p = run(*args, env=dict(env, **extra))
        return p.returncode, (json.loads(p.stdout) if p.returncode == 0 else p.stderr)

    for name in ("rig", "env", "cli"):  # `store info` reads: the stores exist
        ResultsStore(tmp_path / f"{name}.sqlite").close()
    code, out = info("store", "info", "--json", "--config", str(cfg))
    assert code == 0 and out["url"] == f"sqlite:///{tmp_path}/rig.sqlite"
    code, out = info("store", "info", "--json", "--config", str(cfg), VTS_STORE=f"sqlite:///{tmp_path}/env.sqlite")
    assert code == 0 and out["url"] == f"sqlite:///{tmp_path}/env.sqlite" and out["from"] == "$VTS_STORE"
    code, out = info(
        "--store",
        f"sqlite:///{tmp_path}/cli.sqlite",
        "store",
        "info",
        "--json",
        "--config",
        str(cfg),
        VTS_STORE=f"sqlite:///{tmp_path}/env.sqlite",
    )
    assert code == 0 and out["url"] == f"sqlite:///{tmp_path}/cli.sqlite" and out["from"] == "--store"
    code, err = info("--store", "postgresql://u:hunter2@127.0.0.1/x", "store", "info")
    assert code == 2 and "holds a password" in err and "hunter2" not in err and "Traceback" not in err


def test_vts_store_takes_a_report_from_postgresql_with_the_password_from_its_variable(pg_server, tmp_path, monkeypatch):
    from test_report import populate

    url = pg_server.password_url(pg_server.new_database(owner="vts"))
    monkeypatch.setenv(PASSWORD_ENV, pg_server.password)
    with ResultsStore(url, password_env=PASSWORD_ENV) as store:
        populate(store)
    cfg = tmp_path / "rig.yaml"  # the room's own store is another: --store wins
    cfg.write_text(
        f"rig: vts\ncameras:\n  - name: cam1\n    host: 127.0.0.1\nstore:\n  url: sqlite:///{tmp_path}/room.sqlite\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in (ENV_STORE, ENV_STORE_PASSWORD_ENV, PASSWORD_ENV)}
    env.update(VTS_CONFIG=str(cfg), DEPT_DB_PW=pg_server.password)
    out = tmp_path / "drift.html"
    p = run(
        "--store",
        url,
        "--store-password-env",
        "DEPT_DB_PW",
        "report",
        "drift",
        "--since",
        "all",
        "-o",
        out,
        "--json",
        env=env,
    )
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert set(data["cameras"]) == {"cam1", "cam2"} and not (tmp_path / "room.sqlite").exists()
    assert pg_server.password not in out.read_text() + p.stdout + p.stderr
