"""Is a database ours? A store that is not a vts-hw results store is never written.

A database named as the results store is one of:

* ``new`` — an SQLite file that does not exist or has 0 bytes (or one vts-hw is creating
  right now: switched to the WAL journal, one page, no tables yet);
* ``empty`` — a database with no tables (an SQLite file with nothing in it, a PostgreSQL
  database just made by ``createdb``);
* ``ours`` — a vts-hw results store (``schema_migrations`` with its columns, ``runs`` and
  ``measurements``), of any schema version;
* ``foreign`` — anything else: a file that is not an SQLite database, a database holding
  other tables.

What may be done with each depends on what the command does (:data:`MODES`):

* ``read`` (reports, ``vts store info``, the source of ``vts store migrate``, ``vts qa push``):
  only ``ours``; anything else is refused in one sentence and nothing is created;
* ``create`` (commands that write results, the target of a migrate; the default of
  :class:`~vts_hw.store.ResultsStore`): also ``new`` becomes a store, and on PostgreSQL an
  ``empty`` database (``createdb`` is how a department makes a new one: the analogue of a
  0-byte file);
* ``init`` (``vts store init URL``): also an ``empty`` SQLite file.

``foreign`` is refused whatever the command. The SQLite check reads the file through a
connection of its own that never creates the file, never switches its journal and ends with a
rollback: a foreign file stays byte-identical. See docs/decisions/0050-foreign-databases.md.
"""

from __future__ import annotations

import os
import sqlite3
import stat
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import quote

from sqlalchemy import Connection, inspect

from vts_hw.files import kind_of
from vts_hw.store.errors import NoStore, StoreError

NEW, EMPTY, OURS, FOREIGN = "new", "empty", "ours", "foreign"
MODES = ("read", "create", "init")
#: the tables and columns that make a database a vts-hw results store (any schema version)
OUR_TABLES = ("schema_migrations", "runs", "measurements")
OUR_VERSION_COLUMNS = {"version", "applied", "description"}


@dataclass(frozen=True)
class Found:
    kind: str  # NEW, EMPTY, OURS or FOREIGN
    detail: str = ""  # why, in words ("the file does not exist", "it holds the table(s) users, posts")


def _tables_text(names) -> str:
    names = sorted(names)
    shown = ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")
    return f"it holds the table(s) {shown}"


def judge_tables(tables: set[str], version_columns: set[str]) -> Found:
    """ours / empty / foreign from a database's table names and ``schema_migrations``' columns."""
    if not tables:
        return Found(EMPTY, "it holds no tables")
    if set(OUR_TABLES) <= tables and OUR_VERSION_COLUMNS <= version_columns:
        return Found(OURS)
    return Found(FOREIGN, _tables_text(tables))


def sqlite_file_kind(path: Path, busy_timeout: float = 30.0) -> Found:
    """What the SQLite file at ``path`` is, read without changing it (see the module docstring)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return Found(NEW, "the file does not exist")
    except OSError as exc:
        raise StoreError(f"{path}: cannot read the results store ({exc.strerror or exc})") from None
    if stat.S_ISLNK(st.st_mode):  # as every writer: a link is not followed (decision 0081)
        return Found(FOREIGN, f"it is {kind_of(path, st)}, which is never followed: name the store file itself")
    if not stat.S_ISREG(st.st_mode):  # a folder, or a device or FIFO SQLite would write into or wait on
        return Found(FOREIGN, f"it is {kind_of(path, st)}, not a regular file")
    size = st.st_size
    if size == 0:
        return Found(NEW, "the file is empty (0 bytes)")
    try:  # mode=rw: never creates the file; no journal switch, a read transaction rolled back
        con = sqlite3.connect(
            f"file:{quote(str(path.absolute()))}?mode=rw", uri=True, timeout=busy_timeout, isolation_level=None
        )
    except sqlite3.Error as exc:
        raise StoreError(f"{path}: cannot open the results store ({exc})") from None
    try:
        con.execute("BEGIN")
        rows = con.execute("SELECT type, name FROM sqlite_master").fetchall()
        tables = {name for kind, name in rows if kind in ("table", "view") and not name.startswith("sqlite_")}
        cols = (
            {r[1] for r in con.execute("PRAGMA table_info(schema_migrations)")}
            if "schema_migrations" in tables
            else set()
        )
        if not rows:
            journal = con.execute("PRAGMA journal_mode").fetchone()[0]
            pages = con.execute("PRAGMA page_count").fetchone()[0]
            tagged = (
                con.execute("PRAGMA user_version").fetchone()[0] or con.execute("PRAGMA application_id").fetchone()[0]
            )
            if str(journal).lower() == "wal" and pages <= 1 and not tagged:
                return Found(NEW, "a store being created")  # what a 0-byte file becomes in our hands
        con.execute("ROLLBACK")
    except sqlite3.DatabaseError as exc:
        text = str(exc)
        if "not a database" in text or "malformed" in text or "encrypted" in text:
            return Found(FOREIGN, "it is not an SQLite database")
        raise StoreError(f"{path}: cannot read the results store ({text})") from None
    finally:
        con.close()
    return judge_tables(tables, cols)


def connection_kind(conn: Connection) -> Found:
    """What the database behind ``conn`` is (its default schema), through SQLAlchemy's inspector."""
    insp = inspect(conn)
    tables = set(insp.get_table_names()) | set(insp.get_view_names())
    cols = {c["name"] for c in insp.get_columns("schema_migrations")} if "schema_migrations" in tables else set()
    return judge_tables(tables, cols)


def allowed(found: Found, mode: str, where: str, backend: str) -> None:
    """StoreError (exit 3) in one sentence when a command of ``mode`` must not use ``found``."""
    if mode not in MODES:
        raise ValueError(f"mode {mode!r}: expected one of {', '.join(MODES)}")
    if found.kind == OURS:
        return
    if found.kind == FOREIGN:
        raise StoreError(
            f"{where} is not a vts-hw results store ({found.detail}), so it was left untouched: "
            "name the results store, or a new file for one"
        )
    init = f"`vts store init {where}` makes it one"
    if found.kind == NEW:
        if mode in ("create", "init"):
            return
        raise NoStore(f"{where}: there is no results store there ({found.detail}); a QA run creates it, or {init}")
    # EMPTY
    if mode == "init" or (mode == "create" and backend != "sqlite"):
        return
    raise StoreError(f"{where} is an empty database, not a vts-hw results store ({found.detail}); {init}")


__all__ = [
    "Found",
    "sqlite_file_kind",
    "connection_kind",
    "allowed",
    "judge_tables",
    "MODES",
    "NEW",
    "EMPTY",
    "OURS",
    "FOREIGN",
]
