"""Processes: which one wrote something and whether it still runs, and no process outliving
the command that started it, however that command ends (``kill -9`` included).

* **Who, and is it alive.** :func:`process_record` names this process as a writer records it
  (host, pid and a start token); :func:`is_alive` tells, from such a record, whether that very
  process still runs. On Linux the token is the boot id plus the process start time
  (``/proc/<pid>/stat`` field 22, clock ticks since boot), so a pid reused after the writer
  died, or a reboot since, is not mistaken for the writer; elsewhere the token is empty and only
  the pid is checked. A zombie counts as dead. Only a process of this host can be judged. The
  results store's "running" run rows and the recordings' manifests use it
  (docs/decisions/0082-killed-is-not-finished.md).
* **Workers** (:func:`die_with`, first thing in a pool's worker): killed when their parent dies
  (``prctl(PR_SET_PDEATHSIG)``); the parent of a fork-server worker is the fork server, which
  itself ends when the command does. As a fallback (another system, or a parent that is not the
  command), a daemon thread watches the command's pid and ends the worker within a second of
  it going. docs/decisions/0053-slow-peers-endless-files-signals.md.
* **Programs started** (avrdude, make, the firmware emulator, an alert command):
  ``subprocess.Popen(cmd, **child_options())`` asks the kernel to signal the child when the
  thread that started it ends, the command's own end included (``kill -9``): so a program is
  started from a thread that lives as long as the program should (the command's main thread).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import signal
import socket
import sys
import threading
from pathlib import Path

PR_SET_PDEATHSIG = 1
WATCH_EVERY_S = 0.5
_PROC = Path("/proc")


# -- who, and is it alive ------------------------------------------------------------------------
def host_name() -> str:
    return socket.gethostname()


def _boot_id() -> str:
    try:
        return (_PROC / "sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def _stat_fields(pid: int) -> list[str] | None:
    """Fields of /proc/<pid>/stat after the command name (index 0 is the state), or None."""
    try:
        text = (_PROC / str(pid) / "stat").read_text()
    except OSError:
        return None
    # the command name is in parentheses and may itself hold spaces or parentheses
    return text[text.rfind(")") + 2 :].split()


def process_start(pid: int | None = None) -> str:
    """The start token of a process (default: this one), "" when the platform has none."""
    pid = os.getpid() if pid is None else pid
    boot = _boot_id()
    fields = _stat_fields(pid)
    if not boot or fields is None or len(fields) < 20:
        return ""
    return f"{boot}/{fields[19]}"  # stat field 22 (starttime); fields[0] is field 3


def process_record() -> dict:
    """This process as a writer names itself: ``{"host", "pid", "process"}`` (the start token)."""
    return {"host": host_name(), "pid": os.getpid(), "process": process_start()}


def is_alive(pid: int | None, token: str) -> bool | None:
    """True/False for a process on this host, None when it cannot be told (no pid, no way to check)."""
    if pid is None or pid <= 0:
        return None
    boot, sep, start = token.partition("/")
    if sep:
        now_boot = _boot_id()
        if now_boot and now_boot != boot:
            return False  # rebooted since: every process of that boot is gone
    fields = _stat_fields(pid)
    if fields is not None:
        if fields[0] in ("Z", "X"):
            return False  # zombie or dead, waiting to be reaped
        if sep and len(fields) > 19 and fields[19] != start:
            return False  # the pid now belongs to another process
        return True
    if (_PROC / "self").exists():
        return False  # /proc works and has no entry for the pid: gone
    return _signal_alive(pid)


def _signal_alive(pid: int) -> bool | None:
    if os.name != "posix":
        return None  # os.kill(pid, 0) would terminate the process on Windows
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # exists, owned by someone else
    except OSError as exc:
        return False if exc.errno == errno.ESRCH else None
    return True


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not yet reaped, does not); True when it cannot be told."""
    return is_alive(pid, "") is not False


# -- dying with the command ----------------------------------------------------------------------
def _prctl():
    """libc's prctl (Linux), or None."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(None, use_errno=True).prctl
    except (OSError, AttributeError):
        return None


def die_with(command_pid: int) -> None:
    """End this process when its parent, or the process ``command_pid``, ends."""
    parent = os.getppid()
    prctl = _prctl()
    if prctl is not None:
        prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent or not alive(command_pid):  # gone before the request took
        os._exit(1)

    def watch() -> None:
        while True:
            threading.Event().wait(WATCH_EVERY_S)
            if os.getppid() != parent or not alive(command_pid):
                os._exit(1)

    threading.Thread(target=watch, name="lifeline", daemon=True).start()


def child_options(sig: int = signal.SIGKILL) -> dict:
    """Keyword arguments for ``subprocess.Popen``/``run``: the program started gets ``sig``
    (SIGKILL; SIGTERM for one that cleans up after itself quickly) when the thread starting it
    ends, whatever ends it. Start it from a thread that lives as long as the program should.
    No option on a system without ``prctl``."""
    prctl = _prctl()  # looked up here: the child only calls it (no lookup after the fork)
    if prctl is None:
        return {}
    parent = os.getpid()

    def in_child() -> None:
        prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        if os.getppid() != parent:  # the command ended between the fork and the request
            os._exit(1)

    return {"preexec_fn": in_child}


@contextlib.contextmanager
def interrupts_deferred():
    """Ctrl-C and SIGTERM (which the CLI makes an interrupt too) held back for the block, then
    delivered at its end: for a block that must not be cut in the middle (a process pool
    starting its workers: one cut between the fork server's fork and the pool noting the worker
    leaves that worker unwaited-for, and it dies with a traceback when the pool's queues are
    gone). Outside the main thread, nothing is changed."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got: list[int] = []
    held = (signal.SIGINT, signal.SIGTERM)
    old = {s: signal.signal(s, lambda signum, frame: got.append(signum)) for s in held}
    try:
        yield
    finally:
        for s in held:
            signal.signal(s, old[s])
    for s in dict.fromkeys(got):  # each signal held back, once, as it would have come
        if callable(old[s]):
            old[s](s, None)
        elif old[s] == signal.SIG_DFL:  # the default: end as the signal would have ended it
            os.kill(os.getpid(), s)
