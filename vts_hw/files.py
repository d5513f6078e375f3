"""Writing files so that a failure (disk full, read-only folder, no permission) never leaves a
half-written or empty file, never replaces a good file with a worse one, and ends in one
sentence naming the file.

Every output the suite writes whole (JSON, CSV, reports, images, calibrations) goes through
:func:`write_atomic`: the bytes go to a hidden temporary file in the same folder, are flushed
and fsynced, then renamed over the target. A failure at any point removes the temporary file
and raises :class:`WriteFailed` (a :class:`~vts_hw.errors.DataError`, exit code 3); the target
is then exactly as it was before (absent, or the previous version).

Files that grow while acquiring (recordings) cannot be written this way; they use
:func:`os_reason` for the same wording.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
from pathlib import Path

from vts_hw.errors import DataError


class WriteFailed(DataError):
    """A file could not be written; the message names it, the reason, and what was kept."""

    def __init__(self, path: str | os.PathLike, reason: str, kept: str = ""):
        self.path = Path(path)
        self.reason = reason
        self.kept = kept
        super().__init__(f"{self.path}: could not be written ({reason})" + (f"; {kept}" if kept else ""))


def os_reason(exc: BaseException) -> str:
    """A short reason for an OSError: 'no space left on device', 'permission denied', ..."""
    if isinstance(exc, OSError):
        if exc.errno == errno.ENOSPC:
            return "no space left on device"
        if exc.errno == errno.EDQUOT:
            return "disk quota exceeded"
        if exc.errno == errno.EROFS:
            return "read-only file system"
        if exc.strerror:
            return exc.strerror[0].lower() + exc.strerror[1:]
    return str(exc) or type(exc).__name__


def is_disk_full(exc: BaseException) -> bool:
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def write_atomic(path: str | os.PathLike, data: bytes | str, *, encoding: str = "utf-8",
                 kept: str | None = None, mode: int | None = None) -> Path:
    """Write ``data`` to ``path`` whole, or not at all (see the module docstring).

    ``kept`` is what the error message says was kept (default: the previous file, if there
    was one, is unchanged). ``mode`` sets the file's permission bits (e.g. 0o600)."""
    path = Path(path)
    payload = data.encode(encoding) if isinstance(data, str) else bytes(data)
    existed = path.exists()
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o666 if mode is None else mode)
        try:
            view = memoryview(payload)
            while view:
                n = os.write(fd, view)
                view = view[n:]
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink()
        if kept is None:
            kept = "the previous version is unchanged" if existed else "nothing was written there"
        raise WriteFailed(path, os_reason(exc), kept) from None
    return path


def write_json_atomic(path: str | os.PathLike, data, *, kept: str | None = None, indent: int | None = 2) -> Path:
    """JSON text of ``data`` written with :func:`write_atomic`."""
    return write_atomic(path, json.dumps(data, indent=indent, default=str) + "\n", kept=kept)


def ensure_dir(folder: str | os.PathLike, what: str = "folder") -> Path:
    """Create ``folder`` (and parents); one sentence naming it when that is impossible."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise WriteFailed(folder, f"a file of that name is in the way of the {what}") from None
    except OSError as exc:
        raise WriteFailed(folder, f"cannot create the {what}: {os_reason(exc)}") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise WriteFailed(folder, f"the {what} is not writable")
    return folder


class Outputs:
    """The files a command writes beside its result (a report, a plot, an export), each whole or
    not at all. One that cannot be written is noted and the work goes on, so that the result is
    still printed and stored; the command then ends with :meth:`error` (exit 3) naming the file.

    ``attempt(fn, *args)`` runs one writer: its return value, or None when it raised
    :class:`WriteFailed` (noted in :attr:`failed`)."""

    def __init__(self) -> None:
        self.failed: list[WriteFailed] = []

    def attempt(self, fn, *args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except WriteFailed as exc:
            self.failed.append(exc)
            return None

    def __bool__(self) -> bool:          # true when every output was written
        return not self.failed

    def sentence(self) -> str:
        """Every file not written, with its reason, in one sentence (empty when none)."""
        return "; ".join(str(e) for e in self.failed)

    def not_written(self) -> list[str]:
        return [str(e.path) for e in self.failed]


def export_stopped(exc: WriteFailed, out) -> WriteFailed:
    """``exc`` from one file of an export into the folder ``out``, saying what that means for the
    others: those before it are whole, the rest were not written (an export stops at its first
    file that cannot be written; each file is whole or absent)."""
    kept = (f"{exc.kept}; the export into {out} stopped there: the files written before it are whole, "
            "the rest were not written")
    return WriteFailed(exc.path, exc.reason, kept)
