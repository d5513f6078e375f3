"""The class "killed" of bench/bad_inputs.py (issue 21 round 2, issue 32 §3 and §5): SIGINT,
SIGTERM and SIGKILL to every long command and to the console while a job of its pages runs, at
several moments, and what is left afterwards.

Each long command runs in a forked child as a background job of a script would: with SIGINT
ignored at the start (a non-interactive shell's ``cmd &``), in a session of its own, and with
:data:`MARK` in its environment (every process it starts inherits it, even one that leaves its
session). It gets its signal at one :data:`MOMENTS`: ``starting`` (half a second in), ``under
way`` (its first frames on disk, its workers or avrdude started, the console's job running), or
``later`` (under way, then 3 s more). Afterwards, judged by state (never by how long it took):

* **running**: no process carrying its mark, none of its session, may outlive it
  (:data:`ORPHAN_WAIT_S` for them to go; then they are killed and reported);
* **on disk**: every recording folder it left is read by the readers users have (`vts recording
  info`): exit 0 on a folder whose writer was killed is a false OK (it claims a finished
  recording); after SIGINT the manifest says ``interrupted``; every frame the index lists is
  whole in its .mjpeg. A store it wrote holds no verdict of a run it was killed in, and a run it
  began is there (a killed commissioning leaves its row, not nothing);
* **switched on**: a case with a rig of its own (simulated cameras and a trigger box, its firmware
  in the emulator) has the square wave off once the host is gone (the box's output pin stops
  toggling: read from the emulator's log of pin edges, and confirmed by asking it ``OUTP?``,
  within :data:`WAVE_OFF_S`), and each camera's LED as it was before the case (read from the
  simulated camera; on the rig the other cases share, others switch them) where the command's
  own end leaves it so (a scan leaves the LED ring on: the markers are retro-reflective);
* **exit**: SIGINT: 130 saying ``interrupted`` (or 0 where Ctrl-C is the way a command ends);
  SIGTERM: 130 or 143, or killed by it; no traceback.

:func:`badkit.forked.fork_vts` is the runner (the sweep's own), with its hook before ``main``
(SIGINT ignored, the mark set) and its hook while the command runs (the signal).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import socket
import sys
import time
from pathlib import Path

from badkit.classes import Case, Verdict, common
from badkit.forked import FORK_LOCK, fork_vts

CLASS = "killed"
KINDS = ("SIGINT", "SIGTERM", "SIGKILL")
MOMENTS = ("starting", "under way", "later")
AFTER_SIGNAL_S = 60.0  # how long a command may take to stop after SIGINT or SIGTERM
ORPHAN_WAIT_S = 20.0  # how long its processes may take to go after it ended
WAVE_OFF_S = 90.0  # how long the trigger box may keep its square wave on after its host died
QUIET_S = 3.0  # no edge on the wave's pin for this long (wall clock): it is off
MARK = "VTS_SWEEP_KILLED_CASE"
VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


# -- what is running -------------------------------------------------------------------------------


def session_members(sid: int) -> list[int]:
    """Live processes of session ``sid`` (the child's own session: its workers, fork servers)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if fields[0] != "Z" and int(fields[3]) == sid:
            out.append(int(d.name))
    return out


def marked(tag: str) -> list[int]:
    """Live processes whose environment holds ``MARK=tag`` (inherited from the case's command)."""
    needle = f"{MARK}={tag}\0".encode()
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            if needle in (d / "environ").read_bytes() and _state(int(d.name)) not in ("Z", "X"):
                out.append(int(d.name))
        except OSError:
            continue
    return out


def _descendants(pid: int) -> list[int]:
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                kids.setdefault(int((d / "stat").read_text().rsplit(")", 1)[1].split()[1]), []).append(int(d.name))
            except (OSError, IndexError, ValueError):
                pass
    out, todo = [], [pid]
    while todo:
        for k in kids.get(todo.pop(), []):
            out.append(k)
            todo.append(k)
    return out


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "X"


def _comm(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return "?"


def _before(tag: str, env: dict | None = None):
    def hook() -> None:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # as `cmd &` in a script starts it
        os.environ.update(env or {})  # a rig of the case's own: its passwords
        os.environ[MARK] = tag

    return hook


class _Signaller:
    """``during``: wait for the moment (``ready(wd, pid)``, then ``extra_s``; or ``wait_s``), send
    ``signum``; then note what of it is left running once it has ended."""

    def __init__(
        self, wd: Path, signum: int, ready, wait_s: float, extra_s: float, tag: str, moment: str = "", job_ended=None
    ):
        self.wd, self.signum, self.ready, self.wait_s, self.extra_s, self.tag = wd, signum, ready, wait_s, extra_s, tag
        self.moment, self._job_ended = moment, job_ended
        self.sent_after: float | None = None
        self.ended_first = False
        self.job_ended = False  # (a console's job ended before the signal: what it stored is its own)
        self.left: list[str] = []

    def __call__(self, pid: int) -> None:
        t0 = time.monotonic()
        while time.monotonic() - t0 < self.wait_s:
            with FORK_LOCK:  # a readiness check may read a store (SQLite): never across a fork
                if self.ready(self.wd, pid):
                    break
            if not Path(f"/proc/{pid}").exists() or _state(pid) == "Z":
                self.ended_first = True
                return
            time.sleep(0.05)
        end = time.monotonic() + self.extra_s
        while time.monotonic() < end and _state(pid) not in ("Z", "X"):
            time.sleep(0.05)
        if _state(pid) in ("Z", "X"):
            self.ended_first = True
            return
        self.sent_after = time.monotonic() - t0
        self.job_ended = bool(self._job_ended and self._job_ended(self.wd, pid))
        try:
            os.kill(pid, self.signum)
        except ProcessLookupError:
            self.ended_first = True
            return
        # what is left of it once it has ended (its pipes may be held open by orphans: look now)
        end = time.monotonic() + AFTER_SIGNAL_S
        while _state(pid) not in ("Z", "X") and time.monotonic() < end:
            time.sleep(0.05)
        if _state(pid) not in ("Z", "X"):
            return  # still running: the runner's time limit says so
        end = time.monotonic() + ORPHAN_WAIT_S
        left = self._left(pid)
        while left and time.monotonic() < end:
            time.sleep(0.2)
            left = self._left(pid)
        self.left = [f"{p} {_comm(p)}" for p in left]
        for p in left:  # never leave them running
            try:
                os.kill(p, signal.SIGKILL)
            except OSError:
                pass

    def _left(self, pid: int) -> list[int]:
        return sorted({p for p in session_members(pid) + marked(self.tag) if p != pid})


# -- when it is under way --------------------------------------------------------------------------


def _frames_on_disk(wd: Path, pid: int) -> bool:
    return any(p.stat().st_size > 100_000 for p in wd.rglob("*.mjpeg"))


def _workers_up(wd: Path, pid: int) -> bool:
    return len(_descendants(pid)) >= 2


def _runs(name: str):
    def ready(wd: Path, pid: int) -> bool:
        return any(_comm(p) == name for p in _descendants(pid))

    return ready


def _file(rel: str):
    return lambda wd, pid: (wd / rel).exists()


def _after(seconds: float):
    """A readiness test true ``seconds`` after it is first asked (a factory: one per case)."""

    def factory():
        t = {}

        def ready(wd, pid):
            t.setdefault("t0", time.monotonic())
            return time.monotonic() - t["t0"] >= seconds

        return ready

    return factory


def _always(test):
    return lambda: test


# -- what is switched on ---------------------------------------------------------------------------


class Box:
    """A rig of the case's own: simulated cameras (`vts sim up --detach` in its folder: their LEDs
    are this case's alone) and a trigger box (its firmware in the emulator), in a rig.yaml."""

    def __init__(self, wd: Path):
        self.wd, self.box, self.env = wd, None, {}
        self.config = wd / "rig-box.yaml"  # written by start()

    def start(self) -> None:
        """Started when the case runs (not when it is planned): the cameras, the box, rig-box.yaml."""
        import subprocess

        import yaml

        from vts_hw.sim_devices.rig import load_env_file
        from vts_hw.sim_devices.trigger_box import SimTriggerBox

        p = subprocess.run(
            [sys.executable, "-m", "vts_hw.cli", "sim", "up", "--detach", "--dir", str(self.wd / "sim")],
            capture_output=True,
            text=True,
            timeout=300,
        )
        if p.returncode != 0:
            raise RuntimeError(f"vts sim up: {p.stderr.strip()[-200:]}")
        self.env = load_env_file(self.wd / "sim" / "sim.env")
        self.box = SimTriggerBox(workdir=self.wd / "box").start()
        rig = yaml.safe_load((self.wd / "sim" / "rig.yaml").read_text())
        rig["trigger"] = {"backend": "triggerbox", "address": self.box.port}
        self.config.write_text(yaml.safe_dump(rig))

    def wave_left_on(self) -> str:
        """'' when the square wave is off (or was never on), else what is wrong. The output pin
        must stop toggling within WAVE_OFF_S; then the box is asked (OUTP?)."""
        if self.box is None or not self.box.edges("OC1A"):
            return ""
        end = time.monotonic() + WAVE_OFF_S
        n, quiet_since = len(self.box.edges("OC1A")), time.monotonic()
        while time.monotonic() < end:
            time.sleep(0.5)
            m = len(self.box.edges("OC1A"))
            if m != n:
                n, quiet_since = m, time.monotonic()
            elif time.monotonic() - quiet_since >= max(QUIET_S, 3 * self._period()):
                said = self.ask("OUTP?")
                return "" if not re.search(r"\b(1|ON)\b", said) else f"the box says its output is on ({said})"
        return f"the trigger box's square wave still on {WAVE_OFF_S:.0f} s after its host was gone"

    def _period(self) -> float:
        """The square wave's half period (emulated seconds between its last edges)."""
        from vts_hw.sim_devices.trigger_box import F_CPU

        e = self.box.edges("OC1A")[-6:]
        gaps = sorted(b.cycle - a.cycle for a, b in zip(e, e[1:]))
        return gaps[len(gaps) // 2] / F_CPU if gaps else 0.0

    def ask(self, what: str) -> str:
        import serial

        try:
            with serial.Serial(self.box.port, 115200, timeout=2) as s:
                s.write(what.encode() + b"\n")
                return s.readline().decode(errors="replace").strip()
        except (OSError, serial.SerialException) as exc:
            return f"(not asked: {exc})"

    def stop(self) -> None:
        import subprocess

        if self.box is not None:
            self.box.stop()
        subprocess.run(
            [sys.executable, "-m", "vts_hw.cli", "sim", "down", "--dir", str(self.wd / "sim")],
            capture_output=True,
            timeout=60,
        )


def leds(config: Path) -> dict[str, bool | None]:
    """Each simulated camera's LED, read from the camera itself (/sim/state)."""
    import yaml

    out = {}
    for cam in yaml.safe_load(config.read_text()).get("cameras", []):
        try:
            with socket.create_connection(("127.0.0.1", cam["port"]), timeout=10) as s:
                s.sendall(b"GET /sim/state HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n")
                data = b""
                while chunk := s.recv(65536):
                    data += chunk
            out[cam["name"]] = bool(json.loads(data.split(b"\r\n\r\n", 1)[1]).get("led_on"))
        except (OSError, ValueError, IndexError, KeyError):
            out[cam["name"]] = None
    return out


# -- what is on disk ---------------------------------------------------------------------------------


def _recording_whole(folder: Path) -> str:
    """'' when every frame each index lists is whole in its .mjpeg, else what is wrong."""
    from vts_hw.recording.folder import read_index
    from vts_hw.recording.mjpeg import split_jpegs

    problems = []
    for idx in folder.glob("*.index.csv"):
        mj = folder / idx.name.replace(".index.csv", ".mjpeg")
        try:
            rows = read_index(idx, lenient=True)
        except Exception as exc:  # noqa: BLE001 -- judged, not raised
            problems.append(f"{idx.name}: {exc}")
            continue
        data = mj.read_bytes() if mj.exists() else b""
        whole = {(s.offset, s.length) for s in split_jpegs(data) if s.complete}
        bad = [r.frame for r in rows if (r.offset, r.length) not in whole]
        if bad:
            problems.append(f"{idx.name}: {len(bad)} indexed frame(s) not whole in {mj.name}")
    return "; ".join(problems)


def _recordings(wd: Path) -> list[Path]:
    return sorted({p.parent for p in wd.rglob("manifest.json") if "box" not in p.parts})


def _read_as_users_do(folder: Path, kind: str) -> str:
    """'' when `vts recording info` reads a killed recording as unfinished, else what it claims."""
    code, out, err = fork_vts(["recording", "info", str(folder)], 120, folder.parent / f".info-{folder.name}")
    said = (out + err).lower()
    if code is None:
        return f"vts recording info {folder.name} did not answer"
    if "Traceback (most recent call last)" in err:
        return f"vts recording info {folder.name}: a traceback"
    if code == 0 and kind != "SIGINT":
        return f"vts recording info {folder.name} exits 0 on a recording whose writer was killed ({kind})"
    if kind != "SIGINT" and "interrupted" not in said:
        return f"vts recording info {folder.name} does not say interrupted (exit {code})"
    return ""


VERDICTS = ("OK", "TOLERANCE", "ACTION")


def _store_after(wd: Path, procedure: str, must_have_row: bool, judge_verdicts: bool) -> str:
    """'' when the case's store holds no verdict of a run it was killed in and, ``must_have_row``,
    the run it began is there."""
    db = wd / "own.sqlite"
    if not db.exists():
        return f"no store left: the {procedure} run it began is nowhere" if must_have_row else ""
    import sqlite3

    con = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        rows = con.execute("SELECT procedure, status FROM runs WHERE procedure LIKE ?", (f"%{procedure}%",)).fetchall()
    except sqlite3.OperationalError as exc:
        if "no such table" not in str(exc):
            return f"the store could not be read ({exc})"
        rows = []  # killed before the store had its tables: nothing claimed
    finally:
        con.close()
    ours = [r for r in rows if r not in _BASE_ROWS.get(str(db), [])]
    if must_have_row and not ours:
        return f"the store holds no row of the {procedure} run it was killed in"
    verdicts = [r[1] for r in ours if r[1] in VERDICTS]
    if verdicts and judge_verdicts:
        return f"the store holds a verdict ({', '.join(verdicts)}) of the {procedure} run it was killed in"
    return ""


_BASE_ROWS: dict[str, list] = {}


# -- the judge ----------------------------------------------------------------------------------------


def _judge(
    kind: str, holder: dict, ends, procedure: str | None, must_have_row: bool, what: str = "", leds_kept: bool = True
):
    def judge(wd: Path, code, out, err) -> Verdict:
        signaller: _Signaller = holder["signaller"]
        box: Box | None = holder.get("box")
        try:
            v = _verdict(wd, code, err, kind, signaller, ends)
            if not signaller.ended_first:
                orderly = kind == "SIGINT" or (kind == "SIGTERM" and code in (0, 130, 143))
                for folder in _recordings(wd):
                    wrong = _recording_whole(folder)
                    if wrong:
                        v.damaged, v.why = True, wrong
                    said = _read_as_users_do(folder, "SIGINT" if orderly else kind)
                    if said:
                        v.false_ok, v.why = True, said
                    manifest = folder / "manifest.json"
                    if orderly and manifest.exists():
                        try:
                            m = json.loads(manifest.read_text())
                        except ValueError:
                            m = {}
                        told = {m.get("status"), (m.get("scan") or {}).get("stop_reason"), m.get("stop_reason")}
                        if "interrupted" not in told:
                            v.other, v.why = True, f"the manifest says {m.get('status')!r} after {kind} (exit {code})"
                if procedure:
                    # a run begun is there once under way (not half a second in); a commissioning's steps
                    # done before the kill keep their verdicts; a job that had ended before it, too
                    wrong = _store_after(
                        wd,
                        procedure,
                        must_have_row and kind != "SIGINT" and signaller.moment != "starting",
                        not must_have_row and not signaller.job_ended,
                    )
                    if wrong:
                        v.false_ok, v.why = True, wrong
            if box is not None:
                on = box.wave_left_on()
                if os.environ.get("BAD_INPUTS_DEBUG"):
                    Path(os.environ["BAD_INPUTS_DEBUG"], f"{kind}-{what}.edges").write_text(
                        f"{len(box.box.edges('OC1A'))} OC1A edges; said {on!r}; "
                        f"{[round(e.cycle / 16e6, 3) for e in box.box.edges()][-30:]} {box.box.edges()[-3:]}\n"
                    )
                if on:
                    v.other, v.why = True, on
            if "leds" in holder and leds_kept:
                now = leds(holder["config"])
                if now != holder["leds"]:
                    v.other, v.why = True, f"the LEDs were {holder['leds']}, now {now}"
            return v
        finally:
            if box is not None:
                box.stop()

    return judge


def _verdict(wd, code, err, kind, s: _Signaller, ends) -> Verdict:
    if s.ended_first:
        v = common(code, err)
        v.why = v.why or "ended before the signal (nothing to judge)"
        return v
    last = (err.strip().splitlines() or [""])[-1]
    if kind == "SIGKILL":
        v = Verdict() if code == -signal.SIGKILL else common(code, err)
    else:
        allowed = set(ends) | ({130, 143, -signal.SIGTERM} if kind == "SIGTERM" else set())
        v = common(code, err)
        if v.hang or v.traceback:
            pass
        elif code not in allowed:
            v = Verdict(
                other=True, why=f"exit {code} after {kind}, not {' or '.join(map(str, sorted(allowed)))}: {last}"
            )
        else:
            v = Verdict()  # (130 is no exit of common()'s: here it is the one expected)
            if code == 130 and "interrupted" not in err:
                v.other, v.why = True, f"exit 130 after {kind} without saying 'interrupted'"
    if s.left:
        v.other, v.why = True, f"{len(s.left)} process(es) left running after {kind} of the command: {s.left[:4]}"
    return v


def _case(
    what: str,
    argv_of,
    kind: str,
    moment: str,
    ready,
    wait_s: float,
    *,
    ends=frozenset({130}),
    box: bool = False,
    procedure: str | None = None,
    must_have_row: bool = False,
    config=None,
    during=None,
    job_ended=None,
    leds_kept: bool = True,
) -> Case:
    signum = getattr(signal, kind)
    holder: dict = {}
    tag = f"{os.getpid()}-{abs(hash((what, kind, moment))) % 10**9}"

    def make(wd: Path) -> list[str]:
        rd = ready() if moment != "starting" else (lambda wd, pid: True)
        extra = {"starting": 0.5, "under way": 0.0, "later": 3.0}[moment]
        holder["signaller"] = _Signaller(wd, signum, rd, wait_s, extra, tag, moment, job_ended)
        cfg = config
        if box:
            holder["box"] = b = Box(wd)
            cfg = b.config
        if wd.joinpath("own.sqlite").exists():
            import sqlite3

            con = sqlite3.connect(wd / "own.sqlite")
            _BASE_ROWS[str(wd / "own.sqlite")] = con.execute("SELECT procedure, status FROM runs").fetchall()
            con.close()
        return argv_of(wd, cfg)

    def run(argv, timeout, wd):
        if "box" in holder:
            try:
                holder["box"].start()
            except Exception as exc:  # noqa: BLE001 -- the case says why it could not run
                return 2, "", f"vts: (sweep) the trigger box emulator did not start: {exc}"
        if "box" in holder:  # the LEDs of its own cameras (those of a shared rig others switch)
            holder["config"] = holder["box"].config
            holder["leds"] = leds(holder["config"])
        s = holder["signaller"]
        hook = s if during is None else (lambda pid: during(wd, pid, s))
        return fork_vts(
            argv, timeout, wd, before=_before(tag, holder["box"].env if "box" in holder else None), during=hook
        )

    def judge(wd, code, out, err):
        if os.environ.get("BAD_INPUTS_DEBUG"):
            Path(os.environ["BAD_INPUTS_DEBUG"], f"{kind}-{what}.err").write_text(err)
        return _judge(kind, holder, ends, procedure, must_have_row, what, leds_kept)(wd, code, out, err)

    return Case(CLASS, f"{kind} {moment}: {what}", make, judge, extra={"run": run})


# -- the console and its pages' jobs ----------------------------------------------------------------


def listening_port(pid: int, deadline: float) -> int | None:
    """The TCP port process ``pid`` listens on (a console started with --port 0: no port picked ahead
    for it that another process could take meanwhile), read from /proc; None if it never listens."""
    while time.monotonic() < deadline and _state(pid) not in ("Z", "X"):
        inodes = set()
        try:
            for fd in os.listdir(f"/proc/{pid}/fd"):
                try:
                    link = os.readlink(f"/proc/{pid}/fd/{fd}")
                except OSError:
                    continue
                if link.startswith("socket:["):
                    inodes.add(link[8:-1])
            for table in ("tcp", "tcp6"):
                for line in Path(f"/proc/{pid}/net/{table}").read_text().splitlines()[1:]:
                    f = line.split()
                    if f[3] == "0A" and f[9] in inodes:  # LISTEN
                        return int(f[1].rsplit(":", 1)[1], 16)
        except OSError:
            pass
        time.sleep(0.2)
    return None


def _http(port: int, method: str, path: str, body: bytes = b"", token: str = "") -> tuple[int, bytes]:
    head = (
        f"{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n"
        f"Origin: http://127.0.0.1:{port}\r\nContent-Type: application/json\r\n"
        f"Content-Length: {len(body)}\r\n" + (f"X-Console-Token: {token}\r\n" if token else "") + "\r\n"
    )
    with socket.create_connection(("127.0.0.1", port), timeout=30) as s:
        s.sendall(head.encode() + body)
        data = b""
        while chunk := s.recv(65536):
            data += chunk
    status = int(data.split(b" ", 2)[1])
    return status, data.split(b"\r\n\r\n", 1)[-1]


def _console_job(job: str):
    """``during`` of a console case: wait for the console to answer, start ``job`` (a Scan-page
    scan, a Daily QA) from its page as the person at the console would, then the signaller (whose
    readiness is the job under way)."""

    def during(wd: Path, pid: int, signaller: _Signaller) -> None:
        port = listening_port(pid, time.monotonic() + 120) or 0
        (wd / ".port").write_text(str(port))
        end = time.monotonic() + 120
        token = ""
        while time.monotonic() < end and _state(pid) not in ("Z", "X"):
            try:
                status, body = _http(port, "GET", "/")
                m = re.search(rb'name="console-token" content="([^"]+)"', body)
                if status == 200 and m:
                    token = m.group(1).decode()
                    break
            except OSError:
                pass
            time.sleep(0.3)
        if token:
            try:
                if job == "scan":
                    _http(port, "POST", "/scan/start", b'{"duration_s": 60}', token)
                else:
                    _http(port, "POST", "/qa/run", b'{"frames": 30}', token)
            except OSError:
                pass
        signaller(pid)

    return during


def _qa_ended(wd: Path, pid: int) -> bool:
    """The console's Daily QA job is over (done or failed), as /qa/state says."""
    try:
        status, body = _http(int((wd / ".port").read_text()), "GET", "/qa/state")
        job = json.loads(body)
        job = job.get("job", job)
        return status == 200 and job.get("state") not in ("running", None)
    except (OSError, ValueError, IndexError, AttributeError):
        return False


def _qa_running(wd: Path, pid: int) -> bool:
    try:
        port = int((wd / ".port").read_text())
        status, body = _http(port, "GET", "/qa/state")
        return status == 200 and b'"running"' in body and b'"taken":0' not in body.replace(b" ", b"")
    except (OSError, ValueError, IndexError):
        return False


# -- every long command ---------------------------------------------------------------------------------


def cases(inp, only: str | None = None, full: bool = False) -> list[Case]:
    """Every long command with each signal at each moment (``full``), or each command once, the
    signals and moments taken in turn (make test's share: SIGTERM and SIGKILL under way first).
    ``inp``: badkit.full_disk's inputs (a simulated rig, a recording, its cameras, a store)."""
    cfg = str(inp.config)
    rec, cams = str(inp.session), str(inp.cameras)
    fw = Path(__file__).resolve().parents[2] / "firmware" / "build" / "trigger_box.hex"
    own = lambda wd: ["--store", f"sqlite:///{wd / 'own.sqlite'}"]  # noqa: E731

    def with_baseline(wd: Path) -> list[str]:
        shutil.copy(inp.baseline_store(), wd / "own.sqlite")
        return own(wd)

    def silent_port(wd: Path) -> str:
        """A serial port nobody answers on (a pty whose other end this process holds): avrdude waits
        there for a bootloader, as at a board without one."""
        master, slave = os.openpty()
        _HELD.append(master)
        name = os.ttyname(slave)
        os.close(slave)
        return name

    def console_argv(job):
        def argv(wd: Path, c) -> list[str]:
            (wd / ".port").write_text("0")  # (its port, once it listens: during())
            (wd / "scans").mkdir(mode=0o700, exist_ok=True)
            return [*with_baseline(wd), "console", "--config", str(c), "--port", "0", "--scans-dir", str(wd / "scans")]

        return argv

    # name: (argv(wd, config), when it is under way, how long to wait for that, the exits a SIGINT may
    # end it with, options: box (a trigger box of its own), procedure (its store row), the config)
    long = {
        "scan start": (
            lambda wd, c: [
                "scan",
                "start",
                "--no-live",
                "--duration",
                "60",
                "-o",
                str(wd / "scan"),
                "--config",
                str(c),
            ],
            _always(_frames_on_disk),
            60,
            {0, 130},
            dict(box=True, leds_kept=False),
        ),
        "camera record": (
            lambda wd, c: [
                "camera",
                "record",
                "cam1",
                "cam2",
                "--seconds",
                "60",
                "-o",
                str(wd / "rec"),
                "--config",
                str(c),
            ],
            _always(_frames_on_disk),
            60,
            {130},
            {},
        ),
        "camera stream": (lambda wd, c: ["camera", "stream", "cam1", "--config", str(c)], _after(3), 30, {0, 130}, {}),
        "qa daily": (
            lambda wd, c: [*with_baseline(wd), "qa", "daily", "--frames", "50", "--config", str(c)],
            _after(3),
            30,
            {130},
            dict(procedure="daily"),
        ),
        "motion analyze": (
            lambda wd, c: [
                "motion",
                "analyze",
                rec,
                "--calibration",
                cams,
                "--config",
                str(c),
                "--workers",
                "2",
                "-o",
                str(wd / "r.html"),
            ],
            _always(_workers_up),
            60,
            {130},
            {},
        ),
        "recording process": (
            lambda wd, c: [
                "recording",
                "process",
                rec,
                "--calibration",
                cams,
                "--config",
                str(c),
                "-o",
                str(wd / "tracks"),
                "--workers",
                "2",
            ],
            _always(_workers_up),
            60,
            {130},
            {},
        ),
        "calibrate stereo": (
            lambda wd, c: ["calibrate", "stereo", "--sim", "--sim-poses", "60", "-o", str(wd / "calib.json")],
            _after(3),
            20,
            {130},
            dict(config=None),
        ),
        "commission": (
            lambda wd, c: [
                *own(wd),
                "commission",
                "--config",
                str(c),
                "--listen",
                "0.2",
                "--skip",
                "trigger",
                "--why",
                "the sweep's rig has no trigger box",
            ],
            _after(4),
            30,
            {130},
            dict(procedure="commission", must_have_row=True),
        ),
        "trigger flash": (
            lambda wd, c: ["trigger", "flash", "--port", silent_port(wd), "--hex", str(fw), "--attempts", "10"],
            _always(_runs("avrdude")),
            30,
            {130},
            dict(config=None),
        ),
        "sim up": (
            lambda wd, c: ["sim", "up", "--dir", str(wd / "sim"), "--trigger", "triggerbox"],
            _always(_file("sim/rig.yaml")),
            90,
            {0, 130},
            dict(config=None),
        ),
        "console, a Scan-page scan": (
            console_argv("scan"),
            _always(_frames_on_disk),
            90,
            {0, 130},
            dict(box=True, during=_console_job("scan"), leds_kept=False),
        ),
        "console, a Daily QA": (
            console_argv("qa"),
            _always(_qa_running),
            90,
            {0, 130},
            dict(procedure="daily", during=_console_job("qa"), job_ended=_qa_ended),
        ),
    }
    out = []
    for i, (name, (argv_of, ready, wait_s, ends, opts)) in enumerate(long.items()):
        if only and not name.startswith(only):
            continue
        config = opts.pop("config", cfg)
        combos = [(k, m) for k in KINDS for m in MOMENTS] if full else [(("SIGKILL", "SIGTERM")[i % 2], "under way")]
        for kind, moment in combos:
            out.append(_case(name, argv_of, kind, moment, ready, wait_s, ends=frozenset(ends), config=config, **opts))
    return out


_HELD: list[int] = []  # the silent ports' other ends, held while the sweep runs


__all__ = ["CLASS", "cases", "fork_vts", "session_members", "marked"]
