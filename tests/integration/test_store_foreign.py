"""A database that is not a vts-hw results store is never written (issue 21, part A 2): every
command that opens the store refuses it in one sentence (exit 3) and leaves it byte-identical;
an empty database or a store that does not exist yet is refused for reading; only a new file
given to a command that writes results, or `vts store init`, becomes a store. On SQLite and on
the throwaway PostgreSQL server."""

from __future__ import annotations

import hashlib
import json
import sqlite3
from pathlib import Path

import psycopg
import pytest

from inprocess_cli import vts
from vts_hw.store import ResultsStore, StoreError
from vts_hw.store.paths import to_url


def sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def beside(p: Path) -> list[str]:
    """Everything in the file's folder named after it (-wal, -shm, -journal ...)."""
    return sorted(q.name for q in p.parent.iterdir() if q.name.startswith(p.name))


@pytest.fixture()
def foreign(tmp_path) -> Path:
    """Someone else's SQLite database (rollback journal, two tables)."""
    p = tmp_path / "clinic.sqlite"
    con = sqlite3.connect(p)
    con.executescript(
        "CREATE TABLE patients (id INTEGER PRIMARY KEY, name TEXT);"
        "INSERT INTO patients (name) VALUES ('A'), ('B');"
        "CREATE TABLE runs (id INTEGER PRIMARY KEY, what TEXT);"
    )
    con.commit()
    con.close()
    return p


@pytest.fixture()
def good(tmp_path) -> Path:
    p = tmp_path / "ours.sqlite"
    with ResultsStore(p) as s, s.begin_run("daily", rig="room-1") as h:
        h.measure("cam1", "drift_x_px", 0.1, "px")
    return p


def _empty_sqlite(p: Path) -> Path:
    con = sqlite3.connect(p)
    con.execute("PRAGMA user_version = 0")
    con.execute("VACUUM")
    con.close()
    assert p.stat().st_size > 0
    return p


def test_every_store_command_leaves_a_foreign_sqlite_file_byte_identical(foreign, good, tmp_path, capsys):
    before = sha(foreign)
    url = f"sqlite:///{foreign}"
    cases = [
        ("--store", url, "store", "info"),
        ("store", "migrate", "--from", foreign, "--to", tmp_path / "new.sqlite"),
        ("store", "migrate", "--from", good, "--to", url),
        ("store", "init", url),
        ("--store", url, "report", "drift", "--rig", "room-1", "-o", tmp_path / "d.html"),
        ("--store", url, "report", "rooms", "-o", tmp_path / "r.html"),
    ]
    for args in cases:
        code, out, err = vts(capsys, *args)
        assert code == 3, (args, code, err)
        line = err.strip()
        assert "\n" not in line and "Traceback" not in err, err
        assert str(foreign) in line and "is not a vts-hw results store" in line and "patients" in line, line
        assert sha(foreign) == before and beside(foreign) == [foreign.name], args
    assert not (tmp_path / "new.sqlite").exists()
    assert not (tmp_path / "d.html").exists() and not (tmp_path / "r.html").exists()
    # a file that is not SQLite at all, the same
    junk = tmp_path / "notes.db"
    junk.write_bytes(b"this is my lab notebook, not a database\n" * 200)
    code, _, err = vts(capsys, "--store", junk, "store", "info")
    assert code == 3 and "not an SQLite database" in err and junk.read_bytes().startswith(b"this is my lab")
    # the library too, whatever the mode
    for mode in ("read", "create", "init"):
        with pytest.raises(StoreError, match="not a vts-hw results store"):
            ResultsStore(foreign, mode=mode)
    assert sha(foreign) == before


def test_a_command_that_writes_results_never_writes_into_a_foreign_store(foreign, tmp_path, capsys):
    """`vts qa import` (a writer) keeps the run file and names the foreign database."""
    from vts_hw.store.unsaved import FORMAT

    run = tmp_path / "run.json"
    run.write_text(
        json.dumps(
            {
                "format": FORMAT,
                "procedure": "daily",
                "started": 1.8e9,
                "finished": 1.8e9 + 5,
                "state": "OK",
                "measurements": [
                    {"subject": "cam1", "metric": "drift_x_px", "value": 0.1, "unit": "px", "state": "OK"}
                ],
            }
        )
    )
    cfg = tmp_path / "rig.yaml"
    cfg.write_text(f"rig: room-1\ncameras:\n  - name: cam1\n    host: 127.0.0.1\nstore:\n  url: sqlite:///{foreign}\n")
    before = sha(foreign)
    code, _, err = vts(capsys, "qa", "import", run, "--config", cfg)
    assert code == 3 and "is not a vts-hw results store" in err
    assert sha(foreign) == before and run.exists()


def test_reading_never_creates_a_store(tmp_path, capsys):
    missing, zero, empty = tmp_path / "missing.sqlite", tmp_path / "zero.sqlite", _empty_sqlite(tmp_path / "e.sqlite")
    zero.write_bytes(b"")
    empty_sha = sha(empty)
    for p, words in ((missing, "does not exist"), (zero, "0 bytes"), (empty, "is an empty database")):
        for args in (
            ("--store", p, "store", "info"),
            ("store", "migrate", "--from", p, "--to", tmp_path / "n.sqlite"),
            ("--store", p, "report", "rooms", "-o", tmp_path / "r.html"),
        ):
            code, _, err = vts(capsys, *args)
            assert code == 3 and words in err and str(p) in err and "Traceback" not in err, (args, err)
    assert not missing.exists() and zero.stat().st_size == 0 and sha(empty) == empty_sha
    assert not (tmp_path / "n.sqlite").exists()
    # a new empty SQLite file made by another tool is not taken by a writer either: only by `store init`
    code, _, err = vts(capsys, "store", "migrate", "--from", _good_store(tmp_path), "--to", empty)
    assert code == 3 and "vts store init" in err and sha(empty) == empty_sha


def _good_store(tmp_path) -> Path:
    p = tmp_path / "src.sqlite"
    with ResultsStore(p) as s, s.begin_run("daily", rig="room-1") as h:
        h.measure("cam1", "drift_x_px", 0.1, "px")
    return p


def test_store_init_and_writers_make_new_files_stores(tmp_path, capsys):
    empty = _empty_sqlite(tmp_path / "e.sqlite")
    zero = tmp_path / "zero.sqlite"
    zero.write_bytes(b"")
    for p in (empty, zero, tmp_path / "sub" / "new.sqlite"):
        code, out, err = vts(capsys, "store", "init", p)
        assert code == 0 and "results store created" in out, err
        code, out, err = vts(capsys, "store", "init", p)  # twice: nothing changes
        assert code == 0 and "already a results store" in out, err
        code, out, err = vts(capsys, "--store", p, "store", "info", "--json")
        assert code == 0 and json.loads(out)["rows"]["runs"] == 0, err
    # a writer takes a new (or 0-byte) file: migrate --to
    zero2 = tmp_path / "zero2.sqlite"
    zero2.write_bytes(b"")
    code, out, err = vts(capsys, "store", "migrate", "--from", _good_store(tmp_path), "--to", zero2)
    assert code == 0, err
    with ResultsStore(zero2, mode="read") as s:
        assert len(s.runs()) == 1


# --- PostgreSQL --------------------------------------------------------------------------------


def _pg_tables(url: str) -> list[tuple]:
    dsn = to_url(url).set(drivername="postgresql").render_as_string(hide_password=False)
    with psycopg.connect(dsn) as con:
        tables = con.execute(
            "SELECT table_name FROM information_schema.tables WHERE table_schema = 'public' ORDER BY table_name"
        ).fetchall()
        rows = con.execute("SELECT id, name FROM patients ORDER BY id").fetchall() if ("patients",) in tables else []
    return tables + rows


def test_a_foreign_postgresql_database_is_never_written(pg_url, good, tmp_path, capsys):
    dsn = to_url(pg_url).set(drivername="postgresql").render_as_string(hide_password=False)
    with psycopg.connect(dsn) as con:
        con.execute("CREATE TABLE patients (id serial PRIMARY KEY, name text)")
        con.execute("INSERT INTO patients (name) VALUES ('A'), ('B')")
    before = _pg_tables(pg_url)
    for args in (
        ("--store", pg_url, "store", "info"),
        ("store", "init", pg_url),
        ("store", "migrate", "--from", good, "--to", pg_url),
        ("store", "migrate", "--from", pg_url, "--to", tmp_path / "n.sqlite"),
        ("--store", pg_url, "report", "rooms", "-o", tmp_path / "r.html"),
    ):
        code, _, err = vts(capsys, *args)
        assert code == 3 and "is not a vts-hw results store" in err and "patients" in err, (args, err)
        assert _pg_tables(pg_url) == before, args
    assert not (tmp_path / "n.sqlite").exists()


def test_an_empty_postgresql_database_is_read_as_nothing_and_written_as_new(pg_url, good, capsys):
    code, _, err = vts(capsys, "--store", pg_url, "store", "info")
    assert code == 3 and "is an empty database" in err and "vts store init" in err
    assert _pg_tables(pg_url) == []
    # `createdb` then a migrate (a command that writes results): the department's new store
    code, out, err = vts(capsys, "store", "migrate", "--from", good, "--to", pg_url)
    assert code == 0, err
    code, out, err = vts(capsys, "--store", pg_url, "store", "info", "--json")
    assert code == 0 and json.loads(out)["rows"]["runs"] == 1


def test_store_init_on_an_empty_postgresql_database(pg_url, capsys):
    code, out, err = vts(capsys, "store", "init", pg_url)
    assert code == 0 and "results store created" in out, err
    assert ("schema_migrations",) in _pg_tables(pg_url)
