"""Saving a result that took work to compute (a calibration, a mapping) so that a full disk or a
read-only folder does not lose it.

:func:`save_or_keep` writes the text whole to the file asked for (:func:`vts_hw.files.write_atomic`:
nothing half-written, the previous version kept). If that fails, it writes the same text to a
fallback file named after it with the time, in the current folder or else the temporary folder
($TMPDIR), and returns the :class:`~vts_hw.files.WriteFailed` error (exit code 3) whose message
names the file that could not be written and says where the result went instead, for the caller
to raise once it has shown the result.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

from vts_hw.files import WriteFailed, write_atomic


@dataclass
class Saved:
    """Where a result went: ``written`` (the file asked for), else ``fallback`` (or None if no
    file could be written at all) and ``error`` (to raise after showing the result)."""

    path: Path
    written: Path | None = None
    fallback: Path | None = None
    error: WriteFailed | None = None

    def data(self) -> dict:
        """For --json: ``output`` (None if not written), ``saved_to``, ``write_error``."""
        return {
            "output": str(self.written) if self.written else None,
            "saved_to": str(self.written or self.fallback) if (self.written or self.fallback) else None,
            "write_error": str(self.error) if self.error else None,
        }


def fallback_folders() -> list[Path]:
    """Where a result that could not be written goes: the current folder, then $TMPDIR."""
    out: list[Path] = []
    for folder in (Path.cwd(), Path(tempfile.gettempdir())):
        if folder.resolve() not in [f.resolve() for f in out]:
            out.append(folder)
    return out


def save_or_keep(path: str | os.PathLike, text: str, what: str = "result") -> Saved:
    """Write ``text`` to ``path``; if impossible, to a fallback file (see the module docstring).
    A ``path`` that is not a regular file (a device, FIFO, folder, symbolic link: files.NotReplaced)
    is not written either; the result then goes to the fallback file the same way."""
    path = Path(path)
    try:
        return Saved(path, written=write_atomic(path, text))
    except WriteFailed as exc:
        reason, kept = exc.reason, exc.kept
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
    tried = []
    for folder in fallback_folders():
        other = folder / f"{path.stem}-{stamp}{path.suffix or '.json'}"
        n = 2
        while os.path.lexists(other):  # whatever is there, a link or a FIFO too, is someone else's
            other = folder / f"{path.stem}-{stamp}-{n}{path.suffix or '.json'}"
            n += 1
        try:
            write_atomic(other, text)
        except WriteFailed:
            tried.append(str(other))
            continue
        return Saved(
            path, fallback=other, error=WriteFailed(path, reason, f"{kept}; the {what} was saved to {other} instead")
        )
    return Saved(
        path,
        error=WriteFailed(
            path,
            reason,
            f"{kept}; the {what} could not be saved anywhere else either (tried"
            f" {', '.join(tried)}), so only the figures printed here are left",
        ),
    )
