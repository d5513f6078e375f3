"""How bench/bad_inputs.py runs one case: `vts ARGV` in a forked child of the sweep's process
(the CLI imported once, before the fork), in a folder and a session of its own, with a time
limit; a hook runs in the child before ``main`` (note the stores it opens, ignore SIGINT, cap
its memory) and one in the parent while it runs (send it a signal)."""

from __future__ import annotations

import io
import os
import select
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from pathlib import Path

#: Held around each fork, and by this process's threads while they call into a C library that has
#: locks of its own (SQLite: a judge reading a case's store, a readiness check): a child forked
#: while another thread held SQLite's mutex inherits it held, and its first store call waits for
#: ever (found: `store init` and `report rooms` on a full disk "hung" in 1 sweep of 3, never alone).
FORK_LOCK = threading.RLock()  # (a judge may itself fork a reader: `vts recording info`)


def fork_vts(
    argv: list[str],
    timeout: float,
    workdir: Path,
    before: Callable[[], None] | None = None,
    during: Callable[[int], None] | None = None,
) -> tuple[int | None, str, str]:
    """`vts ARGV` in a forked child in its own session (``before()`` run in the child first);
    ``during(pid)`` runs in the parent while it does (it may signal it). (exit code, or None
    when it outlived ``timeout``; stdout; stderr). A child killed by a signal gives -signum."""
    out_r, out_w = os.pipe()
    err_r, err_w = os.pipe()
    with FORK_LOCK:  # (no thread of ours is inside SQLite meanwhile)
        pid = os.fork()
    if pid == 0:
        code = 98
        try:
            os.makedirs(workdir, exist_ok=True)
            os.chdir(workdir)
            os.dup2(out_w, 1)
            os.dup2(err_w, 2)
            os.setsid()
            sys.stdout = io.TextIOWrapper(os.fdopen(1, "wb", buffering=0), write_through=True)
            sys.stderr = io.TextIOWrapper(os.fdopen(2, "wb", buffering=0), write_through=True)
            sys.stdin = open(os.devnull)
            # a pool's workers would import this process's __main__ (the bench, by a path relative
            # to a folder it left): as from the `vts` script, there is nothing of ours to import
            main_mod = sys.modules.get("__main__")
            if main_mod is not None and hasattr(main_mod, "__file__"):
                del main_mod.__file__
            if before:
                before()
            from vts_hw.cli import main

            code = 0
            try:
                main(argv)
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            except BaseException:
                traceback.print_exc()
                code = 99
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code)
    os.close(out_w)
    os.close(err_w)
    chunks = {out_r: [], err_r: []}
    if during:
        during(pid)
    deadline = time.monotonic() + timeout
    fds, hung = [out_r, err_r], False
    while fds:
        left = deadline - time.monotonic()
        if left <= 0:
            hung = True
            try:
                os.killpg(pid, signal.SIGKILL)
            except OSError:
                pass
            break
        for fd in select.select(fds, [], [], min(left, 0.5))[0]:
            data = os.read(fd, 65536)
            if data:
                chunks[fd].append(data)
            else:
                fds.remove(fd)
    _, status = os.waitpid(pid, 0)
    for fd in (out_r, err_r):
        os.close(fd)
    code = None if hung else os.waitstatus_to_exitcode(status)
    return code, b"".join(chunks[out_r]).decode(errors="replace"), b"".join(chunks[err_r]).decode(errors="replace")
