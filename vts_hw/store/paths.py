"""Where the store lives: the default per-user file, and URLs made safe to show.

The default follows the XDG base directory spec: ``$XDG_DATA_HOME/vts-hw/results.sqlite``
when XDG_DATA_HOME is set to an absolute path (the spec says to ignore a relative one),
else ``~/.local/share/vts-hw/results.sqlite``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from sqlalchemy.engine import URL, make_url

APP_DIR = "vts-hw"
DB_NAME = "results.sqlite"


def default_path() -> Path:
    """The default SQLite file of the current user."""
    xdg = os.environ.get("XDG_DATA_HOME", "")
    base = Path(xdg) if xdg and os.path.isabs(xdg) else Path.home() / ".local" / "share"
    return base / APP_DIR / DB_NAME


def default_url() -> str:
    """``sqlite:////abs/path/results.sqlite`` for the default file."""
    return f"sqlite:///{default_path()}"


@dataclass(frozen=True)
class StoreTarget:
    """A store to open: its URL (None: the per-user default), the name of the environment
    variable holding its password (None: none, or libpq's own PGPASSWORD/~/.pgpass), and
    where the URL came from (for messages)."""

    url: str | None = None
    password_env: str | None = None
    source: str = "default"

    def __str__(self) -> str:
        return self.url or default_url()


#: driver names taken as PostgreSQL through psycopg 3
_PG_NAMES = {"postgresql": "postgresql+psycopg", "postgres": "postgresql+psycopg"}


def to_url(url: str | os.PathLike | StoreTarget | None) -> URL:
    """A SQLAlchemy URL from a URL string, a plain file path (taken as SQLite), a StoreTarget or
    None (default). ``postgresql://`` (and ``postgres://``) mean PostgreSQL through psycopg 3."""
    if isinstance(url, StoreTarget):
        url = url.url
    if url is None:
        url = default_url()
    if isinstance(url, os.PathLike) or "://" not in url:
        return URL.create("sqlite", database=str(Path(url).expanduser().absolute()))
    parsed = make_url(url)
    if parsed.drivername in _PG_NAMES:
        parsed = parsed.set(drivername=_PG_NAMES[parsed.drivername])
    return parsed


def masked(url: URL) -> str:
    """The URL as text with any password replaced by ``***`` (for repr, logs and errors)."""
    return url.render_as_string(hide_password=True)


def sqlite_file(url: URL) -> Path | None:
    """The file of a file-based SQLite URL, None for other databases and in-memory SQLite."""
    if url.get_backend_name() != "sqlite":
        return None
    db = url.database or ""
    if db in ("", ":memory:") or db.startswith("file:"):
        return None
    return Path(db)
