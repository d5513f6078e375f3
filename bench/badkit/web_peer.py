"""The console the class "web" of bench/bad_inputs.py talks to, and how it talks (issue 32 §5).

:class:`PlantedRig` sets up once: a simulated rig (`vts sim up --detach --qatrack`: two cameras, a
QATrack+, their passwords and token in ``sim.env``, its store ``results.sqlite`` beside them),
users in that store (``ann`` an operator, ``phil`` a physicist, ``carl`` for the login form's
cases), a run with an artifact (so the History pages have ids), and secrets where a careless
server would serve them: files named as secrets (``sim.env``, ``results.sqlite``, ``id_rsa``,
``.env``, ``rig.yaml``) with the real secrets' bytes in them, in the scans folder, in a scan
folder beside its manifest (and a link from there to ``sim.env``), and in the store's folder.

:class:`Console` is `vts console` as a user runs it, a subprocess on port 0 (the address read
from what it prints), in the rig's folder (so its default ``--scans-dir .`` is the folder of the
secrets and the store), its stderr kept in a file (a traceback there is found by the case that
caused it). :meth:`Console.send` is one HTTP/1.1 request over a socket of its own, the path and
every header exactly as given (no client normalises ``..`` or fills in Host), answered or
``None`` after a deadline (a hang). :meth:`Console.state` is what no refused request may change:
each camera's LED (read from the simulated camera itself), the aim checks, the scan and Daily QA
jobs, the scans folder, the store's runs, outbox and users, and the action log's new entries.
"""

from __future__ import annotations

import json
import os
import re
import socket
import sqlite3
import ssl
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

PY = sys.executable
PASSWORDS = {
    "ann": ("operator", "ann-runs-the-scans-7"),
    "phil": ("physicist", "phil-sets-baselines-9"),
    "carl": ("operator", "carl-fills-the-form-3"),
}
MARKER = "VTS-SWEEP-SECRET-7f3a9c"  # in every planted secret file (id_rsa, .env)
SECRET_NAMES = ("sim.env", "results.sqlite", "id_rsa", ".env", "rig.yaml")
SCAN = "scan-20260101T000000Z"
DEADLINE_S = 60.0  # one answer, on a busy machine: else a hang


def vts(*args, cwd=None, env=None, timeout=300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [PY, "-m", "vts_hw.cli", *map(str, args)], capture_output=True, text=True, cwd=cwd, env=env, timeout=timeout
    )


@dataclass
class Answer:
    status: int
    headers: dict[str, str]
    body: bytes

    def header(self, name: str) -> str:
        return self.headers.get(name.lower(), "")


class PlantedRig:
    """The simulated rig, its store with users and a run, and the planted secrets (see the module)."""

    def __init__(self, root: Path):
        self.root = root
        self.sim = root / "sim"
        p = vts("sim", "up", "--detach", "--qatrack", "--dir", self.sim, timeout=300)
        if p.returncode != 0:
            raise RuntimeError(f"vts sim up failed: {p.stderr.strip()[-300:]}")
        from vts_hw.sim_devices.rig import load_env_file

        # (the console's default scans folder is beside the per-user store: this sweep's own)
        self.env = {**os.environ, **load_env_file(self.sim / "sim.env"), "XDG_DATA_HOME": str(root / "xdg")}
        self.rig_yaml = self.sim / "rig.yaml"
        import yaml

        rig = yaml.safe_load(self.rig_yaml.read_text())
        self.cameras = {c["name"]: c["port"] for c in rig["cameras"]}
        self.store = self.sim / "results.sqlite"
        self._users_and_a_run()
        self.scans = root / "scans"
        self.scans.mkdir(mode=0o700)
        self.plant(self.sim)  # the store's folder (and the folder the console is started in)
        self.secrets = self._secrets()

    def plant(self, folder: Path) -> None:
        """Secrets in ``folder`` and in a scan folder there (beside its manifest, and a link to sim.env):
        done once the console has started (it may refuse to start on a scans folder holding them)."""
        self._plant(folder)
        scan = folder / SCAN
        scan.mkdir(exist_ok=True)
        (scan / "manifest.json").write_text(json.dumps({"status": "finalised", "cameras": ["cam1"]}))
        self._plant(scan)
        if not (scan / "link.env").is_symlink():
            (scan / "link.env").symlink_to(self.sim / "sim.env")

    def _users_and_a_run(self) -> None:
        """The users (as `vts console user add` adds them) and a daily run with a plot."""
        from vts_hw.console.users import add_user
        from vts_hw.store import ResultsStore

        png = self.root / "plot.png"
        png.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 64 + b"IEND\xaeB`\x82")
        with ResultsStore(f"sqlite:///{self.store}") as s:
            for name, (role, pw) in PASSWORDS.items():
                add_user(s, name, role, pw)
            with s.begin_run("daily", rig="sim", started=time.time() - 3600) as h:
                h.measure("cam1", "drift_x_px", 0.1, "px")
                h.artifact(str(png), kind="plot")

    def _plant(self, folder: Path) -> None:
        for name in SECRET_NAMES:
            dst = folder / name
            if dst.exists():
                continue
            if name == "results.sqlite":
                dst.write_bytes(self.store.read_bytes())
            elif name in ("sim.env", "rig.yaml"):
                dst.write_bytes((self.sim / name).read_bytes())
            else:
                dst.write_text(f"-----BEGIN SECRET-----\n{MARKER}\n-----END SECRET-----\n")

    def _secrets(self) -> dict[str, bytes]:
        """What no answer may hold: every password and token of sim.env, the users' password hashes
        (their salt and digest), the marker of the planted files, a SQLite file's header."""
        from vts_hw.sim_devices.rig import load_env_file

        out = {k: v.encode() for k, v in load_env_file(self.sim / "sim.env").items() if "PASSWORD" in k or "TOKEN" in k}
        for name, (_, pw) in PASSWORDS.items():
            out[f"{name}'s password"] = pw.encode()
        con = sqlite3.connect(f"file:{self.store}?mode=ro", uri=True)
        try:
            for name, h in con.execute("SELECT name, password FROM users"):
                out[f"{name}'s password hash"] = h.rsplit("$", 1)[-1].encode()
        finally:
            con.close()
        out["a planted secret file"] = MARKER.encode()
        out["an SQLite file"] = b"SQLite format 3\0"
        return out

    def close(self) -> None:
        vts("sim", "down", "--dir", self.sim, timeout=60)

    # -- what the simulated devices and the store say -------------------------------------
    def led(self, camera: str) -> bool | None:
        try:
            with socket.create_connection(("127.0.0.1", self.cameras[camera]), timeout=10) as s:
                s.sendall(b"GET /sim/state HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n")
                data = b""
                while chunk := s.recv(65536):
                    data += chunk
            return bool(json.loads(data.split(b"\r\n\r\n", 1)[1]).get("led_on"))
        except (OSError, ValueError, IndexError):
            return None

    def streams(self) -> int:
        """The simulated cameras' open streams, all together."""
        total = 0
        for port in self.cameras.values():
            try:
                with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
                    s.sendall(b"GET /sim/state HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n")
                    data = b""
                    while chunk := s.recv(65536):
                        data += chunk
                total += int(json.loads(data.split(b"\r\n\r\n", 1)[1]).get("active_streams", 0))
            except (OSError, ValueError, IndexError):
                pass
        return total

    def store_rows(self) -> dict:
        con = sqlite3.connect(f"file:{self.store}?mode=ro", uri=True, timeout=30)
        try:
            out = {}
            for table in ("runs", "outbox", "users", "artifacts", "measurements"):
                try:
                    out[table] = con.execute(f"SELECT count(*) FROM {table}").fetchone()[0]  # (names of this list)
                except sqlite3.Error:
                    out[table] = None
            try:
                out["actions"] = con.execute("SELECT id, user_name, what, detail FROM actions ORDER BY id").fetchall()
            except sqlite3.Error:
                out["actions"] = []
            return out
        finally:
            con.close()


@dataclass
class Who:
    """Who sends a request: ``local`` (a console without users), ``anon`` (no session), or a user
    logged in (its session cookie and the page token its pages carry)."""

    name: str
    cookie: str = ""
    token: str = ""
    password: str = ""
    extra: dict = field(default_factory=dict)


class Console:
    """`vts console ARGS` in ``cwd``, a subprocess (see the module docstring)."""

    def __init__(self, room: PlantedRig, args: list[str], cwd: Path, label: str):
        self.room, self.label = room, label
        self.scans_dir = Path(args[args.index("--scans-dir") + 1]) if "--scans-dir" in args else cwd
        self.log = room.root / f"console-{label}.stderr"
        self._err = open(self.log, "wb")
        self.proc = subprocess.Popen(
            [PY, "-m", "vts_hw.cli", "console", "--config", str(room.rig_yaml), "--port", "0", *args],
            cwd=cwd,
            env=room.env,
            stdout=subprocess.PIPE,
            stderr=self._err,
            stdin=subprocess.DEVNULL,
        )
        line = self.proc.stdout.readline().decode(errors="replace")
        m = re.search(r"(https?)://127\.0\.0\.1:(\d+)/", line)
        if not m:
            self.proc.wait(30)
            raise RuntimeError(
                f"vts console {' '.join(args)} did not start: {line.strip()} "
                f"{self.log.read_text(errors='replace')[-400:]}"
            )
        self.scheme, self.port = m.group(1), int(m.group(2))
        self.host = f"127.0.0.1:{self.port}"
        self.origin = f"{self.scheme}://{self.host}"
        #: over HTTPS the session cookie is __Host- prefixed (login.py); its certificate is the test's own
        self.cookie_name = "__Host-vts_session" if self.scheme == "https" else "vts_session"
        self._tls = ssl._create_unverified_context() if self.scheme == "https" else None  # nosec B323: a test's own
        self._seen = 0
        if "--scans-dir" not in args:  # its default: as its Scan page says
            a = self.send("GET", "/scan/state")
            try:
                self.scans_dir = Path(json.loads(a.body)["scans"])
            except (AttributeError, ValueError, KeyError, TypeError):
                pass
        self.scans_dir.mkdir(parents=True, exist_ok=True)
        room.plant(self.scans_dir)

    def new_errors(self) -> str:
        """What the console wrote on stderr since the last call."""
        data = self.log.read_bytes()
        new, self._seen = data[self._seen :], len(data)
        return new.decode(errors="replace")

    def stop(self) -> tuple[int | None, str]:
        """Ctrl-C, as a user stops it: (its exit code, None if it did not stop; its stderr tail)."""
        import signal

        self.proc.send_signal(signal.SIGINT)
        try:
            code = self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
            code = None
        self._err.close()
        return code, self.log.read_text(errors="replace")[-400:]

    def _connect(self, timeout: float):
        s = socket.create_connection(("127.0.0.1", self.port), timeout=timeout)
        return self._tls.wrap_socket(s, server_hostname="127.0.0.1") if self._tls is not None else s

    # -- one request -----------------------------------------------------------------------
    def send(
        self,
        method: str,
        path: str,
        *,
        who: Who | None = None,
        headers: dict | None = None,
        body: bytes | None = None,
        ctype: str | None = None,
        stream: bool = False,
        deadline: float = DEADLINE_S,
    ) -> Answer | None:
        """One request, exactly as given; ``who``'s cookie (and, on a POST, this console's Origin and
        ``who``'s token) unless ``headers`` says otherwise (a value None leaves a header out).
        ``stream``: an event stream: the head and its first event only. None: no answer in time."""
        hs: dict[str, str | None] = {
            "Host": self.host,
            "Accept": "text/html,application/json;q=0.9,*/*;q=0.8",
            "Connection": "close",
        }
        if who is not None and who.cookie:
            hs["Cookie"] = f"{self.cookie_name}={who.cookie}"
        if method != "GET":
            hs["Origin"] = self.origin
            if who is not None and who.token:
                hs["X-Console-Token"] = who.token
        if body is not None:
            hs["Content-Type"] = ctype or "application/json"
            hs["Content-Length"] = str(len(body))
        elif method != "GET":
            hs["Content-Length"] = "0"
        for k, v in (headers or {}).items():
            hs = {a: b for a, b in hs.items() if a.lower() != k.lower()}
            hs[k] = v
        head = f"{method} {path} HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in hs.items() if v is not None)
        end = time.monotonic() + deadline
        try:
            with self._connect(deadline) as s:
                data = b""
                try:
                    s.sendall(head.encode("latin-1", errors="replace") + b"\r\n" + (body or b""))
                except (BrokenPipeError, ConnectionResetError):  # answered (and closed) before the body was read
                    data = _drain(s)
                    if not data:
                        raise
                    return _parse(data)
                while time.monotonic() < end:
                    s.settimeout(max(0.1, end - time.monotonic()))
                    try:
                        chunk = s.recv(65536)
                    except ConnectionResetError:
                        if not data:
                            raise
                        break
                    if not chunk:
                        break
                    data += chunk
                    if stream and b"\r\n\r\n" in data and len(data.split(b"\r\n\r\n", 1)[1]) > 0:
                        break  # an event stream: its head and first chunk
                else:
                    return None
        except TimeoutError:
            return None
        except OSError as exc:
            return Answer(0, {}, f"connection failed: {exc}".encode())
        return _parse(data)


def _drain(s) -> bytes:
    data = b""
    try:
        s.settimeout(5)
        while chunk := s.recv(65536):
            data += chunk
    except OSError:
        pass
    return data


def _parse(data: bytes) -> Answer:
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    try:
        status = int(lines[0].split()[1])
    except (IndexError, ValueError):
        return Answer(0, {}, data)
    headers: dict[str, str] = {}
    for line in lines[1:]:
        k, _, v = line.partition(":")
        k = k.strip().lower()
        headers[k] = f"{headers[k]}, {v.strip()}" if k in headers and k == "set-cookie" else v.strip()
    if headers.get("transfer-encoding", "").lower() == "chunked":
        body = _unchunk(body)
    return Answer(status, headers, body)


def _unchunk(body: bytes) -> bytes:
    out, rest = b"", body
    while rest:
        size_line, _, rest = rest.partition(b"\r\n")
        try:
            n = int(size_line.split(b";")[0], 16)
        except ValueError:
            return out + rest
        if n == 0:
            break
        out, rest = out + rest[:n], rest[n + 2 :]
    return out


__all__ = ["PlantedRig", "Console", "Who", "Answer", "SCAN", "SECRET_NAMES", "MARKER"]
