"""The results store's test helpers shared by tests/integration/test_store.py and tests/integration/test_store_schema.py:
a fresh store on each back end, an SQLite file, raw SQL beside the store, the file's integrity."""

import sqlite3
from pathlib import Path

import pytest
from sqlalchemy import create_engine, text

from vts_hw.store import ResultsStore
from vts_hw.store.paths import sqlite_file, to_url


@pytest.fixture()
def db(tmp_path) -> Path:
    return tmp_path / "data" / "results.sqlite"


@pytest.fixture()
def sqlite_store(db):
    with ResultsStore(str(db)) as s:
        yield s


@pytest.fixture()
def store(store_url):
    """A fresh store on each back end (conftest.store_url)."""
    with ResultsStore(store_url) as s:
        yield s


def _sql(url: str, *statements: str, params: dict | None = None) -> list:
    """Run raw SQL on the database behind ``url`` (any back end), outside the store, in one
    committed transaction; the rows of the last statement."""
    engine = create_engine(to_url(url))
    try:
        with engine.begin() as conn:
            rows = []
            for stmt in statements:
                res = conn.execute(text(stmt), params or {})
                rows = res.all() if res.returns_rows else []
            return rows
    finally:
        engine.dispose()


def _is_pg(url: str) -> bool:
    return url.startswith("postgresql")


def _raw(db: Path) -> sqlite3.Connection:
    return sqlite3.connect(db, isolation_level=None)


def _check_file(db) -> None:
    """SQLite: the file's integrity and foreign keys (PostgreSQL checks its own on every write)."""
    if isinstance(db, str):
        db = sqlite_file(to_url(db))
        if db is None:
            return
    con = _raw(db)
    try:
        assert con.execute("PRAGMA integrity_check").fetchall() == [("ok",)]
        assert con.execute("PRAGMA foreign_key_check").fetchall() == []
    finally:
        con.close()
