"""A recording left ``status: recording``: still being written, or interrupted.

The writer (writer.py) names itself in the manifest (``writer``: host, pid and the process's
start token, :func:`vts_hw.lifeline.process_record`) and rewrites the manifest with its final
status when it closes. A ``kill -9``, a power cut or a crash leaves ``recording`` for ever, so
``recording`` alone says nothing: :func:`judge` asks whether that very process still runs
(:func:`vts_hw.lifeline.is_alive`: the pid, and its start time, so a pid reused since is not
taken for the writer). A recording whose writer runs is being recorded; any other (its writer
gone, written on another computer, which cannot be asked from here, or by a writer that named
none) is *interrupted*: never a finished recording. :func:`vts_hw.recording.folder.load_manifest`
applies it, so every reader of a recording sees the same (docs/decisions/0082-killed-is-not-finished.md).
"""

from __future__ import annotations

from dataclasses import dataclass

from vts_hw.lifeline import host_name, is_alive

__all__ = ["Unfinished", "judge", "RUNNING", "INTERRUPTED"]

RUNNING = "recording"  # its writer runs
INTERRUPTED = "interrupted"  # its writer died without closing it, or cannot be asked


@dataclass(frozen=True)
class Unfinished:
    """What a manifest left ``recording`` is: ``status`` RUNNING or INTERRUPTED, and why."""

    status: str
    why: str
    pid: int | None = None

    @property
    def running(self) -> bool:
        return self.status == RUNNING


def judge(manifest: dict) -> Unfinished | None:
    """None for a closed recording; else whether its writer still runs (see the module)."""
    if manifest.get("status") != "recording":
        return None
    w = manifest.get("writer")
    if not isinstance(w, dict):
        return Unfinished(
            INTERRUPTED,
            "its recording was never closed (status 'recording') and names no "
            "writer to ask whether it still runs: read as interrupted",
        )
    pid, host, token = w.get("pid"), w.get("host"), w.get("process")
    pid = pid if isinstance(pid, int) and not isinstance(pid, bool) else None
    host = host if isinstance(host, str) else None
    token = token if isinstance(token, str) else ""
    if host != host_name():
        shown = "".join(c for c in host or "" if c.isprintable())[:80] or "another computer"
        return Unfinished(
            INTERRUPTED,
            f"its recording was never closed, and it was written on {shown}, which "
            f"cannot be asked from here whether it still records: read as interrupted",
            pid,
        )
    alive = is_alive(pid, token)
    if alive:
        return Unfinished(RUNNING, f"it is being recorded now by vts (pid {pid}) on this computer", pid)
    who = f"vts (pid {pid})" if pid is not None else "its writer"
    how = (
        "ended without closing it (killed, or the computer stopped)"
        if alive is False
        else "cannot be asked whether it still runs"
    )
    return Unfinished(INTERRUPTED, f"its recording was interrupted: {who}, which wrote it on this computer, {how}", pid)
