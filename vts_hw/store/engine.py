"""Engines: SQLite set up for safety and concurrency, anything else left to SQLAlchemy.

SQLite (file): the parent directory is created, and the file made readable by its owner
only (:func:`owner_only`); every connection gets a busy timeout,
foreign keys on, ``synchronous = FULL`` and the WAL journal (readers never wait for the
writer; a commit is one append to the WAL, so a ``kill -9`` at any moment leaves the last
committed state). Python's sqlite3 driver does not BEGIN before DDL or SELECT (legacy
transaction control), so its transaction handling is switched off and SQLAlchemy emits
BEGIN itself: ``BEGIN`` for reads (one snapshot per read) and ``BEGIN IMMEDIATE`` for
writes (take the write lock first, waiting up to the busy timeout, instead of failing
half-way when another writer got there first).

PostgreSQL (``postgresql://`` is taken as psycopg 3, see paths.to_url): the server's default
isolation (READ COMMITTED); a commit is durable when the server says so; a client killed
mid-transaction is rolled back by the server.

In-memory SQLite (``sqlite://``) shares one connection (tests; one thread at a time).
"""

from __future__ import annotations

import logging
import os
import stat
from pathlib import Path

from sqlalchemy import Connection, create_engine, event
from sqlalchemy.engine import URL, Engine
from sqlalchemy.pool import StaticPool

from vts_hw.files import PRIVATE
from vts_hw.store.errors import StoreError
from vts_hw.store.paths import masked, sqlite_file

log = logging.getLogger(__name__)

#: the files SQLite keeps beside a database (WAL mode, and a rollback journal)
SQLITE_SIDE_FILES = ("-wal", "-shm", "-journal")
#: execution option that makes the next BEGIN on a SQLite connection a BEGIN IMMEDIATE
WRITE_OPTION = "vts_store_write"


def make_engine(url: URL, busy_timeout: float, password_env: str | None = None) -> Engine:
    """An engine for ``url``; for SQLite, configured as the module docstring says.

    PostgreSQL: ``password_env`` names the environment variable whose value is handed to the
    driver at each connect (the password lives in no URL, log or message); a connect gives
    up after ``busy_timeout`` seconds at most (10 s unless the URL says otherwise)."""
    if url.get_backend_name() != "sqlite":
        args = {}
        if url.get_backend_name() == "postgresql" and "connect_timeout" not in url.query:
            args["connect_timeout"] = max(1, min(10, int(busy_timeout)))
        engine = create_engine(url, pool_pre_ping=True, connect_args=args)
        if password_env:
            password_from_env(url, password_env)  # unset: one sentence now, not at first use

            @event.listens_for(engine, "do_connect")
            def _password(_dialect, _conn_rec, _cargs, cparams):
                cparams["password"] = password_from_env(url, password_env)

        return engine
    path = sqlite_file(url)
    if path is None:
        engine = create_engine(url, poolclass=StaticPool, connect_args={"check_same_thread": False})
    else:
        owner_only(path)
        engine = create_engine(url, connect_args={"timeout": busy_timeout, "check_same_thread": False})
    _sqlite_setup(engine, busy_timeout, wal=path is not None, where=masked(url))
    return engine


def owner_only(path: Path) -> None:
    """The SQLite store readable by its owner only (it holds the console users' password hashes):
    its folder made 0700 when new, the file created 0600 (exclusively, never through a link)
    before SQLite opens it, so that its -wal, -shm and -journal files, which SQLite creates with
    the database's mode, are 0600 too. A store of ours (this user's) that others may read is
    narrowed to 0600, with those files; one of another user keeps its mode. Decision 0081."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        os.close(os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, PRIVATE))
        return
    except FileExistsError:
        pass
    except OSError as exc:
        raise StoreError(f"{path}: cannot create the results store ({exc.strerror or exc})") from None
    for p in (path, *(path.with_name(path.name + s) for s in SQLITE_SIDE_FILES)):
        try:
            st = os.lstat(p)
            if stat.S_ISREG(st.st_mode) and st.st_uid == os.geteuid() and st.st_mode & 0o077:
                os.chmod(p, stat.S_IMODE(st.st_mode) & PRIVATE)
        except OSError:  # absent, or not ours to change: SQLite says what it cannot open
            continue


def password_from_env(url: URL, name: str) -> str:
    """The password in environment variable ``name``; StoreError naming it when it is not set."""
    value = os.environ.get(name)
    if not value:
        raise StoreError(
            f"{masked(url)}: the environment variable {name}, named to hold the database "
            f"password (store.password_env), is not set"
        )
    return value


def _sqlite_setup(engine: Engine, busy_timeout: float, wal: bool, where: str) -> None:
    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn, _record):
        dbapi_conn.isolation_level = None  # SQLAlchemy emits BEGIN (below), not the driver
        cur = dbapi_conn.cursor()
        try:
            cur.execute(f"PRAGMA busy_timeout = {int(busy_timeout * 1000)}")
            cur.execute("PRAGMA foreign_keys = ON")
            if wal:
                mode = cur.execute("PRAGMA journal_mode").fetchone()[0]
                if str(mode).lower() != "wal":
                    mode = cur.execute("PRAGMA journal_mode = WAL").fetchone()[0]
                    if str(mode).lower() != "wal":
                        log.warning(
                            "%s: cannot use the WAL journal (got %s); readers may wait for writers", where, mode
                        )
            cur.execute("PRAGMA synchronous = FULL")
        finally:
            cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn: Connection):
        write = conn.get_execution_options().get(WRITE_OPTION, False)
        conn.exec_driver_sql("BEGIN IMMEDIATE" if write else "BEGIN")
