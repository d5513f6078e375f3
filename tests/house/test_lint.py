"""ruff on the tree (issue 34 §5): `ruff check` with the project's configuration ([tool.ruff] in
pyproject.toml: the rules E4 E7 E9 F I UP B at 120 columns) finds nothing, and `ruff format
--check` would change no file. docs/decisions/0104-ruff.md; how to run it: docs/develop/checks.md.

ruff is run as the dev extra installs it (`python -m ruff`), on the checkout (its .gitignore and
the default exclusions say what is left out: .venv, firmware/build, site/ ...), without its cache
(nothing written into the checkout). A third test plants findings in a scratch folder with the
project's configuration and sees both checks fail naming them, and only them: the configuration is the one
used (ruff's own default set would also report the generator in list(), C400, and its 88 columns
would split the def's line; the zip() without strict=, B905, is ignored by it)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
RUFF = [sys.executable, "-m", "ruff"]
SHOWN = 200  # the findings printed when the check fails (the count is always given)


def ruff(*args: str, cwd: Path = REPO) -> subprocess.CompletedProcess:
    return subprocess.run([*RUFF, *args, "--no-cache"], cwd=cwd, capture_output=True, text=True, timeout=300)


def shown(p: subprocess.CompletedProcess) -> str:
    lines = (p.stdout + p.stderr).splitlines()
    more = f"\n... and {len(lines) - SHOWN} more lines" if len(lines) > SHOWN else ""
    return "\n".join(lines[:SHOWN]) + more


def test_ruff_check_finds_nothing_in_the_tree():
    p = ruff("check", "--output-format", "concise", ".")
    print(p.stdout, p.stderr)
    assert p.returncode == 0, "ruff check (fix what it cannot fix itself; `ruff check --fix` the rest):\n" + shown(p)


def test_the_tree_is_ruff_formatted():
    p = ruff("format", "--check", "--output-format", "concise", ".")  # a line a file (the default shows each diff)
    print(p.stdout, p.stderr)
    assert p.returncode == 0, "ruff format --check (`ruff format FILE` writes them):\n" + shown(p)


PLANTED = """\
import sys
import os


def callbacks(names):
    out = []
    for name in names:
        out.append(lambda: name.upper())
    return out


def pairs(a, b):
    return list(x for x in zip(a, b))


def fits_in_120(a_long_argument_name, another_long_argument_name, a_third_one, a_fourth_one):
    return (a_long_argument_name, another_long_argument_name, a_third_one, a_fourth_one, os.sep,
            sys.argv)
"""


def test_planted_findings_fail_both_checks_with_the_projects_configuration(tmp_path):
    shutil.copy(REPO / "pyproject.toml", tmp_path / "pyproject.toml")
    (tmp_path / "planted.py").write_text(PLANTED)
    p = ruff("check", "--output-format", "concise", ".", cwd=tmp_path)
    assert p.returncode == 1, p.stdout + p.stderr
    found = {line.split(": ", 1)[1].split()[0] for line in p.stdout.splitlines() if line.startswith("planted.py:")}
    # the unsorted imports, the loop variable in a closure; not B905 (ignored) nor C400 (not selected,
    # ruff's own default set reports it)
    assert found == {"I001", "B023"}, p.stdout
    p = ruff("format", "--check", "--output-format", "concise", ".", cwd=tmp_path)
    assert p.returncode == 1 and p.stdout.startswith("planted.py:"), p.stdout + p.stderr
    # at 120 columns the def's line stays as it is: the return's continuation alone is reformatted
    p = ruff("format", "--diff", ".", cwd=tmp_path)
    changed = [line for line in p.stdout.splitlines() if line.startswith(("-", "+")) and line[:3] not in ("---", "+++")]
    assert changed == [
        "-    return (a_long_argument_name, another_long_argument_name, a_third_one, a_fourth_one, os.sep,",
        "-            sys.argv)",
        "+    return (a_long_argument_name, another_long_argument_name, a_third_one, a_fourth_one, os.sep, sys.argv)",
    ], p.stdout
