"""Writing files so that a failure (disk full, read-only folder, no permission) never leaves a
half-written or empty file, never replaces a good file with a worse one, never replaces or
writes through anything that is not a regular file, and ends in one sentence naming the file.

Every output the suite writes whole (JSON, CSV, reports, images, calibrations) goes through
:func:`write_atomic`: the bytes go to a hidden temporary file in the same folder (a new name,
created exclusively, never through a symbolic link), are flushed and fsynced, then renamed over
the target. A failure at any point removes the temporary file and raises :class:`WriteFailed`
(a :class:`~vts_hw.errors.DataError`, exit code 3); the target is then exactly as it was
before (absent, or the previous version). A file that is replaced keeps its permission bits
(and, written by root, its owner); a file holding a secret (``mode=0o600``) is never left
readable by anyone else.

A target that exists and is not a regular file (a device such as ``/dev/full``, a FIFO, a
socket, a folder) or is a symbolic link is refused before anything is written, and again just
before the rename (:func:`check_target`, :class:`NotReplaced`, exit 3): ``os.replace`` would
otherwise put a JPEG where ``/dev/full`` was. No writer follows a symbolic link at the name it is
given (docs/decisions/0081-writers-replace-only-regular-files.md). A folder a command writes
into is checked the same way (:func:`check_folder`, :func:`ensure_dir`).

Files that grow while acquiring (recordings, logs) cannot be written this way: they are opened
with :func:`open_fd` / :func:`open_writable` (the same refusals, and a FIFO never blocks the
open) and use :func:`os_reason` for the same wording.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import secrets
import stat
from pathlib import Path

from vts_hw.errors import DataError

#: the permission bits of a file holding a secret (the store, sim.env, a TLS key)
PRIVATE = 0o600
NOTHING_WRITTEN = "nothing was written there"


class WriteFailed(DataError):
    """A file could not be written; the message names it, the reason, and what was kept."""

    def __init__(self, path: str | os.PathLike, reason: str, kept: str = ""):
        self.path = Path(path)
        self.reason = reason
        self.kept = kept
        super().__init__(f"{self.path}: could not be written ({reason})" + (f"; {kept}" if kept else ""))


class NotReplaced(WriteFailed):
    """The name a writer was given exists and is not what it writes: a device, a FIFO, a socket,
    a folder where a file is meant (or a file where a folder is), or a symbolic link, which no
    writer follows. It is left as it is; exit 3 like any file that could not be written."""

    def __init__(self, path: str | os.PathLike, kind: str, folder: bool = False, kept: str = NOTHING_WRITTEN):
        self.kind = kind
        if kind.startswith("a symbolic link"):
            reason = f"it is {kind}, which no writer follows: name the {'folder' if folder else 'file'} itself"
        else:
            reason = f"it is {kind}, not a {'folder' if folder else 'regular file'}, so it was left as it is"
        super().__init__(path, reason, kept)


def kind_of(path: str | os.PathLike[str], st: os.stat_result) -> str:
    """What a file that is not a regular file is, in words (``st``: its ``lstat``)."""
    m = st.st_mode
    if stat.S_ISLNK(m):
        try:
            return f"a symbolic link to {os.readlink(path)}"
        except OSError:
            return "a symbolic link"
    for test, words in (
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISFIFO, "a named pipe (FIFO)"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISREG, "a regular file"),
    ):
        if test(m):
            return words
    return "not a regular file"


def _lstat(path: str | os.PathLike) -> os.stat_result | None:
    """``lstat`` of ``path``; None when there is nothing of that name (or its folder cannot be
    searched: the write itself then says why)."""
    try:
        return os.lstat(path)
    except OSError:
        return None


def check_target(path: str | os.PathLike, kept: str = NOTHING_WRITTEN) -> os.stat_result | None:
    """Before writing the file ``path``: None when nothing is there, its stat when it is a regular
    file, else :class:`NotReplaced` (a device, FIFO, socket, folder, or a symbolic link)."""
    st = _lstat(path)
    if st is None or stat.S_ISREG(st.st_mode):
        return st
    raise NotReplaced(path, kind_of(path, st), False, kept)


def check_folder(path: str | os.PathLike, what: str = "folder") -> bool:
    """Before writing into the folder ``path``: False when nothing is there, True when it is a
    folder, else :class:`NotReplaced` (a file, device, FIFO or socket of that name is in the way;
    a symbolic link is not followed)."""
    st = _lstat(path)
    if st is None:
        return False
    if stat.S_ISDIR(st.st_mode):
        return True
    if stat.S_ISREG(st.st_mode):
        raise WriteFailed(path, f"a file of that name is in the way of the {what}")
    raise NotReplaced(path, kind_of(path, st), True)


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


def _new_temp(path: Path, perms: int) -> tuple[Path, int]:
    """A hidden file beside ``path`` of a name no one had: created exclusively (a name planted
    beforehand, a symbolic link included, is never opened), for this writer only."""
    for _ in range(64):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(6)}.tmp")
        try:
            return tmp, os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, perms)
        except FileExistsError:
            continue
    raise FileExistsError(errno.EEXIST, "no free temporary name beside it", str(path))


def _keep_owner_and_mode(fd: int, old: os.stat_result | None, mode: int | None) -> None:
    """The new file takes the permission bits of the one it replaces (narrowed to ``mode`` for a
    secret) and, written by root, its owner and group."""
    if old is None:
        return
    bits = stat.S_IMODE(old.st_mode) & 0o777
    if mode is not None:
        bits &= mode
    if os.geteuid() == 0 and (old.st_uid, old.st_gid) != (0, 0):
        with contextlib.suppress(OSError):
            os.fchown(fd, old.st_uid, old.st_gid)
    os.fchmod(fd, bits)


def write_atomic(
    path: str | os.PathLike,
    data: bytes | str,
    *,
    encoding: str = "utf-8",
    kept: str | None = None,
    mode: int | None = None,
) -> Path:
    """Write ``data`` to ``path`` whole, or not at all (see the module docstring).

    ``kept`` is what the error message says was kept (default: the previous file, if there
    was one, is unchanged). ``mode`` sets the file's permission bits (e.g. 0o600, a secret: an
    existing file's bits are narrowed to it, never widened). A ``path`` that is not a regular
    file is refused (:class:`NotReplaced`), before and again just before the rename."""
    path = Path(path)
    payload = data.encode(encoding) if isinstance(data, str) else bytes(data)
    old = check_target(path, NOTHING_WRITTEN if kept is None else kept)
    tmp = None
    try:
        tmp, fd = _new_temp(path, 0o666 if mode is None else mode)
        try:
            _keep_owner_and_mode(fd, old, mode)
            view = memoryview(payload)
            while view:
                n = os.write(fd, view)
                view = view[n:]
            os.fsync(fd)
        finally:
            os.close(fd)
        check_target(path, NOTHING_WRITTEN if kept is None else kept)  # it may have changed meanwhile
        os.replace(tmp, path)
    except NotReplaced:
        if tmp is not None:
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise
    except OSError as exc:
        if tmp is not None:
            with contextlib.suppress(OSError):
                tmp.unlink()
        if kept is None:
            kept = "the previous version is unchanged" if old is not None else NOTHING_WRITTEN
        raise WriteFailed(path, os_reason(exc), kept) from None
    return path


def check_private_folder(folder: str | os.PathLike, what: str) -> None:
    """WriteFailed naming ``what`` (a file holding a secret, to go into ``folder``) when the folder
    belongs to another user (not root) or anyone may write into it (no sticky bit): they could
    replace the file or put theirs in its place."""
    try:
        st = os.stat(folder)
    except OSError:
        return  # the write itself says why
    if st.st_uid not in (os.geteuid(), 0):
        raise WriteFailed(
            Path(folder) / what,
            f"its folder {folder} belongs to another user (uid {st.st_uid}), "
            "who could replace it; a file holding a secret goes into a "
            "folder of your own",
            NOTHING_WRITTEN,
        )
    if st.st_mode & stat.S_IWOTH and not st.st_mode & stat.S_ISVTX:
        raise WriteFailed(
            Path(folder) / what,
            f"anyone may write into its folder {folder}, and replace it; a "
            "file holding a secret goes into a folder of your own",
            NOTHING_WRITTEN,
        )


def write_secret(path: str | os.PathLike, data: bytes | str, *, kept: str | None = None) -> Path:
    """:func:`write_atomic` of a file holding a secret (a password, a token, a private key): mode
    0600 whatever the umask (an existing file narrowed to it), in a folder of its owner's
    (:func:`check_private_folder`)."""
    path = Path(path)
    check_private_folder(path.parent, path.name)
    return write_atomic(path, data, kept=kept, mode=PRIVATE)


def open_fd(
    path: str | os.PathLike,
    *,
    append: bool = True,
    exclusive: bool = False,
    perms: int = 0o666,
    kept: str = NOTHING_WRITTEN,
) -> int:
    """A descriptor to write the regular file ``path`` (created when absent with ``perms``; ``append``
    at its end, else emptied; ``exclusive``: it must not exist). Never a device, FIFO, socket or
    folder, never through a symbolic link: :class:`NotReplaced`, checked before the open and on
    what was opened (a FIFO does not block the open). Other failures are the OSError."""
    check_target(path, kept)
    flags = os.O_WRONLY | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC
    flags |= (os.O_APPEND if append else 0) | (os.O_EXCL if exclusive else 0)
    try:
        fd = os.open(path, flags, perms)
    except OSError as exc:
        if exc.errno in (errno.ELOOP, errno.ENXIO, errno.EISDIR, errno.EEXIST):  # changed meanwhile
            st = _lstat(path)
            if st is not None and not stat.S_ISREG(st.st_mode):
                raise NotReplaced(path, kind_of(path, st), False, kept) from None
        raise
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise NotReplaced(path, kind_of(path, st), False, kept)
        fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
        if not append:
            os.ftruncate(fd, 0)
    except BaseException:
        os.close(fd)
        raise
    return fd


def open_writable(
    path: str | os.PathLike,
    mode: str = "ab",
    *,
    encoding: str | None = None,
    newline: str | None = None,
    perms: int = 0o666,
    kept: str = NOTHING_WRITTEN,
):
    """:func:`open_fd` as a file object: ``mode`` is ``w``/``a`` (text, with ``encoding`` and
    ``newline``) or ``wb``/``ab``, as :func:`open` takes them."""
    if mode not in ("w", "a", "wb", "ab"):
        raise ValueError(f"mode {mode!r}: expected w, a, wb or ab")
    fd = open_fd(path, append=mode.startswith("a"), perms=perms, kept=kept)
    try:
        return os.fdopen(fd, mode, encoding=encoding, newline=newline) if "b" not in mode else os.fdopen(fd, mode)
    except BaseException:
        os.close(fd)
        raise


def write_json_atomic(
    path: str | os.PathLike, data, *, kept: str | None = None, indent: int | None = 2, mode: int | None = None
) -> Path:
    """JSON text of ``data`` written with :func:`write_atomic`."""
    return write_atomic(path, json.dumps(data, indent=indent, default=str) + "\n", kept=kept, mode=mode)


def ensure_dir(folder: str | os.PathLike, what: str = "folder", *, link_ok: bool = False, mode: int = 0o777) -> Path:
    """Create ``folder`` (and parents; new ones with ``mode``, less the umask); one sentence naming
    it when that is impossible. A device, FIFO or socket of that name is refused
    (:class:`NotReplaced`), and so is a symbolic link unless ``link_ok`` (the folder of a file
    named on the command line, as the kernel resolves it, not a folder named to write into)."""
    folder = Path(folder)
    if not (link_ok and os.path.isdir(folder)):
        check_folder(folder, what)
    try:
        folder.mkdir(parents=True, exist_ok=True, mode=mode)
    except FileExistsError:
        raise WriteFailed(folder, f"a file of that name is in the way of the {what}") from None
    except OSError as exc:
        raise WriteFailed(folder, f"cannot create the {what}: {os_reason(exc)}") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise WriteFailed(folder, f"the {what} is not writable")
    return folder


@contextlib.contextmanager
def filled_folder(folder: str | os.PathLike, what: str = "folder"):
    """``ensure_dir(folder)`` for a block that writes into it: the folders made here (it and its
    new parents) that the block left empty because it failed (a full disk) are removed again, so
    that no empty folder is left to be taken for a result (an empty ``unsaved-...`` artifacts
    folder looks like a run's)."""
    folder = Path(folder)
    made = []  # the folders ensure_dir makes, deepest first
    for f in (folder, *folder.parents):
        if os.path.lexists(f):
            break
        made.append(f)
    ensure_dir(folder, what)
    try:
        yield folder
    except BaseException:
        for f in made:
            try:
                f.rmdir()  # only when empty: what was written is kept
            except OSError:
                break
        raise


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

    def __bool__(self) -> bool:  # true when every output was written
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
    kept = (
        f"{exc.kept}; the export into {out} stopped there: the files written before it are whole, "
        "the rest were not written"
    )
    return WriteFailed(exc.path, exc.reason, kept)
