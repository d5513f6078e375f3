"""`vts ARGS` run in the test's own process (the CLI's main(), as the console script runs it).

``vts(capsys, ...)`` for tests that read what it printed with pytest's capsys; ``run(...)`` in
place of ``subprocess.run([sys.executable, "-m", "vts_hw.cli.__main__", ...])`` where the
process itself is not what the test is about (a bad input's sentence and exit code, a report
written): the same exit code, stdout and stderr, without a Python start and the imports of a
command each time (about a second each). Tests of the real process (signals, kill -9, the
installed command, what a command loads) keep their subprocess."""

from __future__ import annotations

import contextlib
import io
import logging
import os
import subprocess
import sys
import threading
import warnings

from vts_hw.cli import main


def vts(capsys, *args) -> tuple[int, str, str]:
    """`vts ARGS` in this process: (exit code, stdout, stderr); its log, warnings and threads'
    uncaught exceptions on stderr as run()'s are."""
    try:
        with _as_a_process():
            main([str(a) for a in args])
        code = 0
    except SystemExit as exc:
        code = _exit_code(exc)
    got = capsys.readouterr()
    return code, got.out, got.err


def _replace_environ(env: dict[str, str]) -> None:
    """os.environ made ``env`` key by key: never empty on the way (a thread of the test, a
    simulated device's, may read it meanwhile), unlike a clear() and an update()."""
    for key in [k for k in os.environ if k not in env]:
        os.environ.pop(key, None)
    for key, value in env.items():
        if os.environ.get(key) != value:
            os.environ[key] = value


def _exit_code(exc: SystemExit) -> int:
    """The exit status a process ending with ``exc`` has; a message exit's text on stderr, as
    Python prints it."""
    if isinstance(exc.code, str):
        print(exc.code, file=sys.stderr)
    return exc.code if isinstance(exc.code, int) else 0 if exc.code is None else 1


@contextlib.contextmanager
def _environment(env: dict | None, cwd=None):
    """os.environ as ``env`` (the whole of it, as subprocess's env= gives a child) and the
    working folder ``cwd`` while the command runs; both as they were afterwards."""
    saved, here = dict(os.environ), os.getcwd()
    try:
        if env is not None:
            _replace_environ(env)
        if cwd is not None:
            os.chdir(cwd)
        yield
    finally:
        os.chdir(here)
        _replace_environ(saved)


def _show_on_stderr(message, category, filename, lineno, file=None, line=None) -> None:
    sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


@contextlib.contextmanager
def _as_a_process():
    """The log, Python's warnings and a thread's uncaught exception on the command's stderr, as
    in a process of its own: the CLI's logging.basicConfig adds no handler while pytest's are on
    the root logger, and pytest records the warnings and the threads' exceptions, so none would
    reach stderr (a test's ``stderr == ""`` or ``"Traceback" not in stderr`` could not fail on
    them). The root logger, the warnings and the hooks as they were afterwards."""
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    hooks = threading.excepthook, sys.unraisablehook
    root.handlers = []
    root.setLevel(logging.WARNING)  # (a fresh process's)
    threading.excepthook, sys.unraisablehook = threading.__excepthook__, sys.__unraisablehook__
    try:
        with warnings.catch_warnings():
            warnings.resetwarnings()  # then a fresh interpreter's filters (no -W, no -X dev)
            for category in (ResourceWarning, ImportWarning, PendingDeprecationWarning, DeprecationWarning):
                warnings.simplefilter("ignore", category)
            warnings.filterwarnings("default", category=DeprecationWarning, module="__main__")
            warnings.showwarning = _show_on_stderr  # (restored by catch_warnings)
            yield
    finally:
        for handler in root.handlers:  # (the one basicConfig added, on the command's stderr)
            handler.close()
        root.handlers = handlers
        root.setLevel(level)
        threading.excepthook, sys.unraisablehook = hooks


@contextlib.contextmanager
def _stdin(stream):
    saved = sys.stdin
    sys.stdin = stream
    try:
        yield
    finally:
        sys.stdin = saved


def _stream() -> io.TextIOWrapper:
    """A text stream with a byte buffer under it, as a pipe's is (not a terminal)."""
    return io.TextIOWrapper(io.BytesIO(), encoding="utf-8", errors="replace", write_through=True)


def _text(stream: io.TextIOWrapper) -> str:
    stream.flush()
    return stream.buffer.getvalue().decode("utf-8", errors="replace")


def run(*args, env: dict | None = None, cwd=None, input: str | None = None) -> subprocess.CompletedProcess:
    """`vts ARGS` in this process with ``env`` and ``cwd`` as a child would have them and
    ``input`` as what it reads from its standard input (none: an empty one): a CompletedProcess
    with its returncode, stdout and stderr (text), as subprocess.run's capture_output=True,
    text=True gives; what the command logs and the warnings a process shows are on its stderr.
    An exception main() does not turn into an exit is raised here (in a subprocess it would be
    a traceback on stderr, which the tests refuse)."""
    argv = [str(a) for a in args]
    out, err = _stream(), _stream()
    stdin = io.TextIOWrapper(io.BytesIO((input or "").encode()), encoding="utf-8")
    with (
        _environment(env, cwd),
        _stdin(stdin),
        contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
        _as_a_process(),
    ):
        try:
            main(argv)
            code = 0
        except SystemExit as exc:
            code = _exit_code(exc)
    return subprocess.CompletedProcess(["vts", *argv], code, _text(out), _text(err))
