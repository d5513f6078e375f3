"""Who wrote a "running" row, and whether that process is still alive.

A run row records the host name, the pid and a process-start token. On Linux the token is
the boot id plus the process start time (``/proc/<pid>/stat`` field 22, clock ticks since
boot), so a pid reused after the writer died, or a reboot since, is not mistaken for the
writer. Elsewhere the token is empty and only the pid is checked. A zombie counts as dead.

Only runs written on this host can be judged; runs of other hosts (a shared PostgreSQL
server) are left as they are.
"""

from __future__ import annotations

import errno
import os
import socket
from pathlib import Path

_PROC = Path("/proc")


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
    return text[text.rfind(")") + 2:].split()


def process_start(pid: int | None = None) -> str:
    """The start token of a process (default: this one), "" when the platform has none."""
    pid = os.getpid() if pid is None else pid
    boot = _boot_id()
    fields = _stat_fields(pid)
    if not boot or fields is None or len(fields) < 20:
        return ""
    return f"{boot}/{fields[19]}"  # stat field 22 (starttime); fields[0] is field 3


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
