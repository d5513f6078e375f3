"""No child outlives its command (issue 32 §3): a program the product starts (avrdude, make, the
firmware emulator, an alert command) is killed by the kernel when the command that started it
ends, ``kill -9`` included (vts_hw/lifeline.py ``child_options``, decision 0082).

The children are stopped (SIGSTOP) before their command is killed: a stopped program cannot end
by itself, so only the kernel's signal on its parent's death can take it (and the deadlines
below are hang detectors, never a measure of speed).
"""

from __future__ import annotations

import ast
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vts_hw.drivers import avrdude
from vts_hw.drivers.trigger_box_flash import check_port
from vts_hw.lifeline import alive
from vts_hw.sim_devices.trigger_box import build, firmware_dir

ROOT = Path(__file__).resolve().parents[2]
VTS = [sys.executable, "-m", "vts_hw.cli"]
HANG_S = 120.0
pytestmark = pytest.mark.timeout(300)


def _until(check, timeout=HANG_S):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = check()
        if got:
            return got
        time.sleep(0.05)
    return check()


def _children(pid: int, name: str, arg: str = "") -> list[int]:
    """The pids of the children of ``pid`` whose command name is ``name`` and whose command
    line holds the argument ``arg`` (from /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            argv = (d / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        comm, rest = stat[stat.index("(") + 1 : stat.rindex(")")], stat[stat.rindex(")") + 2 :].split()
        if comm == name and int(rest[1]) == pid and (not arg or arg.encode() in argv):
            out.append(int(d.name))
    return out


def _gone_or_kill(pid: int) -> bool:
    """Whether ``pid`` ended (within the hang detector's time); killed here if not, so that no
    test leaves a stopped program behind."""
    gone = bool(_until(lambda: not alive(pid)))
    if not gone:
        os.kill(pid, signal.SIGKILL)
    return gone


def test_a_child_started_with_child_options_dies_with_its_command_killed_by_kill_9():
    code = (
        "import subprocess, sys\n"
        "from vts_hw.lifeline import child_options\n"
        "p = subprocess.Popen(['sleep', '600'], **child_options())\n"
        "print(p.pid, flush=True)\n"
        "p.wait()\n"
    )
    cmd = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    child = int(cmd.stdout.readline())
    os.kill(child, signal.SIGSTOP)
    cmd.kill()
    cmd.wait(timeout=30)
    assert _gone_or_kill(child), "the child outlived its command's kill -9"


@pytest.fixture(scope="module")
def hex_file(tmp_path_factory):
    build()
    d = tmp_path_factory.mktemp("fw")
    shutil.copy(firmware_dir() / "build" / "trigger_box.hex", d / "trigger_box.hex")
    return d / "trigger_box.hex"


def test_kill_9_of_trigger_flash_takes_its_avrdude_and_frees_the_port(hex_file):
    """avrdude talking to a board that never answers (a pty nobody reads: it tries to sync for
    up to 10 attempts); `vts trigger flash` killed with SIGKILL meanwhile: avrdude goes with it
    and the port can be opened and locked again."""
    master, slave = os.openpty()
    port = os.ttyname(slave)
    p = subprocess.Popen(
        [*VTS, "trigger", "flash", "--port", port, "--hex", str(hex_file), "--attempts", "10"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        stdin=subprocess.DEVNULL,
    )
    try:
        found = _until(lambda: _children(p.pid, "avrdude", "-U") or p.poll() is not None)
        avr = _children(p.pid, "avrdude", "-U")  # the upload (not `avrdude -?`, asked for its version)
        assert avr, f"no avrdude started (exit {p.poll()}): {p.stderr.read().decode()[-1000:] if p.poll() else ''}"
        assert found
        os.kill(avr[0], signal.SIGSTOP)
        p.kill()
        p.wait(timeout=30)
        assert _gone_or_kill(avr[0]), "avrdude outlived `vts trigger flash` killed with SIGKILL"
        fd = check_port(port)  # opened and flock'ed as pyserial's exclusive mode does
        os.close(fd)
    finally:
        if p.poll() is None:
            p.kill()
            p.wait()
        os.close(master)
        os.close(slave)


# -- every program the product starts ------------------------------------------------------------
STARTS = {"Popen", "run", "call", "check_call", "check_output"}
#: the one program meant to outlive the command that starts it (`vts sim up --detach`)
MEANT_TO_OUTLIVE = {("sim_devices/rig_detached.py", "start_detached")}


def _starts_without_child_options():
    found = []
    for folder in ("vts_hw", "drivers", "procedures", "sim_devices"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            text = path.read_text()
            if "subprocess" not in text:
                continue
            tree = ast.parse(text, str(path))
            funcs = {}
            for fn in ast.walk(tree):
                if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    for node in ast.walk(fn):
                        funcs.setdefault(id(node), fn.name)
            for node in ast.walk(tree):
                if not (
                    isinstance(node, ast.Call)
                    and isinstance(node.func, ast.Attribute)
                    and node.func.attr in STARTS
                    and isinstance(node.func.value, ast.Name)
                    and node.func.value.id == "subprocess"
                ):
                    continue
                rel = str(path.relative_to(ROOT))
                if (rel, funcs.get(id(node))) in MEANT_TO_OUTLIVE:
                    continue
                spread = [k.value for k in node.keywords if k.arg is None]
                if not any(isinstance(v, ast.Call) and getattr(v.func, "id", "") == "child_options" for v in spread):
                    found.append(f"{rel}:{node.lineno}")
    return found


def test_every_program_the_product_starts_dies_with_its_command():
    """Every subprocess.Popen/run/... in vts_hw, drivers, procedures and sim_devices passes
    ``**child_options()`` (the detached simulated rig alone is meant to outlive `vts sim up`)."""
    assert _starts_without_child_options() == []


def test_the_check_sees_a_start_without_child_options(tmp_path, monkeypatch):
    (tmp_path / "vts_hw").mkdir()
    (tmp_path / "vts_hw" / "x.py").write_text(
        "import subprocess\nsubprocess.run(['true'])\nsubprocess.run(['true'], **child_options())\n"
    )
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert _starts_without_child_options() == ["vts_hw/x.py:2"]


@pytest.mark.parametrize("ask", ["version", "programmers"])
def test_an_avrdude_that_hangs_when_asked_is_one_sentence_and_leaves_nothing_running(tmp_path, monkeypatch, ask):
    """avrdude's version and programmers are asked before a flash: a broken one that never
    answered was a TimeoutExpired traceback; now exit 2 in one sentence, the program ended."""
    pidfile = tmp_path / "pid"
    fake = tmp_path / "avrdude"
    fake.write_text(f"#!/bin/sh\necho $$ > {pidfile}\nexec sleep 600\n")
    fake.chmod(0o755)
    monkeypatch.setattr(avrdude, "ASK_S", 0.5)
    with pytest.raises(avrdude.AvrdudeBroken) as got:
        getattr(avrdude, ask)(str(fake))
    assert got.value.exit_code == 2 and "did not answer within 0.5 s" in str(got.value)
    pid = int(pidfile.read_text())
    assert _until(lambda: not alive(pid), 30), "the hung avrdude is still running"
