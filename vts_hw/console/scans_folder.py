"""The folder the console's Scan page puts its scans into (``vts console --scans-dir``): a folder
of scans and nothing else (docs/decisions/0079-console-network.md).

The default is ``scans/`` beside the per-user results store (``$XDG_DATA_HOME/vts-hw/scans``,
else ``~/.local/share/vts-hw/scans``), never the folder the console was started in, which
may hold a rig.yaml, the simulator's ``sim.env`` or the store. A folder that is not there is
created, readable by its owner only (0700). One that is there is refused (``UsageError``, exit 2,
one sentence naming what is wrong) when it holds anything but scans: every entry must be a
folder (not a link) named ``scan-...`` as `vts scan start` names it, or holding a
``manifest.json``; and when it belongs to another user or anyone may write into it. The Scan
page serves no file of it by path in any case (scan_page.py: a scan's outputs by number).
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from vts_hw.errors import UsageError
from vts_hw.files import WriteFailed, os_reason
from vts_hw.store.paths import default_path

SCAN_PREFIX = "scan-"
MANIFEST = "manifest.json"
FOLDER_MODE = 0o700


def default_scans_dir() -> Path:
    """``scans/`` beside the per-user default results store."""
    return default_path().parent / "scans"


def _is_scan(entry: os.DirEntry) -> bool:
    if entry.is_symlink() or not entry.is_dir(follow_symlinks=False):
        return False
    if entry.name.startswith(SCAN_PREFIX):
        return True
    try:
        return stat.S_ISREG(os.lstat(os.path.join(entry.path, MANIFEST)).st_mode)
    except OSError:
        return False


def _what(entry: os.DirEntry) -> str:
    if entry.is_symlink():
        return "a link"
    if entry.is_dir(follow_symlinks=False):
        return "a folder that is not a scan (no manifest.json)"
    return "a file" if entry.is_file(follow_symlinks=False) else "not a scan"


def check_scans_dir(folder: Path) -> None:
    """UsageError (one sentence) when the existing ``folder`` is not a folder of scans only."""
    where = f"--scans-dir {folder}"
    try:
        st = os.stat(folder)
    except OSError as exc:
        raise UsageError(f"{where}: cannot be read ({os_reason(exc)})") from None
    if not stat.S_ISDIR(st.st_mode):
        raise UsageError(f"{where} is not a folder: give the folder the Scan page's scans go into")
    if st.st_uid not in (os.geteuid(), 0):
        raise UsageError(f"{where} belongs to another user (uid {st.st_uid}): the scans go into a folder of your own")
    if st.st_mode & stat.S_IWOTH and not st.st_mode & stat.S_ISVTX:
        raise UsageError(f"{where}: anyone may write into it: the scans go into a folder of your own")
    try:
        with os.scandir(folder) as entries:
            for entry in entries:
                if not _is_scan(entry):
                    raise UsageError(
                        f"{where} holds {entry.name!r}, {_what(entry)}: the scans folder holds scans "
                        f"only (give a folder of its own, e.g. a new one: it is created 0700)"
                    )
    except OSError as exc:
        raise UsageError(f"{where}: cannot be read ({os_reason(exc)})") from None


def scans_folder(given: str | os.PathLike | None) -> Path:
    """The scans folder to serve: ``given`` (or the default), created 0700 when it is not there,
    checked (:func:`check_scans_dir`) when it is; its absolute path. WriteFailed (exit 3) when it
    cannot be created."""
    folder = Path(given).expanduser() if given not in (None, "") else default_scans_dir()
    folder = folder.absolute()
    if not os.path.lexists(folder):
        try:
            folder.mkdir(parents=True, mode=FOLDER_MODE)
        except FileExistsError:
            pass
        except OSError as exc:
            raise WriteFailed(folder, f"the scans folder cannot be created ({os_reason(exc)})") from None
    check_scans_dir(folder)
    return folder.resolve()


__all__ = ["scans_folder", "check_scans_dir", "default_scans_dir"]
