"""A throwaway PostgreSQL server for the tests: initdb in a temporary folder, listening on
127.0.0.1 (a free port) and on a unix socket in that folder, stopped and removed at the end.

PostgreSQL refuses to run as root, and CI runs as root: then initdb and postgres run as the
unprivileged user ``nobody`` (the folder is handed to it). The binaries are found with
``pg_config --bindir``, else in /usr/lib/postgresql/<newest>/bin; `make test` installs
Debian's ``postgresql`` package when it is missing.

Roles: ``postgres`` (superuser, trusted on the unix socket only) and ``vts`` (a password,
scram-sha-256 over TCP), so the password path of the store is exercised for real.
Each test gets a database of its own (:meth:`PgServer.new_database`, a copy of template0,
~0.1 s; dropped after the test, ~0.01 s).
"""

from __future__ import annotations

import atexit
import glob
import itertools
import os
import pwd
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

import psycopg

INSTALL_HELP = (
    "PostgreSQL's server programs (initdb, postgres) were not found: install Debian's "
    "postgresql package (`apt-get install -y postgresql`; make test does this)"
)
PASSWORD_ENV = "VTS_TEST_PG_PASSWORD"


def find_bindir() -> Path:
    """The folder holding initdb and postgres."""
    candidates = []
    pg_config = shutil.which("pg_config")
    if pg_config:
        out = subprocess.run([pg_config, "--bindir"], capture_output=True, text=True)
        if out.returncode == 0 and out.stdout.strip():
            candidates.append(Path(out.stdout.strip()))

    def version(p: str):
        try:
            return float(Path(p).parent.name)
        except ValueError:
            return 0.0

    candidates += [Path(p) for p in sorted(glob.glob("/usr/lib/postgresql/*/bin"), key=version, reverse=True)]
    for d in candidates:
        if (d / "initdb").is_file() and (d / "postgres").is_file():
            return d
    raise RuntimeError(INSTALL_HELP)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class PgServer:
    """``durable`` False (the tests): fsync and synchronous commit off, for speed (a killed
    client is still rolled back; only a crash of the machine could lose commits). True (the
    benchmarks): the server's defaults, every commit flushed to disk."""

    def __init__(self, durable: bool = False):
        self.durable = durable
        self.bindir = find_bindir()
        self.dir = Path(tempfile.mkdtemp(prefix="vts-pg-"))
        self.data = self.dir / "data"
        self.port = 0
        self.password = secrets.token_urlsafe(16)
        self.proc: subprocess.Popen | None = None
        self._names = itertools.count(1)
        self._as = {}
        if os.geteuid() == 0:  # postgres refuses root: run it as nobody
            nobody = pwd.getpwnam("nobody")
            os.chown(self.dir, nobody.pw_uid, nobody.pw_gid)
            self._as = dict(user=nobody.pw_uid, group=nobody.pw_gid, extra_groups=[])

    # -- life -------------------------------------------------------------------------------

    def start(self) -> PgServer:
        atexit.register(self.stop)
        out = subprocess.run(
            [
                str(self.bindir / "initdb"),
                "-D",
                str(self.data),
                "-U",
                "postgres",
                "--auth-local=trust",
                "--auth-host=scram-sha-256",
                "-E",
                "UTF8",
                "--no-locale",
                "--no-sync",
            ],
            capture_output=True,
            text=True,
            cwd=self.dir,
            **self._as,
        )
        if out.returncode != 0:
            raise RuntimeError(f"initdb failed: {out.stderr.strip()}")
        for _attempt in range(5):
            self.port = _free_port()
            log = open(self.dir / "server.log", "ab")
            self.proc = subprocess.Popen(
                [
                    str(self.bindir / "postgres"),
                    "-D",
                    str(self.data),
                    "-p",
                    str(self.port),
                    "-c",
                    "listen_addresses=127.0.0.1",
                    "-c",
                    f"unix_socket_directories={self.dir}",
                    *(
                        []
                        if self.durable
                        else ["-c", "fsync=off", "-c", "full_page_writes=off", "-c", "synchronous_commit=off"]
                    ),
                    "-c",
                    "max_connections=200",
                    "-c",
                    "shared_buffers=32MB",
                    "-c",
                    "log_min_messages=warning",
                ],
                stdout=log,
                stderr=subprocess.STDOUT,
                cwd=self.dir,
                start_new_session=True,
                **self._as,
            )
            log.close()
            if self._wait_ready():
                break
            self._terminate()
        else:
            raise RuntimeError(f"postgres did not start: {(self.dir / 'server.log').read_text()[-2000:]}")
        with self.admin() as con:
            con.execute(f"CREATE ROLE vts LOGIN CREATEDB PASSWORD '{self.password}'")
        return self

    def _wait_ready(self, timeout: float = 30.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.proc.poll() is not None:
                return False
            try:
                psycopg.connect(self.dsn("postgres"), connect_timeout=2).close()
                return True
            except psycopg.OperationalError:
                time.sleep(0.05)
        return False

    def _terminate(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)  # fast shutdown: ends every session
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None

    def stop(self) -> None:
        self._terminate()
        shutil.rmtree(self.dir, ignore_errors=True)

    # -- use --------------------------------------------------------------------------------

    def dsn(self, db: str) -> str:
        """libpq connection string of the superuser over the unix socket."""
        return f"host={self.dir} port={self.port} user=postgres dbname={db}"

    def admin(self, db: str = "postgres") -> psycopg.Connection:
        return psycopg.connect(self.dsn(db), autocommit=True)

    def new_database(self, owner: str = "postgres") -> str:
        name = f"t{os.getpid()}_{next(self._names)}"
        with self.admin() as con:
            con.execute(f'CREATE DATABASE "{name}" OWNER {owner} TEMPLATE template0')
        return name

    def drop_database(self, name: str) -> None:
        """Drop a test's database (ending any connection left to it): the disk stays small."""
        with self.admin() as con:
            con.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')

    def url(self, db: str) -> str:
        """SQLAlchemy URL of the superuser over the unix socket (no password)."""
        return f"postgresql://postgres@/{db}?host={self.dir}&port={self.port}"

    def password_url(self, db: str) -> str:
        """SQLAlchemy URL of the ``vts`` role over TCP on 127.0.0.1; its password is in no URL:
        the store reads it from $VTS_TEST_PG_PASSWORD (``password_env``)."""
        return f"postgresql://vts@127.0.0.1:{self.port}/{db}"
