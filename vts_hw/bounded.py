"""Reading files from outside with a bound: an endless input (``/dev/zero``, a pipe that never
ends: anything but a regular file) or a huge one (a sparse 100 GB file named by mistake) is refused in one sentence naming
it, instead of filling memory at a gigabyte a second; and the read stays interruptible
(Ctrl-C between chunks, exit 130).

Every reader of a user's file (recording manifests and indexes, loose .mjpg captures, rig.yaml,
calibrations, mappings, trigger logs, JSON imports, list-mode headers) goes through
:func:`read_bytes` / :func:`read_text`, or :func:`open_bounded` to stream a file it reads line
by line. A regular file is checked by its size before a byte is read, and read a chunk at a
time up to the limit (it may grow while read); a character or block device (``/dev/zero``, a
disk), a pipe or a socket is refused outright, and never opened (:func:`open_checked`: a FIFO
swapped in after the check does not block the open either).
docs/decisions/0053-slow-peers-endless-files-signals.md.
"""

from __future__ import annotations

import io
import os
import stat
from pathlib import Path

from vts_hw.errors import DataError

MiB = 2**20
#: JSON and YAML a person or this suite writes: configs, calibrations, manifests, imports
SMALL = 64 * MiB
#: tables that grow with a recording: frame indexes, trigger logs (a year of frames at 25 fps fits)
TABLE = 1024 * MiB
#: a loose .mjpg capture or JPEG read whole (recordings are read frame by frame, never whole)
CAPTURE = 2048 * MiB
#: list-mode data read whole (an acquisition of hours is some GiB)
LISTMODE = 8192 * MiB
#: only a device or pipe refused (a file appended to, or sniffed by its first bytes)
ANY_SIZE = 2**62
CHUNK = MiB


class TooLarge(DataError):
    """A file over the size a reader takes, or one that is not a file (a device, a socket)."""


def _mib(n: int) -> str:
    return f"{n / MiB:g} MiB"


def check_file(path: str | os.PathLike, limit: int, what: str) -> os.stat_result:
    """The file's stat, after refusing a device or socket, or a regular file over ``limit`` bytes.
    (OSError, e.g. no such file, is the caller's to word.) A caller that opens the file itself
    afterwards had better use :func:`open_checked`: the name may be another file by then."""
    return _check_stat(os.stat(path), path, limit, what)


def _check_stat(st: os.stat_result, path, limit: int, what: str) -> os.stat_result:
    if stat.S_ISDIR(st.st_mode):
        raise IsADirectoryError(21, "Is a directory", str(path))
    if not stat.S_ISREG(st.st_mode):
        raise TooLarge(
            f"{path}: not a regular file but a device, pipe or socket, which may never end; a {what} must be a file"
        )
    if st.st_size > limit:
        raise TooLarge(
            f"{path}: {st.st_size / MiB:,.0f} MiB, more than a {what} can be ({_mib(limit)}); nothing was read"
        )
    return st


def open_checked(path: str | os.PathLike, limit: int, what: str):
    """``path`` opened for reading (binary, unbuffered) once it is known to be a regular file of
    at most ``limit`` bytes: checked by its name first (a device is never opened: opening a
    serial port resets the board behind it), then opened without waiting (``O_NONBLOCK``: a FIFO
    put in its place meanwhile does not block the open) and checked again, as opened."""
    check_file(path, limit, what)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
    try:
        _check_stat(os.fstat(fd), path, limit, what)
        os.set_blocking(fd, True)
        return open(fd, "rb", buffering=0)
    except BaseException:
        os.close(fd)
        raise


def read_bytes(path: str | os.PathLike, limit: int = SMALL, what: str = "file") -> bytes:
    """The whole of ``path``, at most ``limit`` bytes (see the module docstring)."""
    out = bytearray()
    with open_checked(path, limit, what) as f:
        while True:
            chunk = f.read(CHUNK)  # a chunk at a time: Ctrl-C is seen between two
            if not chunk:
                return bytes(out)
            out += chunk
            if len(out) > limit:
                raise TooLarge(
                    f"{path}: more than {_mib(limit)} and still coming, more than a {what} can be; stopped reading"
                )


def read_text(
    path: str | os.PathLike, limit: int = SMALL, what: str = "file", encoding: str = "utf-8", errors: str = "strict"
) -> str:
    """:func:`read_bytes` decoded (universal newlines, as ``Path.read_text``)."""
    data = read_bytes(path, limit, what).decode(encoding, errors)
    return data.replace("\r\n", "\n").replace("\r", "\n") if "\r" in data else data


class _Capped(io.RawIOBase):
    """A binary file that raises :class:`TooLarge` once more than ``limit`` bytes were read."""

    def __init__(self, f, path, limit: int, what: str):
        self._f, self._path, self._limit, self._what, self._n = f, path, limit, what, 0

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        n = self._f.readinto(b)
        self._n += n or 0
        if self._n > self._limit:
            raise TooLarge(
                f"{self._path}: more than {_mib(self._limit)}, more than a {self._what} can be; stopped reading"
            )
        return n

    def close(self) -> None:
        self._f.close()
        super().close()


def open_bounded(
    path: str | os.PathLike,
    limit: int = TABLE,
    what: str = "file",
    mode: str = "r",
    encoding: str = "utf-8",
    newline: str | None = None,
    errors: str = "strict",
):
    """``open(path, mode)`` for streaming (``"r"`` text, ``"rb"`` binary) that refuses what
    :func:`check_file` refuses and stops at ``limit`` bytes."""
    raw = _Capped(open_checked(path, limit, what), Path(path), limit, what)
    buffered = io.BufferedReader(raw, CHUNK)
    if mode == "rb":
        return buffered
    return io.TextIOWrapper(buffered, encoding=encoding, newline=newline, errors=errors)


__all__ = [
    "read_bytes",
    "read_text",
    "open_bounded",
    "open_checked",
    "check_file",
    "TooLarge",
    "SMALL",
    "TABLE",
    "CAPTURE",
    "LISTMODE",
    "ANY_SIZE",
]
