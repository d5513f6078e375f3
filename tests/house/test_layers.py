"""The house keeps its layers: every import of the package read from the source.

config → drivers → procedures → store → reports → qatrack: a layer imports only the layers before it
(and the core everything builds on). Tracking (vts_hw/tracking/: frame sets, matching over time,
identities, tracks, the live path) sits on the core (vision, recording, timing) and under the
procedures: the rest of the core (the recording format and capture among it) never imports it.
The room (vts_hw/room/: Room.open(config), the rig's cameras, trigger, calibration, mapping and
store, each opened when first used) sits on the drivers and the store: the applications (the CLI,
the console) and the simulated scenarios open it; a procedure never does: it is given the room's
parts, as bluesky plans are given devices (docs/decisions/0099-the-room.md).
A procedure never holds a store: it returns its analysis
and the caller records it (vts_hw.store.recorder), so procedures/ importing vts_hw.store is a
failure, at any depth of the module (a function's own import too). The core imports no driver, procedure or simulator; only
the CLI and the simulated scenarios import the simulator; every import is absolute.

The imports show the design (issue 34 §3, docs/decisions/0096-imports-show-the-design.md): the
project's own modules are imported at the top of a module, never inside a function (but in the
CLI, whose command map loads a command's modules when it is asked for); the whole graph, imports
inside functions included, has no circle; a module over 500 lines is named in decision 0096 with
its one job. See docs/decisions/0028-structure.md.
"""

from __future__ import annotations

import ast
import functools
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FOLDERS = {
    "vts_hw": "vts_hw",
    "drivers": "vts_hw.drivers",
    "procedures": "vts_hw.procedures",
    "sim_devices": "vts_hw.sim_devices",
}
# what each layer may import, besides itself
ALLOWED = {
    "core": set(),
    "tracking": {"core"},
    "drivers": {"core"},
    "procedures": {"core", "drivers", "tracking"},
    "store": {"core"},
    "report": {"core", "store"},
    "qatrack": {"core", "store", "report"},  # pushing to QATrack+ reads the store and builds reports
    "sim": {"core", "tracking"},  # the simulated patient's marker tracks are Tracks
    # the room with its devices (vts_hw/room/): it opens drivers and the store; procedures get its parts
    "room": {"core", "tracking", "drivers", "store"},
    "scenarios": {"core", "tracking", "drivers", "procedures", "store", "report", "sim", "room"},
    # the room console (vts_hw/console/): an application as the CLI is, beside it, never under it
    # nor over it: it opens devices and calls procedures, the store and reports; no CLI, no simulator
    "console": {"core", "tracking", "drivers", "procedures", "store", "report", "qatrack", "room"},
    "cli": {
        "core",
        "tracking",
        "drivers",
        "procedures",
        "store",
        "report",
        "qatrack",
        "sim",
        "scenarios",
        "console",
        "room",
    },
}


def layer(module: str) -> str:
    parts = module.split(".")
    if parts[:3] == ["vts_hw", "sim_devices", "scenarios"]:
        return "scenarios"
    return {
        "drivers": "drivers",
        "procedures": "procedures",
        "sim_devices": "sim",
        "cli": "cli",
        "store": "store",
        "report": "report",
        "qatrack": "qatrack",
        "tracking": "tracking",
        "console": "console",
        "room": "room",
    }.get(parts[1] if len(parts) > 1 else "", "core")


def modules():
    for folder, package in FOLDERS.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT / folder).with_suffix("").parts
            yield path, ".".join([package, *[p for p in rel if p != "__init__"]])


@functools.cache
def tree(path: Path) -> ast.Module:
    """A module's syntax tree, read once for all the checks of this file."""
    return ast.parse(path.read_text(), str(path))


def imports(path: Path):
    for node in ast.walk(tree(path)):
        if isinstance(node, ast.ImportFrom):
            yield node.lineno, node.level, node.module or ""
        elif isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, 0, alias.name


def test_the_rules_see_every_layer():
    """The check reads real code: every layer has modules, and the CLI imports every other one."""
    seen = {layer(m) for _, m in modules()}
    assert seen == set(ALLOWED)
    cli_imports = {
        layer(t) for p, m in modules() if layer(m) == "cli" for _, _, t in imports(p) if t.startswith("vts_hw.")
    }
    assert cli_imports >= set(ALLOWED) - {"cli"}


def test_imports_go_one_way():
    wrong = []
    for path, module in modules():
        src = layer(module)
        for line, level, target in imports(path):
            if level or not target.startswith("vts_hw.") and target != "vts_hw":
                continue
            dst = layer(target) if target != "vts_hw" else "core"
            if dst != src and dst not in ALLOWED[src]:
                wrong.append(f"{path.relative_to(ROOT)}:{line} ({src}) imports {target} ({dst})")
    assert wrong == []


def test_procedures_never_hold_a_store():
    """Procedures receive what they need (a baseline, a calibration) and return their analyses;
    the recorder stores them. Any import of vts_hw.store from procedures/ fails this."""
    found = [
        f"{p.relative_to(ROOT)}:{line} imports {target}"
        for p, m in modules()
        if layer(m) == "procedures"
        for line, _, target in imports(p)
        if target == "vts_hw.store" or target.startswith("vts_hw.store.")
    ]
    assert found == []
    # nor is one handed to them: no parameter and no attribute named store
    held = []
    for p, m in modules():
        if layer(m) != "procedures":
            continue
        for node in ast.walk(tree(p)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                args = node.args.posonlyargs + node.args.args + node.args.kwonlyargs
                held += [f"{p.relative_to(ROOT)}:{node.lineno} {node.name}({a.arg})" for a in args if a.arg == "store"]
            elif isinstance(node, ast.Attribute) and node.attr == "store" and isinstance(node.value, ast.Name):
                held += [f"{p.relative_to(ROOT)}:{node.lineno} {node.value.id}.store"]
    assert held == []


def test_the_store_check_sees_an_import_of_the_store(tmp_path):
    """The check above reads function-level imports too (where a procedure would hide one)."""
    p = tmp_path / "sneaky.py"
    p.write_text("def run():\n    from vts_hw.store.recorder import record\n    import vts_hw.store\n")
    assert [t for _, _, t in imports(p)] == ["vts_hw.store.recorder", "vts_hw.store"]


def test_every_import_is_absolute():
    relative = [f"{p.relative_to(ROOT)}:{line}" for p, _ in modules() for line, level, _ in imports(p) if level]
    assert relative == []


# ------------------------------------------------------------------ one job per module, a guide

GUIDE = ROOT / "docs" / "decisions" / "0096-imports-show-the-design.md"


def long_modules_named(text: str) -> dict[str, str]:
    """The modules the guide names as over 500 lines, with their one job: the lines of its
    section "Modules over 500 lines" of the form ``- `path/to/module.py`: its one job``."""
    section = (
        text.split("## Modules over 500 lines", 1)[1].split("\n## ", 1)[0]
        if "## Modules over 500 lines" in text
        else ""
    )
    return dict(re.findall(r"^- `([^`]+\.py)`: *(\S.*)$", section, re.M))


def off_the_guide(root: Path, guide: Path) -> tuple[dict[str, int], list[str]]:
    """The modules over 500 lines the guide does not name (with their lengths), and the modules
    it names that are not there."""
    named = long_modules_named(guide.read_text())
    long = {
        str(p.relative_to(root)): n
        for folder in FOLDERS
        for p in (root / folder).rglob("*.py")
        if (n := len(p.read_text().splitlines())) > 500
    }
    return {m: n for m, n in long.items() if m not in named}, [m for m in named if not (root / m).is_file()]


def test_a_module_over_500_lines_is_named_with_its_one_job():
    """500 lines is a hint to split by job, not a cut: a longer module is named in decision 0096
    with its one job in a line; a module named there that no longer exists fails too."""
    unnamed, gone = off_the_guide(ROOT, GUIDE)
    assert unnamed == {}, f"name each in {GUIDE.relative_to(ROOT)} with its one job (or split it by job)"
    assert gone == [], f"{GUIDE.relative_to(ROOT)} names modules that are gone"
    assert all(len(job) > 10 for job in long_modules_named(GUIDE.read_text()).values())


def test_the_guide_check_sees_a_long_module_and_a_name_gone(tmp_path):
    """Planted: a module of 501 lines not named, one named, a named one that is gone; the list
    is read as written (prose and other sections are not the list)."""
    (tmp_path / "procedures").mkdir()
    (tmp_path / "procedures" / "long.py").write_text("x = 1\n" * 501)
    (tmp_path / "procedures" / "named.py").write_text("x = 1\n" * 600)
    (tmp_path / "procedures" / "short.py").write_text("x = 1\n" * 500)
    guide = tmp_path / "0096.md"
    guide.write_text(
        "# 0096\n\n## Modules over 500 lines\n\n- `procedures/named.py`: a scan, start to end\n"
        "- `procedures/gone.py`: was here\nand `procedures/long.py` in prose\n\n## After\n"
        "- `procedures/long.py`: not in the section\n"
    )
    assert long_modules_named(guide.read_text()) == {
        "procedures/named.py": "a scan, start to end",
        "procedures/gone.py": "was here",
    }
    assert off_the_guide(tmp_path, guide) == ({"procedures/long.py": 501}, ["procedures/gone.py"])


# ------------------------------------------------------------------ imports at the top, no circle

#: own imports inside a function, outside vts_hw/cli/, that stay for now: (file, module imported) ->
#: why. Each entry needs its reason; an entry no longer found fails (the list only shrinks).
INSIDE_ALLOWED: dict[tuple[str, str], str] = {}


def _type_only(node) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def own_imports_inside_functions(path: Path) -> list[tuple[int, str]]:
    """(line, module) of each import of the project's own modules inside a function (or lambda)."""
    found = []

    def visit(node, inside: bool):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)) and inside:
                names = [child.module or ""] if isinstance(child, ast.ImportFrom) else [a.name for a in child.names]
                found.extend(
                    (child.lineno, n)
                    for n in names
                    if n == "vts_hw" or n.startswith("vts_hw.") or isinstance(child, ast.ImportFrom) and child.level
                )
            visit(child, inside or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    visit(tree(path), False)
    return found


def test_own_modules_are_imported_at_the_top():
    """An import hidden in a function hides laziness, a circle or a layer crossed; only the CLI's
    command map imports its command modules when asked (and heavy third-party packages stay lazy
    where they are, which this does not look at)."""
    found = {
        (str(p.relative_to(ROOT)), t): line
        for p, m in modules()
        if layer(m) != "cli"
        for line, t in own_imports_inside_functions(p)
    }
    assert [
        f"{f}:{line} imports {t} inside a function"
        for (f, t), line in sorted(found.items())
        if (f, t) not in INSIDE_ALLOWED
    ] == []
    assert [k for k in INSIDE_ALLOWED if k not in found] == [], "an allowed import is gone: remove its entry"
    assert all(len(why) > 10 for why in INSIDE_ALLOWED.values())


def resolved_imports(path: Path, module: str, names: set[str]) -> set[str]:
    """The project's modules ``module`` imports, at any depth (inside functions too; not under
    ``if TYPE_CHECKING``, which never runs): ``from P import x`` is the module P.x when there is one."""

    def owner(name: str) -> str | None:
        while name and name not in names:
            name = name.rpartition(".")[0]
        return name or None

    out = set()

    def visit(node):
        for child in ast.iter_child_nodes(node):
            if _type_only(child):
                continue
            if isinstance(child, ast.ImportFrom) and (child.module or "").startswith("vts_hw"):
                out.update(owner(f"{child.module}.{a.name}") for a in child.names)
            elif isinstance(child, ast.Import):
                out.update(owner(a.name) for a in child.names if a.name.startswith("vts_hw"))
            visit(child)

    visit(tree(path))
    return out - {None, module}


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Each circle of the graph (a strongly connected set of more than one module), as a path that
    goes round it: [a, b, ..., a]."""
    index, low, stack, on, found = {}, {}, [], set(), []

    def connect(v):  # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(_round(graph, comp))

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return found


def _round(graph, comp: set[str]) -> list[str]:
    """A shortest way round the circle through its first module (breadth first inside it)."""
    start = min(comp)
    came = {w: start for w in graph[start] if w in comp}
    todo = sorted(came)
    while start not in came:
        v = todo.pop(0)
        for w in sorted(graph[v]):
            if w in comp and w not in came:
                came[w] = v
                todo.append(w)
    path, v = [start], came[start]
    while v != start:
        path.append(v)
        v = came[v]
    return [start, *reversed(path[1:]), start]


def import_graph(mods) -> dict[str, set[str]]:
    mods = list(mods)
    names = {m for _, m in mods}
    return {m: resolved_imports(p, m, names) for p, m in mods}


def test_the_import_graph_has_no_circle():
    """Imports inside functions count: a circle they close is a circle of the design."""
    graph = import_graph(modules())
    assert len(graph) > 300 and graph["vts_hw.procedures.commission_sequence"] >= {
        "vts_hw.procedures.commission_steps",
        "vts_hw.procedures.commission",
    }
    assert [" -> ".join(c) for c in circles(graph)] == []


def test_the_checks_see_an_import_in_a_function_and_a_circle(tmp_path):
    """Planted: an own import in a method and in a function (found, with its line), a circle closed
    by imports inside functions (found, named), a type-only import (not a circle)."""
    pkg = tmp_path / "vts_hw"
    pkg.mkdir()
    (pkg / "a.py").write_text(
        "from vts_hw import b\n\n\nclass A:\n    def f(self):\n        from vts_hw.d import g\n        return g\n"
    )
    (pkg / "b.py").write_text("import json\n\n\ndef f():\n    import vts_hw.c as c\n    return c\n")
    (pkg / "c.py").write_text(
        "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from vts_hw.b import f\n\n\n"
        "def g():\n    from vts_hw import a\n    return a\n"
    )
    (pkg / "d.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from vts_hw.e import x\n")
    (pkg / "e.py").write_text("from vts_hw.d import y\n")
    assert own_imports_inside_functions(pkg / "a.py") == [(6, "vts_hw.d")]
    assert own_imports_inside_functions(pkg / "b.py") == [(5, "vts_hw.c")]
    assert own_imports_inside_functions(pkg / "e.py") == []
    graph = import_graph((pkg / f"{n}.py", f"vts_hw.{n}") for n in "abcde")
    assert graph["vts_hw.c"] == {"vts_hw.a"} and graph["vts_hw.d"] == set()
    assert circles(graph) == [["vts_hw.a", "vts_hw.b", "vts_hw.c", "vts_hw.a"]]


def test_tracking_is_a_room_of_its_own_between_vision_and_the_procedures():
    """Tracking reads the recording and builds on vision; the procedures and the CLI use it; the
    recording (its format, writer, capture, index, reindex) and vision never import it."""

    def targets(prefix):
        return {t for p, m in modules() if m.startswith(prefix) for _, _, t in imports(p) if t.startswith("vts_hw.")}

    ups = targets("vts_hw.tracking")
    assert any(t.startswith("vts_hw.vision.") for t in ups) and any(t.startswith("vts_hw.recording.") for t in ups)
    assert any(t.startswith("vts_hw.tracking.") for t in targets("vts_hw.procedures"))
    below = {
        m: sorted(t for _, _, t in imports(p) if t.startswith("vts_hw.tracking"))
        for p, m in modules()
        if m.startswith(("vts_hw.recording", "vts_hw.vision"))
    }
    assert len(below) > 20 and {m: t for m, t in below.items() if t} == {}


def test_the_console_is_an_application_beside_the_cli():
    """Nothing under the applications imports the console (the core, tracking, drivers,
    procedures, store, reports); the console never imports the CLI nor the simulator; the
    console imports the drivers' registry, not a driver; and `vts console` only parses, calls
    the console's serve() and prints: the one name it takes from vts_hw.console is serve (and
    the host check it makes before reading the rig, from serve_checks: a refusal loads no page),
    and the user functions of `vts console user`."""
    users = sorted(
        {
            layer(m)
            for p, m in modules()
            for _, _, t in imports(p)
            if t == "vts_hw.console" or t.startswith("vts_hw.console.")
        }
        - {"console"}
    )
    assert users == ["cli"]
    console = {t for p, m in modules() if layer(m) == "console" for _, _, t in imports(p) if t.startswith("vts_hw.")}
    assert console and not {t for t in console if layer(t) in ("cli", "sim", "scenarios")}
    assert {t for t in console if layer(t) == "drivers"} == {"vts_hw.drivers.registry"}
    cli_console = ROOT / "vts_hw" / "cli" / "console.py"
    taken = {
        (n.module, a.name)
        for n in ast.walk(ast.parse(cli_console.read_text()))
        if isinstance(n, ast.ImportFrom) and (n.module or "").startswith("vts_hw.console")
        for a in n.names
    }
    assert taken == {
        ("vts_hw.console.serve", "serve"),
        ("vts_hw.console.serve_checks", "check_host"),
        # `vts console user ...`: the console's users (hashing lives beside the login)
        *(("vts_hw.console.users", n) for n in ("add_user", "check_name", "list_users", "remove_user")),
    }
