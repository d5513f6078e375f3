"""What the detached simulated rig leaves in its log (sim.log) and how its starter reads it: the
line it writes when it fails, the cause found after a given byte, a full disk."""

from __future__ import annotations

import os
from pathlib import Path

from vts_hw.files import os_reason

FAILED = "simulated rig failed: "  # how the detached process says why it stopped (last line of sim.log)


def failure_cause(log_path: Path, start: int = 0) -> str:
    """Why the detached rig stopped, from what it wrote to sim.log after byte ``start``: the
    line it writes when it fails (``FAILED``), else the last line that is not part of a
    traceback's listing."""
    try:
        with open(log_path, "rb") as f:
            f.seek(start)
            lines = [ln.rstrip() for ln in f.read().decode("utf-8", "replace").splitlines() if ln.strip()]
    except OSError as e:
        return f"its log cannot be read ({os_reason(e)})"
    for line in reversed(lines):
        if line.startswith(FAILED):
            return line[len(FAILED) :]
    plain = [ln for ln in lines if not ln.startswith((" ", "\t", "Traceback"))]
    if plain:
        return plain[-1]
    return NOTHING_LOGGED


NOTHING_LOGGED = "it wrote nothing to its log (was it killed, or is the disk full?)"


def disk_full(folder: Path) -> bool:
    try:
        return os.statvfs(folder).f_bavail == 0
    except OSError:
        return False


def one_line(exc: BaseException) -> str:
    """An unexpected exception in one line: its type, the first line of its message and, when
    the message goes on (a build's output), its last line."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    if not lines:
        return type(exc).__name__
    text = lines[0].rstrip(":")
    if len(lines) > 1:
        text += f": {lines[-1]}"
    return f"{type(exc).__name__}: {text}"
