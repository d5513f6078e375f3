"""Worker processes end when the command that started them ends, however it ends (``kill -9``
included): otherwise a pool's workers wait on their task queue for ever, holding their memory.

:func:`die_with` is called first thing in a worker (a pool's initializer). On Linux it asks the
kernel for SIGKILL when the worker's parent dies (``prctl(PR_SET_PDEATHSIG)``); the parent of a
fork-server worker is the fork server, which itself ends when the command does. As a fallback
(another system, or a parent that is not the command), a daemon thread watches the command's
pid and ends the worker within a second of it going. docs/decisions/0053-slow-peers-endless-files-signals.md.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

PR_SET_PDEATHSIG = 1
WATCH_EVERY_S = 0.5


def alive(pid: int) -> bool:
    """Whether ``pid`` runs (a zombie, dead but not yet reaped, does not)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except (OSError, IndexError):
        return True   # no /proc: kill(0) is all there is


def die_with(command_pid: int) -> None:
    """End this process when its parent, or the process ``command_pid``, ends."""
    parent = os.getppid()
    if sys.platform.startswith("linux"):
        try:
            import ctypes
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent or not alive(command_pid):   # gone before the request took
        os._exit(1)

    def watch() -> None:
        while True:
            threading.Event().wait(WATCH_EVERY_S)
            if os.getppid() != parent or not alive(command_pid):
                os._exit(1)
    threading.Thread(target=watch, name="lifeline", daemon=True).start()


@contextlib.contextmanager
def interrupts_deferred():
    """Ctrl-C held back for the block, then raised at its end: for a block that must not be cut
    in the middle (a process pool starting its workers: one cut between the fork server's fork
    and the pool noting the worker leaves that worker unwaited-for, and it dies with a traceback
    when the pool's queues are gone). Outside the main thread, nothing is changed."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    got: list[int] = []
    old = signal.signal(signal.SIGINT, lambda signum, frame: got.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)
    if got and callable(old):
        old(signal.SIGINT, None)
    elif got and old == signal.SIG_DFL:   # the default: end as Ctrl-C would have ended it
        os.kill(os.getpid(), signal.SIGINT)
