"""The simulated rig run detached, for a folder: started in the background (``vts sim up
--detach --dir DIR``: ``python -m vts_hw.sim_devices.rig``, which serves until stopped), found
again by its pid file, stopped (``vts sim down``); the variables of its ``sim.env``.

Nothing here imports the scene or its devices: stopping a rig, or asking whether one runs,
loads no more than this (the rig itself is :mod:`vts_hw.sim_devices.rig`).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from vts_hw.errors import UsageError, VtsError
from vts_hw.files import WriteFailed, ensure_dir, open_writable, os_reason
from vts_hw.lifeline import alive
from vts_hw.sim_devices.rig_log import NOTHING_LOGGED, disk_full, failure_cause

PID_FILE = "sim.pid"
LOG_FILE = "sim.log"
READY_FILE = "rig.yaml"
FOLDER = "simulated rig folder"
_children: dict[int, subprocess.Popen] = {}  # started from this process: reaped on stop


def start_detached(
    folder: str | Path,
    n_cameras: int = 2,
    seed: int = 0,
    firmware: str = "vapix3",
    rate: float = 1.0,
    timeout: float = 60.0,
    trigger: str = "none",
    spect: bool = False,
    https: bool = False,
    gantry: bool = False,
    patient=None,
    qatrack: bool = False,
    ahead: float = 0.0,
    warmup_drift: bool = False,
    announce: bool = False,
) -> int:
    """Start ``serve`` in a background process; return its pid once rig.yaml is written (the
    time allowed grows by 0.1 s per frame made ``ahead``)."""
    timeout += 0.1 * ahead * 25.0 * n_cameras
    folder = ensure_dir(Path(folder).resolve(), FOLDER, mode=0o700)
    if is_running(folder):
        raise already_running(folder)
    for name in (READY_FILE, PID_FILE):
        with contextlib.suppress(FileNotFoundError):
            (folder / name).unlink()
    log_path = folder / LOG_FILE
    had_log = log_path.exists()
    try:  # the first line of this start, on disk before the rig starts: a full disk stops here
        log = open_writable(log_path, "ab")  # never a device, FIFO or symbolic link (files.py)
        log_start = log.tell()
        log.write(f"{time.strftime('%Y-%m-%dT%H:%M:%S%z')} vts sim up: starting ({n_cameras} cameras)\n".encode())
        log.flush()
        os.fsync(log.fileno())
    except OSError as e:
        with contextlib.suppress(OSError, UnboundLocalError):
            log.close()
        with contextlib.suppress(OSError, UnboundLocalError):  # no cut line, no empty log left behind
            if had_log:
                os.truncate(log_path, log_start)
            else:
                log_path.unlink()
        raise WriteFailed(log_path, os_reason(e), "the log is as it was" if had_log else "no log was left") from None
    cmd = (
        [
            sys.executable,
            "-m",
            "vts_hw.sim_devices.rig",
            str(folder),
            str(n_cameras),
            str(seed),
            firmware,
            str(rate),
            trigger,
        ]
        + (["spect"] if spect else [])
        + (["https"] if https else [])
        + (["gantry"] if gantry else [])
        + (["qatrack"] if qatrack else [])
        + ([patient.to_arg()] if patient is not None else [])
        + ([f"ahead={ahead!r}"] if ahead > 0 else [])
        + (["warmup"] if warmup_drift else [])
        + (["announce"] if announce else [])
    )
    # the one program meant to outlive the command that starts it (`vts sim up --detach`: until
    # `vts sim down`); its own children (the firmware emulator) die with it (lifeline.child_options)
    proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=log, start_new_session=True)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if (folder / READY_FILE).exists():
            _children[proc.pid] = proc
            return proc.pid
        if proc.poll() is not None:
            log.close()
            cause = failure_cause(log_path, log_start)
            if proc.returncode == 3 and cause == NOTHING_LOGGED and disk_full(folder):
                cause = f"{folder}: no space left on device"
            err = VtsError(
                f"the simulated rig failed to start (exit {proc.returncode}): {cause} (the whole log: {log_path})"
            )
            if proc.returncode in (2, 3, 4):  # the cause was one of ours: keep its exit code
                err.exit_code = proc.returncode
            raise err
        time.sleep(0.05)
    proc.kill()
    proc.wait()
    log.close()
    raise VtsError(
        f"the simulated rig did not come up within {timeout:g} s; its log {log_path} ends: "
        f"{failure_cause(log_path, log_start)}"
    )


def already_running(folder: Path) -> UsageError:
    return UsageError(
        f"a simulated rig is already running in {folder}: stop it first "
        f"(vts sim down --dir {folder}) or give another --dir"
    )


def pid_of(folder: Path) -> int | None:
    try:
        return int((folder / PID_FILE).read_text().strip())
    except (OSError, ValueError):
        return None


def is_running(folder: str | Path) -> bool:
    pid = pid_of(Path(folder))
    return pid is not None and alive(pid)


def stop_detached(folder: str | Path, timeout: float = 10.0) -> bool:
    """Stop the rig started in ``folder``; False when none was running."""
    folder = Path(folder)
    pid = pid_of(folder)
    if pid is None or not is_running(folder):
        with contextlib.suppress(OSError):  # absent, or DIR is not a folder at all
            (folder / PID_FILE).unlink()
        return False
    os.kill(pid, signal.SIGTERM)
    child = _children.pop(pid, None)
    if child is not None:
        try:
            child.wait(timeout)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not alive(pid):
            break
        time.sleep(0.05)
    else:
        os.kill(pid, signal.SIGKILL)
    with contextlib.suppress(FileNotFoundError):
        (folder / PID_FILE).unlink()
    return True


def load_env_file(path: str | Path) -> dict[str, str]:
    """The variables of a sim.env file."""
    out = {}
    for line in Path(path).read_text().splitlines():
        line = line.strip()
        if line.startswith("export ") and "=" in line:
            k, v = line[len("export ") :].split("=", 1)
            out[k.strip()] = v.strip().strip("'\"")
    return out


__all__ = [
    "PID_FILE",
    "LOG_FILE",
    "READY_FILE",
    "FOLDER",
    "start_detached",
    "stop_detached",
    "is_running",
    "pid_of",
    "already_running",
    "load_env_file",
]
