"""The class "endless and huge files" of bench/bad_inputs.py (issue 21, round 2).

Every file or folder parameter a command reads (outputs left out) is given, one case each:
``/dev/zero`` (endless), a FIFO nobody writes (it blocks whoever opens it), an 8 GiB sparse
file (huge, and all zeros), and, where a folder is wanted, a recording folder whose manifest,
index or .mjpeg is ``/dev/zero``. The global ``--config`` too, for every command that takes one.
The child runs with its address space capped (:data:`MEMORY_CAP`): a reader without a bound
fails fast there (a MemoryError, a traceback) instead of filling the machine.

A case passes when the command ends within the sweep's time limit, with no traceback, a
documented exit code, and, given the endless file itself, not 0 (it was given nothing it could
use: exit 0 is a false OK). A recording folder with one endless part may end 0 when the command
never reads that part.
"""

from __future__ import annotations

import os
import resource
from pathlib import Path

import click

from badkit.classes import Case, Verdict, common
from badkit.signals import fork_vts

CLASS = "endless files"
MEMORY_CAP = 4 * 2**30
#: parameters that name what a command writes, or a folder it creates (never read)
WRITTEN = {"out", "output", "export_dir", "plot_path", "folder", "out_dir"}


def _cap_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_CAP, MEMORY_CAP))


def _run(argv, timeout, wd):
    return fork_vts(argv, timeout, wd, before=_cap_memory)


def make_inputs(root: Path) -> dict[str, str]:
    """The endless and huge things, made once (the recordings' parts are symlinks)."""
    d = root / "endless"
    d.mkdir(parents=True, exist_ok=True)
    os.mkfifo(d / "fifo")
    with open(d / "huge.bin", "wb") as f:
        f.truncate(8 * 2**30)
    files = {"/dev/zero": "/dev/zero", "FIFO": str(d / "fifo"), "8 GiB sparse": str(d / "huge.bin")}
    for part, link in (("manifest", "manifest.json"), ("index", "cam1.index.csv"), ("mjpeg", "cam1.mjpeg")):
        rec = d / f"rec-{part}"
        rec.mkdir()
        (rec / "cam1.mjpeg").write_bytes(b"")
        (rec / "cam1.index.csv").write_text("frame,offset,length,camera_time,host_time\n")
        (rec / "cam2.mjpeg").write_bytes(b"")
        (rec / "cam2.index.csv").write_text("frame,offset,length,camera_time,host_time\n")
        (rec / link).unlink(missing_ok=True)
        (rec / link).symlink_to("/dev/zero")
        files[f"recording, {part} /dev/zero"] = str(rec)
    return files


def _judge(strict: bool):
    """``strict``: the endless file itself was given, so exit 0 is a false OK; a recording folder
    with one endless part may end 0 when the command does not read that part (recording info
    reads no manifest)."""

    def judge(wd: Path, code, out, err) -> Verdict:
        v = common(code, err)
        if code is not None and code < 0:
            v.other, v.why = True, f"killed by signal {-code} (memory cap?)"
        elif v.passed and code == 0 and strict:
            v.false_ok, v.why = True, "exit 0 on an endless or huge input"
        return v

    return judge


def _read(p: click.Parameter) -> bool:
    return isinstance(p.type, (click.Path, click.File)) and p.name not in WRITTEN


def cases(
    cmd_path: tuple[str, ...], cmd: click.Command, base: list[str], cfg: list[str], inputs: dict[str, str], replace
) -> list[Case]:
    """One command's cases: each read path parameter, and --config, given each endless input."""
    out = []
    for p in cmd.params:
        if not _read(p):
            continue
        opt = None if isinstance(p, click.Argument) else (p.opts[-1] if p.opts[-1].startswith("--") else p.opts[0])
        folder_ok = getattr(p.type, "dir_okay", True)
        file_ok = getattr(p.type, "file_okay", True)
        for what, value in inputs.items():
            is_rec = what.startswith("recording")
            if (is_rec and not folder_ok) or (not is_rec and not file_ok):
                continue
            rest = cfg if p.name != "config_path" else []
            argv = [*cmd_path, *replace(base, p, opt, value), *rest]
            out.append(
                Case(CLASS, f"{p.name}: {what}", lambda wd, a=argv: list(a), _judge(not is_rec), extra={"run": _run})
            )
    return out


__all__ = ["CLASS", "cases", "make_inputs"]
