"""Real file-system faults for tests: a small tmpfs that fills up (ENOSPC) or is remounted
read-only, a read-only mount.

Mounting needs root (CI runs as root) or password-less sudo. The mount is global, so a `vts`
subprocess writing into it meets a full disk exactly as it would in the field; it is
unmounted when the test ends (lazily, in case a child still holds a file open).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from pathlib import Path

import pytest


def root_cmd() -> list[str] | None:
    """The prefix that runs mount and umount as root here ([] as root, else sudo -n), or None."""
    if os.geteuid() == 0:
        return []
    if shutil.which("sudo") and subprocess.run(["sudo", "-n", "true"], capture_output=True).returncode == 0:
        return ["sudo", "-n"]
    return None


def _mount(args: list[str]) -> None:
    pre = root_cmd()
    if pre is None:
        pytest.skip("needs root or password-less sudo to mount a small tmpfs (CI runs as root)")
    p = subprocess.run([*pre, "mount", *args], capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"mount {' '.join(args)} failed: {p.stderr.strip()}")


def _umount(path: Path) -> None:
    pre = root_cmd() or []
    subprocess.run([*pre, "umount", "-l", str(path)], capture_output=True)


class SmallDisk:
    """A tmpfs of ``size_kb`` mounted at ``path``; ``fill()`` leaves only ``leave`` bytes free."""

    FILLER = ".filler"

    def __init__(self, path: Path, size_kb: int):
        self.path = path
        self.size_kb = size_kb

    def free(self) -> int:
        st = os.statvfs(self.path)
        return st.f_bavail * st.f_frsize

    def fill(self, leave: int = 0) -> None:
        """Take up the free space with a filler file, leaving about ``leave`` bytes (page-rounded)."""
        filler = self.path / self.FILLER
        fd = os.open(filler, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        block = b"\0" * 4096
        try:
            while True:
                os.write(fd, block)
        except OSError:
            pass
        finally:
            os.close(fd)
        if leave:
            size = filler.stat().st_size
            os.truncate(filler, max(0, size - leave))

    def free_up(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            (self.path / self.FILLER).unlink()

    def read_only(self, on: bool = True) -> None:
        """Remount it read-only (``on``) or writable again: what is on it stays, nothing more goes."""
        _mount(["-o", f"remount,{'ro' if on else 'rw'}", str(self.path)])

    def files(self) -> dict[str, int]:
        """Every file under the mount (but the filler) and its size: what a fault left behind."""
        out = {}
        for p in sorted(self.path.rglob("*")):
            if p.is_file() and p.name != self.FILLER:
                out[str(p.relative_to(self.path))] = p.stat().st_size
        return out


@pytest.fixture()
def small_disk(tmp_path):
    """Factory: ``small_disk(size_kb=256)`` mounts a tmpfs that size and returns a SmallDisk."""
    mounted: list[Path] = []

    def make(size_kb: int = 256, name: str = "disk") -> SmallDisk:
        d = tmp_path / name
        d.mkdir()
        _mount(["-t", "tmpfs", "-o", f"size={size_kb}k,mode=0777", "tmpfs", str(d)])
        mounted.append(d)
        return SmallDisk(d, size_kb)

    yield make
    for d in reversed(mounted):
        _umount(d)


@pytest.fixture()
def readonly_dir(tmp_path):
    """A folder on a read-only file system (root cannot write there either)."""
    d = tmp_path / "readonly"
    d.mkdir()
    _mount(["-t", "tmpfs", "-o", "size=64k,ro", "tmpfs", str(d)])
    yield d
    _umount(d)
