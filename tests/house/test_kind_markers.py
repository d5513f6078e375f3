"""The kinds as markers (decision 0105): -m decides whether a session can reach the real
QATrack+'s module, so that `pytest -n 2 -m unit` starts no QATrack+ install in the background
while `-m "not slow"` (which does reach it) still does (tests/conftest.py)."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import conftest
from conftest import REAL_QATRACK_MARKS, _selects


@pytest.mark.parametrize(
    "expr, reaches",
    [
        ("", True),
        ("interop", True),
        ("real_qatrack", True),
        ("not slow", True),
        ("unit or interop", True),
        ("not (unit or console)", True),
        ("unit", False),
        ("console", False),
        ("(unit or house) and not slow", False),
        ("not real_qatrack", False),
        ("interop and not real_qatrack", False),
        ("unit and", True),  # not an expression it reads: as if it could
    ],
)
def test_the_mark_expression_is_read_for_the_real_qatrack_module(expr, reaches):
    assert _selects(expr, REAL_QATRACK_MARKS) is reaches


def test_the_marks_it_reads_are_the_real_qatrack_modules_own():
    """REAL_QATRACK_MARKS is what tests/interop/test_qatrack_real.py is marked with (its
    pytest.mark.* and its kind): a mark added there and not here (slow, say) would make
    `-m slow` select the module without starting the server its tests wait for."""
    module = Path(conftest.__file__).parent / "interop" / "test_qatrack_real.py"
    marks = {
        node.attr
        for node in ast.walk(ast.parse(module.read_text()))
        if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Attribute) and node.value.attr == "mark"
    }
    assert marks | {module.parent.name} == REAL_QATRACK_MARKS


def _loose(tests: Path, kinds: set[str]) -> list[str]:
    """The test modules under ``tests`` outside a kind's folder (tests/KIND/test_x.py): they would
    be marked with no kind, so that `pytest -m unit or integration or ...` leaves them out."""
    return sorted(
        str(p.relative_to(tests)) for p in tests.rglob("test_*.py") if p.relative_to(tests).parts[0] not in kinds
    )


def test_every_test_module_is_in_a_kinds_folder(tmp_path, pytestconfig):
    assert _loose(Path(conftest.__file__).parent, conftest.kinds(pytestconfig)) == []
    (tmp_path / "unit").mkdir()
    (tmp_path / "unit" / "test_a.py").write_text("")
    (tmp_path / "test_b.py").write_text("")  # (a module added where they all were before decision 0105)
    assert _loose(tmp_path, conftest.kinds(pytestconfig)) == ["test_b.py"]
