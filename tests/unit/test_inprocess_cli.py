"""tests/inprocess_cli.run(): `vts` in the test's process gives what a process of its own would
(decision 0103): its log, Python's warnings and a thread's uncaught exception on its stderr (a
converted test's ``stderr == ""`` or ``"Traceback" not in stderr`` can fail on them, as it could
with a subprocess), and the environment, working folder and hooks as they were afterwards."""

from __future__ import annotations

import logging
import os
import sys
import threading
import warnings

import inprocess_cli


def _command(argv):
    """A command as vts_hw.cli.main runs one: the log set up as `vts` sets it (without -v)."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("vts_hw.somewhere").warning("the rig answered late")
    logging.getLogger("vts_hw.somewhere").info("not shown without -v")
    warnings.warn("a number overflowed", RuntimeWarning, stacklevel=1)
    worker = threading.Thread(target=lambda: 1 / 0, name="a worker")
    worker.start()
    worker.join()
    print(f"ran {' '.join(argv)}; HOME={os.environ.get('HOME')}; here={os.getcwd()}")
    sys.exit(4)


def test_what_the_command_logs_and_warns_is_on_its_stderr(monkeypatch, tmp_path):
    monkeypatch.setattr(inprocess_cli, "main", _command)
    root = logging.getLogger()
    handlers, env, here = root.handlers[:], dict(os.environ), os.getcwd()
    hooks = threading.excepthook, sys.unraisablehook
    r = inprocess_cli.run("qa", "daily", env={"HOME": str(tmp_path)}, cwd=tmp_path)
    assert r.returncode == 4
    assert r.stdout == f"ran qa daily; HOME={tmp_path}; here={tmp_path}\n"
    assert "WARNING vts_hw.somewhere: the rig answered late\n" in r.stderr  # the CLI's format
    assert "not shown without -v" not in r.stderr
    assert "RuntimeWarning: a number overflowed" in r.stderr
    assert "Exception in thread a worker" in r.stderr and "Traceback" in r.stderr and "ZeroDivisionError" in r.stderr
    again = inprocess_cli.run("qa", "daily")  # (a warning shown again by the next command)
    assert "RuntimeWarning: a number overflowed" in again.stderr
    assert root.handlers == handlers and dict(os.environ) == env and os.getcwd() == here
    assert (threading.excepthook, sys.unraisablehook) == hooks


def test_vts_read_with_capsys_has_them_too(monkeypatch, capsys):
    monkeypatch.setattr(inprocess_cli, "main", _command)
    code, out, err = inprocess_cli.vts(capsys, "qa", "daily")
    assert code == 4 and out.startswith("ran qa daily;")
    assert "WARNING vts_hw.somewhere: the rig answered late\n" in err and "RuntimeWarning: a number overflowed" in err
    assert "Exception in thread a worker" in err and "ZeroDivisionError" in err


def test_a_message_exit_is_status_1_and_its_text_on_stderr(monkeypatch, capsys):
    def message_exit(argv):
        sys.exit("vts: gave up")

    monkeypatch.setattr(inprocess_cli, "main", message_exit)
    r = inprocess_cli.run("qa")
    assert (r.returncode, r.stderr) == (1, "vts: gave up\n")
    assert inprocess_cli.vts(capsys, "qa") == (1, "", "vts: gave up\n")
