"""The test modules are handed out longest first, the real QATrack+'s at half time
(tests/module_order.py, decision 0077)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import module_order
from module_order import longest_first


def _items(spec):
    return [SimpleNamespace(nodeid=f"{m}::t{i}") for m, n in spec for i in range(n)]


def test_longest_module_first_its_own_order_kept_and_the_late_one_at_half_time(tmp_path, monkeypatch):
    table = tmp_path / "durations.json"
    table.write_text(json.dumps({"a.py": 10, "b.py": 100, "c.py": 40, "late.py": 30, "d.py": 5}))
    monkeypatch.setattr(module_order, "TABLE", table)
    items = _items([("a.py", 2), ("b.py", 1), ("late.py", 2), ("c.py", 3), ("d.py", 1), ("new.py", 20)])
    got = longest_first(items, late={"late.py"})
    modules = list(dict.fromkeys(i.nodeid.split("::")[0] for i in got))
    # new.py: not in the table, 20 tests at PER_TEST_S each (14 s); half of 199 s is handed out after b
    assert modules == ["b.py", "late.py", "c.py", "new.py", "a.py", "d.py"]
    assert [i.nodeid for i in got if i.nodeid.startswith("c.py")] == ["c.py::t0", "c.py::t1", "c.py::t2"]
    assert sorted(i.nodeid for i in got) == sorted(i.nodeid for i in items)


def test_without_a_table_the_modules_with_most_tests_go_first(tmp_path, monkeypatch):
    monkeypatch.setattr(module_order, "TABLE", tmp_path / "missing.json")
    got = longest_first(_items([("a.py", 1), ("b.py", 3), ("c.py", 2)]))
    assert list(dict.fromkeys(i.nodeid.split("::")[0] for i in got)) == ["b.py", "c.py", "a.py"]


def test_the_table_names_modules_that_exist():
    table = module_order.estimates()
    root = module_order.TABLE.parent.parent
    assert all((root / m).is_file() for m in table), [m for m in table if not (root / m).is_file()]
