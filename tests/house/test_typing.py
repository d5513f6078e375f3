"""mypy on the package's clean part (issue 34 §5): the folders and modules in CLEAN pass mypy
with the project's configuration ([tool.mypy] in pyproject.toml), run as tools/typecheck.py
runs it (a tree of links where drivers/ is vts_hw/drivers ..., setup.py's PACKAGE_DIR; the
modules they import are read, their own errors not reported). docs/decisions/0098-mypy.md.

CLEAN is meant to grow to the whole package: a folder goes in once `python tools/typecheck.py
FOLDER` says "Success". Measured on 2026-11-29 (`python tools/typecheck.py`, the whole package):
620 errors in 139 files before this test, 493 in 111 files once its first part was clean; then
489 in 109 files before the second part (store/, report/, qatrack/, vision/, spect/, timing/,
tracking/, console/, room/, drivers/, procedures/, sim_devices/ but the modules of NOT_YET) and
59 in 9 files after it — all in the modules of NOT_YET; then 0 in 331 source files once those
nine were clean (NOT_YET is empty: the whole package passes).

A new module of vts_hw/'s top level or of any folder in CLEAN is in CLEAN from its first commit."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

CLEAN = (
    "drivers",
    "procedures",
    "sim_devices",
    "vts_hw/*.py",
    "vts_hw/cli",
    "vts_hw/console",
    "vts_hw/motion",
    "vts_hw/qatrack",
    "vts_hw/recording",
    "vts_hw/report",
    "vts_hw/room",
    "vts_hw/spect",
    "vts_hw/store",
    "vts_hw/timing",
    "vts_hw/tracking",
    "vts_hw/vision",
)
NOT_YET: dict[str, str] = {}  # module -> what it waits on (none now: the whole package is clean)


def clean_paths() -> list[str]:
    """CLEAN with its globs expanded and NOT_YET's modules left out (a folder in CLEAN that
    holds one is given module by module)."""
    out: list[str] = []
    for entry in CLEAN:
        if "*" in entry:
            out += sorted(p.relative_to(REPO).as_posix() for p in REPO.glob(entry))
        elif any(n.startswith(entry + "/") for n in NOT_YET):
            out += sorted(p.relative_to(REPO).as_posix() for p in (REPO / entry).rglob("*.py"))
        else:
            out.append(entry)
    return [p for p in out if p not in NOT_YET]


@pytest.fixture(scope="module")
def typecheck():
    spec = importlib.util.spec_from_file_location("typecheck", REPO / "tools" / "typecheck.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def tree(typecheck, tmp_path_factory):
    """The link tree and mypy's cache, kept for the module's two runs."""
    root = tmp_path_factory.mktemp("typecheck")
    return root, typecheck.link_tree(root)


def test_the_clean_part_of_the_package_passes_mypy(typecheck, tree):
    root, prefixes = tree
    p = typecheck.mypy(clean_paths(), root, prefixes)
    assert p.returncode == 0, f"mypy found errors in the clean part (exit {p.returncode}):\n{p.stdout}{p.stderr}"
    assert "Success: no issues found" in p.stdout, p.stdout + p.stderr


def test_a_type_error_planted_in_the_clean_part_fails_the_check(typecheck, tree):
    """The check can fail: a module of the clean part with a wrong type added (a copy in the link
    tree, the checkout untouched) is named with its line and error code."""
    root, prefixes = tree
    planted = root / "vts_hw" / "save_or_keep.py"
    source = REPO / "vts_hw" / "save_or_keep.py"
    text = source.read_text(encoding="utf-8")
    planted.unlink()
    try:
        planted.write_text(text + '\n\nPLANTED: int = "not a number"\n', encoding="utf-8")
        p = typecheck.mypy(clean_paths(), root, prefixes)
    finally:
        planted.unlink()
        planted.symlink_to(source)
    line = len((text + "\n\n").splitlines()) + 1
    assert p.returncode == 1, p.stdout + p.stderr
    assert f"vts_hw/save_or_keep.py:{line}: error: Incompatible types in assignment" in p.stdout, p.stdout
    assert "[assignment]" in p.stdout and "Found 1 error in 1 file" in p.stdout, p.stdout


def test_the_link_tree_maps_each_folder_where_the_package_has_it(typecheck, tree):
    root, prefixes = tree
    assert (root / "vts_hw" / "drivers").resolve() == REPO / "drivers"
    assert (root / "vts_hw" / "procedures").resolve() == REPO / "procedures"
    assert (root / "vts_hw" / "errors.py").resolve() == REPO / "vts_hw" / "errors.py"
    assert typecheck.in_tree("drivers/axis.py", prefixes) == "vts_hw/drivers/axis.py"
    with pytest.raises(ValueError, match="tests/house/test_typing.py: not in the package's folders"):
        typecheck.in_tree("tests/house/test_typing.py", prefixes)
    assert (
        typecheck.back_to_checkout("vts_hw/drivers/axis.py:3: error: x\nvts_hw/cli/qa.py:1: note: y", prefixes)
        == "drivers/axis.py:3: error: x\nvts_hw/cli/qa.py:1: note: y"
    )


def uncovered(modules: list[str]) -> list[str]:
    """The modules (paths in the checkout) neither in the clean part nor waiting in NOT_YET."""
    covered = clean_paths() + list(NOT_YET)
    return [m for m in modules if not any(m == c or m.startswith(c + "/") for c in covered)]


def test_every_module_of_the_package_is_checked_or_said_to_wait(typecheck):
    """CLEAN names folders: a new folder of vts_hw/ (vts_hw/newthing/) would be in none and never
    type-checked while this test passed. Every module of the package's folders (setup.py's
    PACKAGE_DIR, as tools/typecheck.py reads it) is in CLEAN or in NOT_YET."""
    modules = sorted(
        p.relative_to(REPO).as_posix()
        for folder in typecheck.package_dir().values()
        for p in (REPO / folder).rglob("*.py")
    )
    assert len(modules) > 300 and uncovered(modules) == []
    assert uncovered(["vts_hw/newthing/__init__.py", "vts_hw/cli/new.py"]) == ["vts_hw/newthing/__init__.py"]
