"""tools/ensure-debs while another apt or dpkg holds a lock (issue 19: `make test` stopped on
"Could not get lock /var/lib/dpkg/lock-frontend" while a fresh machine's automatic updates ran).

The real apt-get runs, pointed by $ENSURE_DEBS_APT_OPTS at package lists, a cache and a dpkg
status file of the test's own (no sources: nothing is fetched), so the machine's own apt is never
locked; a second process holds the lock the way apt and dpkg do (fcntl), as long as the test says.
The package asked for is in that status file only: the machine's dpkg does not know it (so the
script installs it), and apt-get finds it installed once it gets the lock (nothing is changed)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "tools" / "ensure-debs"
PACKAGE = "vts-ensure-debs-test"
STATUS = f"""Package: {PACKAGE}
Status: install ok installed
Priority: optional
Section: misc
Maintainer: nobody <nobody@localhost>
Architecture: all
Version: 1.0
Description: a package only in tests/install/test_ensure_debs.py's own dpkg status file
"""
# holds a POSIX record lock (as apt and dpkg take theirs) on each file named, for argv[1] seconds
HOLDER = """import fcntl, sys, time
files = [open(p, "a") for p in sys.argv[2:]]
for f in files:
    fcntl.lockf(f, fcntl.LOCK_EX)
print("locked", flush=True)
time.sleep(float(sys.argv[1]))
"""

pytestmark = pytest.mark.skipif(os.geteuid() != 0, reason="ensure-debs runs apt-get as root only (CI runs as root)")


@pytest.fixture()
def apt_state(tmp_path):
    """(options for apt-get, the lock files) of a package state of the test's own."""
    for d in ("lists/partial", "cache/archives/partial", "sources.list.d", "dpkg/updates"):
        (tmp_path / d).mkdir(parents=True)
    (tmp_path / "dpkg" / "status").write_text(STATUS)
    opts = " ".join(
        f"-o {k}={v}"
        for k, v in {
            "Dir::State::Lists": tmp_path / "lists",
            "Dir::Cache": tmp_path / "cache",
            "Dir::Etc::SourceList": os.devnull,
            "Dir::Etc::SourceParts": tmp_path / "sources.list.d",
            "Dir::State::status": tmp_path / "dpkg" / "status",
        }.items()
    )
    locks = {
        "lists": tmp_path / "lists" / "lock",
        "frontend": tmp_path / "dpkg" / "lock-frontend",
        "dpkg": tmp_path / "dpkg" / "lock",
    }
    return opts, locks


@pytest.fixture()
def hold():
    procs = []

    def start(seconds: float, *paths: Path) -> subprocess.Popen:
        p = subprocess.Popen(
            [sys.executable, "-c", HOLDER, str(seconds), *map(str, paths)], stdout=subprocess.PIPE, text=True
        )
        procs.append(p)
        assert p.stdout.readline().strip() == "locked"
        return p

    yield start
    for p in procs:
        p.kill()
        p.wait()


def name(proc: subprocess.Popen) -> str:
    return Path(f"/proc/{proc.pid}/comm").read_text().strip()


def ensure_debs(opts: str, *packages: str, wait: float = 60) -> tuple[subprocess.CompletedProcess, float]:
    env = {**os.environ, "ENSURE_DEBS_APT_OPTS": opts, "ENSURE_DEBS_WAIT": str(wait)}
    t0 = time.monotonic()
    p = subprocess.run([str(SCRIPT), *packages], env=env, capture_output=True, text=True, timeout=120)
    return p, time.monotonic() - t0


def test_nothing_held_installs_at_once(apt_state):
    p, took = ensure_debs(apt_state[0], PACKAGE)
    assert p.returncode == 0, p.stderr
    assert p.stderr.splitlines() == [f"ensure-debs: installing {PACKAGE}", f"ensure-debs: installed {PACKAGE}"]


@pytest.mark.parametrize(
    "held",
    [("lists",), ("frontend", "dpkg"), ("dpkg",)],
    ids=["apt-get update running", "apt-get install running", "dpkg alone running"],
)
def test_another_apt_or_dpkg_is_waited_for_then_the_install_goes_on(apt_state, hold, held):
    opts, locks = apt_state
    holder = hold(3.0, *(locks[k] for k in held))
    p, took = ensure_debs(opts, PACKAGE)
    assert p.returncode == 0, p.stderr
    lines = p.stderr.splitlines()
    assert lines[0] == f"ensure-debs: installing {PACKAGE}"
    assert lines[1] == (
        f"ensure-debs: another apt or dpkg is running (Could not get lock {locks[held[0]]}. "
        f"It is held by process {holder.pid} ({name(holder)})): waiting up to 60 s for it to finish"
    )
    assert lines[2].startswith("ensure-debs: the lock is free after ") and lines[2].endswith(" s; going on")
    assert lines[-1] == f"ensure-debs: installed {PACKAGE}"
    assert took >= 2.0  # it waited for the holder (3 s from before it started)
    assert holder.poll() is not None


def test_a_lock_held_past_the_wait_gives_up_in_one_sentence(apt_state, hold):
    opts, locks = apt_state
    holder = hold(60.0, locks["frontend"])
    p, took = ensure_debs(opts, PACKAGE, wait=3)
    assert p.returncode == 1
    assert p.stderr.splitlines()[-1] == (
        f"ensure-debs: gave up after 3 s: another apt or dpkg still holds the lock (Could not get lock "
        f"{locks['frontend']}. It is held by process {holder.pid} ({name(holder)})); let it finish (or stop it), "
        "then run make again (ENSURE_DEBS_WAIT=SECONDS waits longer)"
    )
    assert "Traceback" not in p.stderr and 3 <= took < 30
    assert holder.poll() is None  # the holder was left alone


def test_nothing_missing_touches_no_lock(apt_state, hold):
    opts, locks = apt_state
    hold(60.0, *locks.values())
    p, took = ensure_debs(opts, "bash", "dpkg", wait=1)
    assert p.returncode == 0 and p.stderr == "" and took < 10
