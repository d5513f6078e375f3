"""docs/faults.md: every row names a test, and that test exists (a row is a test)."""

import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ROW = re.compile(r"^\|(.+)\|\s*$")
NODE = re.compile(r"(tests/\w+/test_\w+\.py)::(\w+)")


def rows():
    out = []
    for line in (REPO / "docs" / "faults.md").read_text().splitlines():
        m = ROW.match(line)
        if not m or set(line) <= set("|-: "):
            continue
        cells = [c.strip() for c in m.group(1).split("|")]
        if cells[0] in ("fault or bad input", "fault (sim)"):
            continue
        out.append(cells)
    return out


def test_every_row_is_a_test_that_exists():
    found = rows()
    assert len(found) >= 80, len(found)
    defined: dict[str, set[str]] = {}
    for cells in found:
        assert len(cells) == 5, cells
        nodes = NODE.findall(cells[-1])
        assert nodes, f"row without a test: {cells[0]}"
        for path, name in nodes:
            if path not in defined:
                tree = ast.parse((REPO / path).read_text())
                defined[path] = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
            assert name in defined[path], f"{cells[0]}: {path}::{name} does not exist"


def test_every_exit_code_is_documented():
    allowed = {"0", "2", "3", "4", "5", "10", "20", "130", "–", "-"}
    for cells in rows():
        codes = set(re.findall(r"\d+|–|-", cells[2]))
        assert codes, cells
        assert codes <= allowed | {"1"}, cells  # 1 only for a sim that fails for an unforeseen reason


def _table_text() -> str:
    return (REPO / "docs" / "faults.md").read_text()


def test_every_fault_the_simulated_camera_injects_has_a_row():
    from dataclasses import fields

    from vts_hw.sim_devices.faults import Faults

    text = _table_text()
    settings = {"version", "stall_s", "torn_mode", "wrong_content_length_extra", "trickle_s"}  # they tune a fault
    knobs = [f.name for f in fields(Faults) if f.name not in settings]
    assert len(knobs) >= 10
    missing = [k for k in knobs if f"`{k}`" not in text]
    assert not missing, f"docs/faults.md has no row for the camera fault(s) {missing}"


def test_every_fault_the_simulated_qatrack_injects_has_a_row():
    from vts_hw.sim_devices.qatrack_server import FAULTS

    text = _table_text()
    missing = [k for k in FAULTS if not re.search(rf"sim `[^`]*\b{re.escape(k)}\b", text)]
    assert not missing, f"docs/faults.md has no row for the QATrack+ fault(s) {missing}"


def test_every_test_the_threat_model_names_exists():
    """docs/security.md: each threat's test exists (``file.py::name``, ``**abbr**::name`` for a file
    it abbreviates as "`file.py` (**abbr**)", and ``::name`` for another test of the file named
    just before it in the same cell)."""
    text = (REPO / "docs" / "security.md").read_text()
    abbr = dict((a, f) for f, a in re.findall(r"`(tests/\w+/test_\w+\.py)` \(\*\*(\w+)\*\*\)", text))
    defined: dict[str, set[str]] = {}
    named, header = 0, None
    for line in text.splitlines():
        m = ROW.match(line)
        if not m:
            header = None  # a table ended
            continue
        if set(line) <= set("|-: "):
            continue
        cells = [c.strip() for c in m.group(1).split("|")]
        if header is None:
            header = cells[0]
            continue
        if header != "threat":  # (the roles' table)
            continue
        assert len(cells) == 3, cells
        last = None
        for f, a, name in re.findall(r"(?:(tests/\w+/test_\w+\.py)|\*\*(\w+)\*\*)?::(\w+)", cells[2]):
            path = f or abbr.get(a) or last
            assert path, f"{cells[0]}: ::{name} names no file"
            last = path
            if path not in defined:
                tree = ast.parse((REPO / path).read_text())
                defined[path] = {n.name for n in ast.walk(tree) if isinstance(n, ast.FunctionDef)}
            assert name in defined[path], f"{cells[0]}: {path}::{name} does not exist"
            named += 1
        assert "test_" in cells[2] or "::" in cells[2], f"a threat without a test: {cells[0]}"
    assert named >= 40, named
