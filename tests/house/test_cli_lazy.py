"""`vts` imports the modules of the command asked for, not all of them (decision 0076).

The map of commands to modules (vts_hw.cli.COMMANDS) must be whole: a command or subcommand
defined in a module the map does not name would be missing from `vts` while the tests that
import every module still see it. Each check runs in a fresh interpreter, as `vts` does."""

from __future__ import annotations

import json
import subprocess
import sys

SEEN = r"""
import atexit, json, sys
def seen():
    print(json.dumps({"cli": sorted(m for m in sys.modules if m.startswith("vts_hw.cli.")),
                      "heavy": sorted(m for m in ("numpy", "scipy", "cv2", "matplotlib", "sqlalchemy")
                                      if m in sys.modules)}))
atexit.register(seen)
from vts_hw.cli import main
main(sys.argv[1:])
"""

TREE = r"""
import importlib, json, pkgutil, click
import vts_hw.cli as c
def tree(cmd):
    return {n: tree(sub) for n, sub in cmd.commands.items()} if isinstance(cmd, click.Group) else None
lazy = {name: tree(c.cli.get_command(click.Context(c.cli), name)) for name in c.COMMANDS}
for m in (m for m in pkgutil.iter_modules(c.__path__) if m.name != "__main__"):
    importlib.import_module(f"vts_hw.cli.{m.name}")
print(json.dumps({"lazy": lazy, "all": tree(c.cli)}))
"""


def _run(code: str, *args: str) -> dict:
    r = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_every_command_and_subcommand_is_reached_through_the_map():
    got = _run(TREE)
    assert got["lazy"] == got["all"], "a module of vts_hw.cli defines a command the COMMANDS map does not load"
    assert {"aim", "setup", "snapshot"} <= set(got["lazy"]["camera"])  # from three modules
    assert "flash" in got["lazy"]["trigger"] and "daily" in got["lazy"]["qa"]


def test_a_command_whose_first_module_was_imported_alone_still_has_all_its_subcommands():
    """Importing one module of a command (``vts_hw.cli.qa``, as a test or a plugin may) registers
    the command; its other modules (``qa_steps``: ``vts qa steps``) are still loaded when it is
    looked up (the map was followed only for a command not yet registered)."""
    code = (
        "import click, json, vts_hw.cli.qa, vts_hw.cli as c\n"
        "print(json.dumps(sorted(c.cli.get_command(click.Context(c.cli), 'qa').commands)))"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert "steps" in json.loads(r.stdout.strip().splitlines()[-1])


def test_a_command_loads_its_own_modules_only():
    got = _run(SEEN, "scan", "--help")
    assert "vts_hw.cli.scan" in got["cli"]
    assert not {"vts_hw.cli.calibrate", "vts_hw.cli.console", "vts_hw.cli.commission"} & set(got["cli"]), got
    assert "scipy" not in got["heavy"] and "matplotlib" not in got["heavy"], got


def test_help_of_vts_lists_every_command_and_an_unknown_one_is_refused():
    r = subprocess.run([sys.executable, "-m", "vts_hw.cli", "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0
    listed = r.stdout.split("Commands:")[1].split()
    from vts_hw.cli import COMMANDS

    assert all(name in listed for name in COMMANDS), r.stdout
    r = subprocess.run([sys.executable, "-m", "vts_hw.cli", "scna"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "No such command 'scna'" in r.stderr and "Traceback" not in r.stderr


def test_a_refused_console_loads_none_of_its_pages():
    """`vts console` refuses what the command line alone says is wrong (serve_checks.py) before
    the console's server and pages are imported: a refusal is one sentence, not a start-up."""
    code = SEEN.replace(
        '"cli": sorted(m for m in sys.modules if m.startswith("vts_hw.cli."))',
        '"cli": sorted(m for m in sys.modules if m.startswith("vts_hw.console"))',
    )
    r = subprocess.run(
        [sys.executable, "-c", code, "console", "--host", "0.0.0.0", "--port", "0"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and "refused to serve the console on 0.0.0.0" in r.stderr, r.stderr[-2000:]
    loaded = set(json.loads(r.stdout.strip().splitlines()[-1])["cli"])
    assert "vts_hw.console.serve_checks" in loaded
    assert not {"vts_hw.console.serve", "vts_hw.console.app", "vts_hw.console.qa_page"} & loaded, sorted(loaded)


def test_the_consoles_pages_load_no_plotting_library_until_a_plot_is_drawn():
    """The console's server and every page import without matplotlib (0.6 s of every console
    start): the QA page's drift plot takes the report package's name, loaded when first drawn."""
    code = (
        "import json, sys\nimport vts_hw.console.app, vts_hw.console.serve\n"
        "print(json.dumps(sorted(m for m in ('matplotlib', 'vts_hw.report.plots') if m in sys.modules)))"
    )
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads(r.stdout.strip().splitlines()[-1]) == []
