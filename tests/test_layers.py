"""The house keeps its layers: every import of the package read from the source.

config → drivers → procedures → store → reports → qatrack: a layer imports only the layers before it
(and the core everything builds on). Tracking (vts_hw/tracking/: frame sets, matching over time,
identities, tracks, the live path) sits on the core (vision, recording, timing) and under the
procedures: the rest of the core (the recording format and capture among it) never imports it.
A procedure never holds a store: it returns its analysis
and the caller records it (vts_hw.store.recorder), so procedures/ importing vts_hw.store is a
failure, at any depth of the module (a function's own import too). The core imports no driver, procedure or simulator; only
the CLI and the simulated scenarios import the simulator; every import is absolute; no module
is over 500 lines. See docs/decisions/0028-structure.md.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = {"vts_hw": "vts_hw", "drivers": "vts_hw.drivers", "procedures": "vts_hw.procedures",
           "sim_devices": "vts_hw.sim_devices"}
# what each layer may import, besides itself
ALLOWED = {
    "core": set(),
    "tracking": {"core"},
    "drivers": {"core"},
    "procedures": {"core", "drivers", "tracking"},
    "store": {"core"},
    "report": {"core", "store"},
    "qatrack": {"core", "store", "report"},   # pushing to QATrack+ reads the store and builds reports
    "sim": {"core", "tracking"},               # the simulated patient's marker tracks are Tracks
    "scenarios": {"core", "tracking", "drivers", "procedures", "store", "report", "sim"},
    # the room console (vts_hw/console/): an application as the CLI is, beside it, never under it
    # nor over it: it opens devices and calls procedures, the store and reports; no CLI, no simulator
    "console": {"core", "tracking", "drivers", "procedures", "store", "report", "qatrack"},
    "cli": {"core", "tracking", "drivers", "procedures", "store", "report", "qatrack", "sim", "scenarios",
            "console"},
}


def layer(module: str) -> str:
    parts = module.split(".")
    if parts[:3] == ["vts_hw", "sim_devices", "scenarios"]:
        return "scenarios"
    return {"drivers": "drivers", "procedures": "procedures", "sim_devices": "sim", "cli": "cli",
            "store": "store", "report": "report", "qatrack": "qatrack",
            "tracking": "tracking", "console": "console"}.get(parts[1] if len(parts) > 1 else "", "core")


def modules():
    for folder, package in FOLDERS.items():
        for path in sorted((ROOT / folder).rglob("*.py")):
            rel = path.relative_to(ROOT / folder).with_suffix("").parts
            yield path, ".".join([package, *[p for p in rel if p != "__init__"]])


def imports(path: Path):
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            yield node.lineno, node.level, node.module or ""
        elif isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, 0, alias.name


def test_the_rules_see_every_layer():
    """The check reads real code: every layer has modules, and the CLI imports every other one."""
    seen = {layer(m) for _, m in modules()}
    assert seen == set(ALLOWED)
    cli_imports = {layer(t) for p, m in modules() if layer(m) == "cli"
                   for _, _, t in imports(p) if t.startswith("vts_hw.")}
    assert cli_imports >= {"core", "tracking", "drivers", "procedures", "store", "report", "qatrack", "sim",
                           "scenarios", "console"}


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
    found = [f"{p.relative_to(ROOT)}:{line} imports {target}" for p, m in modules() if layer(m) == "procedures"
             for line, _, target in imports(p) if target == "vts_hw.store" or target.startswith("vts_hw.store.")]
    assert found == []
    # nor is one handed to them: no parameter and no attribute named store
    held = []
    for p, m in modules():
        if layer(m) != "procedures":
            continue
        for node in ast.walk(ast.parse(p.read_text())):
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


@pytest.mark.parametrize("folder", sorted(FOLDERS))
def test_no_module_over_500_lines(folder):
    long = {str(p.relative_to(ROOT)): n for p in (ROOT / folder).rglob("*.py")
            if (n := len(p.read_text().splitlines())) > 500}
    assert long == {}


def test_tracking_is_a_room_of_its_own_between_vision_and_the_procedures():
    """Tracking reads the recording and builds on vision; the procedures and the CLI use it; the
    recording (its format, writer, capture, index, reindex) and vision never import it."""
    def targets(prefix):
        return {t for p, m in modules() if m.startswith(prefix) for _, _, t in imports(p) if t.startswith("vts_hw.")}
    ups = targets("vts_hw.tracking")
    assert any(t.startswith("vts_hw.vision.") for t in ups) and any(t.startswith("vts_hw.recording.") for t in ups)
    assert any(t.startswith("vts_hw.tracking.") for t in targets("vts_hw.procedures"))
    below = {m: sorted(t for _, _, t in imports(p) if t.startswith("vts_hw.tracking"))
             for p, m in modules() if m.startswith(("vts_hw.recording", "vts_hw.vision"))}
    assert len(below) > 20 and {m: t for m, t in below.items() if t} == {}


def test_the_console_is_an_application_beside_the_cli():
    """Nothing under the applications imports the console (the core, tracking, drivers,
    procedures, store, reports); the console never imports the CLI nor the simulator; the
    console imports the drivers' registry, not a driver; and `vts console` only parses, calls
    the console's serve() and prints: the one name it takes from vts_hw.console is serve (and
    the host check it makes before reading the rig), and the user functions of `vts console user`."""
    users = sorted({layer(m) for p, m in modules() for _, _, t in imports(p)
                    if t == "vts_hw.console" or t.startswith("vts_hw.console.")} - {"console"})
    assert users == ["cli"]
    console = {t for p, m in modules() if layer(m) == "console" for _, _, t in imports(p) if t.startswith("vts_hw.")}
    assert console and not {t for t in console if layer(t) in ("cli", "sim", "scenarios")}
    assert {t for t in console if layer(t) == "drivers"} == {"vts_hw.drivers.registry"}
    cli_console = ROOT / "vts_hw" / "cli" / "console.py"
    taken = {(n.module, a.name) for n in ast.walk(ast.parse(cli_console.read_text()))
             if isinstance(n, ast.ImportFrom) and (n.module or "").startswith("vts_hw.console") for a in n.names}
    assert taken == {("vts_hw.console.serve", "serve"), ("vts_hw.console.serve", "check_host"),
                     # `vts console user ...`: the console's users (hashing lives beside the login)
                     *(("vts_hw.console.users", n) for n in ("add_user", "check_name", "list_users", "remove_user"))}
