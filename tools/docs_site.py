"""The documentation site's generated pages, written from the code when the site is built.

mkdocs.yml names this file as a hook: at every build (``make docs``, ``mkdocs serve``, the test
``tests/house/test_docs_site.py``) it adds these pages to the site, made from what the code holds now,
so they cannot go stale and are never copied by hand (docs/decisions/0097-docs-by-reader.md):

- ``reference/commands.md``   every ``vts`` command, from the click command tree, with its help
- ``reference/rig-yaml.md``   every rig.yaml key, from the settings models (pydantic), with the
                              trigger backends' own settings models and the metrics with a window
- ``reference/exit-codes.md`` every exit code, and where the code sets each (the error classes of
                              vts_hw/errors.py and the others, the QA results' codes)
- ``develop/layers.md``       the layers and what each may import, from tests/house/test_layers.py
- ``develop/benches.md``      every benchmark in bench/, from its docstring
- ``decisions/index.md``      every note of docs/decisions/, by number, from its title

``python tools/docs_site.py OUTDIR`` writes the same pages into OUTDIR, to read them without
building the site.
"""

from __future__ import annotations

import ast
import re
import sys
from pathlib import Path
from typing import Any, Union, get_args, get_origin

import click
from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File
from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from vts_hw import catalog
from vts_hw.cli import COMMANDS, command_tree
from vts_hw.config import RigConfig, TriggerConfig
from vts_hw.drivers import registry
from vts_hw.errors import VtsError
from vts_hw.files import ensure_dir, write_atomic

ROOT = Path(__file__).resolve().parents[1]
#: the folders whose modules the exit codes are read from, and their package names
PACKAGES = {"vts_hw": "vts_hw", "drivers": "vts_hw.drivers", "procedures": "vts_hw.procedures"}

#: what each exit code means to the user: the contract the code keeps (the sources of each are
#: found in the code when the page is made, and a code the code uses but this table lacks fails
#: the build)
EXIT_MEANINGS = {
    0: "done (a QA result within tolerance: OK)",
    1: "anything else that went wrong (a bug: please report it with the command)",
    2: "bad input or a setup mistake (a bad rig.yaml, option or file name); nothing written",
    3: "a file or the store could not be read or written; the message says what was kept",
    4: "a device failed or did not deliver (or QATrack+ refused a push)",
    5: "no drift baseline (take one with `vts qa drift --set-baseline`)",
    10: "a QA result in TOLERANCE",
    20: "a QA result in ACTION",
    130: "interrupted (Ctrl-C, SIGTERM): what was done is kept and said to be interrupted",
}


# ---- every command ------------------------------------------------------------------------------


def commands_page() -> str:
    out = [
        "# Commands",
        "",
        "Every command of `vts`, as `vts COMMAND --help` prints it. This page is made from the "
        "command tree when the site is built (`tools/docs_site.py`).",
        "",
        "Top-level commands: " + ", ".join(f"[`{n}`](#vts-{n})" for n in sorted(COMMANDS)) + ".",
        "",
    ]
    contexts: dict[tuple[str, ...], click.Context] = {}
    for path, command in command_tree():
        parent = contexts.get(path[:-1]) if path else None
        ctx = click.Context(
            command, info_name=path[-1] if path else "vts", parent=parent, max_content_width=80, terminal_width=80
        )
        contexts[path] = ctx
        name = " ".join(("vts", *path))
        level = "#" * min(2 + max(len(path) - 1, 0), 4)
        out += [f"{level} {name}", "", "```text", command.get_help(ctx).rstrip(), "```", ""]
    return "\n".join(out)


# ---- rig.yaml ------------------------------------------------------------------------------------


def _type_name(annotation: Any) -> str:
    origin = get_origin(annotation)
    if origin is None:
        if isinstance(annotation, type):
            return annotation.__name__
        return str(annotation).replace("typing.", "")
    args = [a for a in get_args(annotation) if a is not type(None)]
    if origin is Union:
        return " or ".join(_type_name(a) for a in args) + (
            " (or null)" if len(args) < len(get_args(annotation)) else ""
        )
    name = getattr(origin, "__name__", str(origin).replace("typing.", ""))
    if name == "Literal":
        return " | ".join(repr(a) for a in get_args(annotation))
    return f"{name}[{', '.join(_type_name(a) for a in args)}]"


def _limits(field) -> str:
    parts = []
    for m in field.metadata:
        for attr, sign in (
            ("ge", ">="),
            ("gt", ">"),
            ("le", "<="),
            ("lt", "<"),
            ("min_length", "length >="),
            ("pattern", "matches"),
        ):
            v = getattr(m, attr, None)
            if v is not None:
                parts.append(f"{sign} `{v}`" if attr == "pattern" else f"{sign} {v}")
    return ", ".join(parts)


def _default(field) -> str:
    if field.is_required():
        return "required"
    if field.default_factory is not None:
        value = field.default_factory()
    else:
        value = field.default
    if value is PydanticUndefined:
        return ""
    if isinstance(value, BaseModel):
        return "(its section's defaults)"
    return f"`{value!r}`" if value not in (None, "") else ("null" if value is None else '`""`')


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|").replace("``", "`")


def _nested(annotation: Any) -> tuple[str, type[BaseModel]] | None:
    """(how its keys are written below the parent key, the model) for a model, a list of
    models, a dict of models, or an optional one of these."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "", annotation
    origin, args = get_origin(annotation), [a for a in get_args(annotation) if a is not type(None)]
    if origin is Union and len(args) == 1:
        return _nested(args[0])
    if origin is list and args and isinstance(args[0], type) and issubclass(args[0], BaseModel):
        return "[]", args[0]
    if origin is dict and len(args) == 2 and isinstance(args[1], type) and issubclass(args[1], BaseModel):
        return ".<name>", args[1]
    return None


def _model_table(model: type[BaseModel], prefix: str, out: list[str], sections: list) -> None:
    out += ["| key | type | default | limits | what |", "| --- | --- | --- | --- | --- |"]
    for name, field in model.model_fields.items():
        key = f"{prefix}{name}"
        nested = _nested(field.annotation)
        what = field.description or ""
        if nested is not None:
            sections.append((key + nested[0], nested[1]))
            doc = (nested[1].__doc__ or "").strip() if nested[1].__module__.startswith("vts_hw") else ""
            first = re.split(r"(?<=\.)\s", " ".join(doc.split("\n\n")[0].split()), maxsplit=1)[0] if doc else ""
            what = what or (first + " " if len(first) <= 160 else "") + "(its keys below)"
        out.append(
            f"| `{key}` | {_cell(_type_name(field.annotation))} | {_cell(_default(field))} | "
            f"{_cell(_limits(field))} | {_cell(what)} |"
        )
    out.append("")


def rig_yaml_page() -> str:
    out = [
        "# rig.yaml: every key",
        "",
        "Made from the settings models (`vts_hw/config.py` and the models it names; each trigger "
        "backend's own model) when the site is built (`tools/docs_site.py`). How to write the file, "
        "with an example: [The rig config](rig-config.md). A key that is not listed here is refused "
        "when the file is read (one sentence naming the file and the key, exit 2).",
        "",
    ]
    sections: list = [("", RigConfig)]
    seen = set()
    while sections:
        prefix, model = sections.pop(0)
        if (prefix, model) in seen:
            continue
        seen.add((prefix, model))
        title = f"`{prefix}`" if prefix else "the top level"
        out += [f"## {title}", ""]
        doc = (model.__doc__ or "").strip()
        if doc and model.__module__.startswith("vts_hw") and not doc.startswith("Usage docs"):
            out += [_cell(doc.split("\n\n")[0]), ""]
        sub: list = []
        _model_table(model, f"{prefix}." if prefix else "", out, sub)
        sections[0:0] = sub
    out += [
        "## `trigger` keys of each backend",
        "",
        "Beside the keys every backend shares (above), `trigger:` holds the keys of the backend it "
        "names (`trigger: backend:`), checked by that backend's own settings model when it is opened "
        "(`drivers/registry.py`, `TRIGGER_BACKENDS`).",
        "",
    ]
    for name in sorted(registry.TRIGGER_BACKENDS):
        backend = registry.trigger_backend(TriggerConfig(backend=name, address="-"))
        out += [f"### `backend: {name}`", "", _cell(getattr(backend, "what", "")), ""]
        if backend.settings.model_fields:
            _model_table(backend.settings, "trigger.", out, [])
        else:
            out += ["No keys of its own.", ""]
    out += [
        "## Camera kinds",
        "",
        "`cameras[].kind` names the driver of a camera (`drivers/registry.py`, `CAMERA_KINDS`). Each "
        "kind has its own settings model: the keys of the entry (above) it uses, and its own keys under "
        "`options:`, checked when the camera is opened (and before a QA run or a scan touches anything).",
        "",
    ]
    for kind in sorted(registry.CAMERA_KINDS):
        model = registry.camera_class(kind).settings
        out += [f"### `kind: {kind}`", "", f"`{registry.CAMERA_KINDS[kind]}`. {_cell(model.__doc__ or '')}", ""]
        rows: list[str] = []
        _model_table(model, "cameras[].", rows, [])
        own = {k for k in model.model_fields if k not in model.entry_keys}
        out += [
            re.sub(
                r"^\| `cameras\[\]\.(\w+)`",
                lambda m, own=own: f"| `cameras[].options.{m.group(1)}`" if m.group(1) in own else m.group(0),
                row,
            )
            for row in rows
        ]
    out += [
        "",
        "## Metrics with a tolerance window",
        "",
        "`tolerances:` takes these names (`vts_hw/tolerance.py`'s `DEFAULT_TOLERANCES` and the "
        "`windows` of the entries of `vts_hw/catalog.py`), each with its default window:",
        "",
        "| metric | action low | tolerance low | tolerance high | action high | unit |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for metric, window in catalog.windows().items():
        cells = [getattr(window, k) for k in ("action_low", "tolerance_low", "tolerance_high", "action_high")]
        out.append(f"| `{metric}` | " + " | ".join("" if c is None else str(c) for c in cells) + f" | {window.unit} |")
    return "\n".join(out) + "\n"


# ---- exit codes ----------------------------------------------------------------------------------


def _modules():
    for folder in PACKAGES:
        for path in sorted((ROOT / folder).rglob("*.py")):
            yield path, path.relative_to(ROOT).as_posix()


def _int(node) -> int | None:
    return node.value if isinstance(node, ast.Constant) and type(node.value) is int else None


def exit_code_sources() -> dict[int, list[str]]:
    """code -> where the code sets it: error classes with an ``exit_code``, tables named
    ``EXIT_*``, and ``sys.exit(N)`` with a literal N, read from the source."""
    found: dict[int, list[str]] = {}

    def add(code, text):
        if code is not None:
            found.setdefault(code, []).append(text)

    for path, rel in _modules():
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef):
                for item in node.body:
                    if isinstance(item, ast.Assign) and any(getattr(t, "id", "") == "exit_code" for t in item.targets):
                        doc = (ast.get_docstring(node) or "").split("\n\n")[0]
                        add(_int(item.value), f"`{node.name}` ({rel}): {_cell(doc)}".rstrip(": "))
            elif isinstance(node, ast.Assign) and len(node.targets) == 1:
                target = node.targets[0]
                names = [getattr(t, "id", "") for t in getattr(target, "elts", [target])]
                values = getattr(node.value, "elts", [node.value])
                if not any(n.startswith("EXIT_") for n in names):
                    continue
                if isinstance(node.value, ast.Dict):
                    for k, v in zip(node.value.keys, node.value.values):
                        label = ast.unparse(k) if k is not None else ""
                        add(_int(v), f"`{names[0]}[{label}]` ({rel})")
                elif len(names) == len(values):
                    for n, v in zip(names, values):
                        add(_int(v), f"`{n}` ({rel})")
            elif (
                isinstance(node, ast.Call)
                and ast.unparse(node.func) == "sys.exit"
                and node.args
                and _int(node.args[0]) is not None
            ):
                add(_int(node.args[0]), f"`sys.exit({node.args[0].value})` ({rel}:{node.lineno})")
    return found


def exit_codes_page() -> str:
    sources = exit_code_sources()
    unknown = sorted(set(sources) - set(EXIT_MEANINGS))
    if unknown:
        raise PluginError(
            f"tools/docs_site.py: exit code {unknown[0]} is set by the code "
            f"({sources[unknown[0]][0]}) but has no meaning in EXIT_MEANINGS"
        )
    out = [
        "# Exit codes",
        "",
        "Every command ends with one of these. An error is one sentence starting `vts:`, never a "
        "traceback. Made from the code when the site is built (`tools/docs_site.py`): the error "
        "classes (`vts_hw/errors.py` and their kin), the tables named `EXIT_*` and the literal "
        "`sys.exit` calls.",
        "",
        "| code | meaning |",
        "| --- | --- |",
    ]
    out += [f"| **{code}** | {meaning} |" for code, meaning in sorted(EXIT_MEANINGS.items())]
    out += ["", "## Where the code sets each", ""]
    for code in sorted(EXIT_MEANINGS):
        out += [f"### {code}", ""]
        out += [f"- {s}" for s in sources.get(code, [])] or ["- (every command that ends without an error)"]
        out.append("")
    return "\n".join(out)


# ---- layers --------------------------------------------------------------------------------------


def _literal(path: Path, name: str):
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == name for t in node.targets):
            return ast.literal_eval(node.value)
    raise PluginError(f"tools/docs_site.py: {path.relative_to(ROOT)} has no {name} table")


def layers_page() -> str:
    test = ROOT / "tests" / "house" / "test_layers.py"
    allowed = _literal(test, "ALLOWED")
    doc = ast.get_docstring(ast.parse(test.read_text())) or ""
    out = [
        "# The layers",
        "",
        "What each layer may import, read from `tests/house/test_layers.py` (its `ALLOWED` table) when the "
        "site is built: that test fails on any import that breaks it. A layer always imports itself.",
        "",
        "| layer | may import |",
        "| --- | --- |",
    ]
    out += [f"| {layer} | {', '.join(sorted(may)) or '(nothing of the project)'} |" for layer, may in allowed.items()]
    out += ["", "## The rules, as the test states them", ""]
    out += [doc, "", "Where each module is and what it holds: [Where things are](where-things-are.md).", ""]
    return "\n".join(out)


# ---- benchmarks ----------------------------------------------------------------------------------


def benches_page() -> str:
    out = [
        "# Benchmarks",
        "",
        "`make bench` runs every one (`bench/run_all.py`); each prints figures measured in one run "
        "(ratios, never timed assertions). Run one with `.venv/bin/python bench/NAME.py` (`--help` for "
        "its options). This list is made from each script's docstring when the site is built.",
        "",
        "| bench | what it measures |",
        "| --- | --- |",
    ]
    for path in sorted((ROOT / "bench").glob("*.py")):
        doc = ast.get_docstring(ast.parse(path.read_text())) or ""
        out.append(f"| `bench/{path.name}` | {_cell(doc.split(chr(10) * 2)[0])} |")
    return "\n".join(out) + "\n"


# ---- decisions -----------------------------------------------------------------------------------


def decision_notes() -> list[tuple[str, str, str]]:
    """(number, title, file name) of every note in docs/decisions/, by number."""
    notes = []
    for path in sorted((ROOT / "docs" / "decisions").glob("[0-9][0-9][0-9][0-9]-*.md")):
        first = next((line for line in path.read_text().splitlines() if line.startswith("# ")), "")
        title = re.sub(r"^#\s*\d{4}\s*[—–-]\s*", "", first).strip() or path.stem
        notes.append((path.name[:4], title, path.name))
    return notes


def decisions_page() -> str:
    out = [
        "# Decisions",
        "",
        "Short notes on the choices behind the code, one per choice, by number. This index is made "
        "from the notes' titles when the site is built.",
        "",
        "| # | decision |",
        "| --- | --- |",
    ]
    out += [f"| {num} | [{_cell(title)}]({name}) |" for num, title, name in decision_notes()]
    return "\n".join(out) + "\n"


#: the generated pages: their path in the site and the function that writes each
PAGES = {
    "reference/commands.md": commands_page,
    "reference/rig-yaml.md": rig_yaml_page,
    "reference/exit-codes.md": exit_codes_page,
    "develop/layers.md": layers_page,
    "develop/benches.md": benches_page,
    "decisions/index.md": decisions_page,
}


def on_files(files, config):
    """mkdocs hook: the generated pages added to the site's files (never written into docs/)."""
    for uri, make in PAGES.items():
        if files.get_file_from_path(uri) is not None:
            raise PluginError(f"tools/docs_site.py: docs/{uri} exists, but it is a generated page; remove it")
        files.append(File.generated(config, uri, content=make()))
    return files


def main(argv: list[str]) -> int:
    """``python tools/docs_site.py OUTDIR``: the made pages written into OUTDIR (each whole, through
    vts_hw.files); a folder or file that cannot be written is one sentence and exit 3."""
    if len(argv) != 1:
        print("usage: python tools/docs_site.py OUTDIR", file=sys.stderr)
        return 2
    try:
        for uri, make in PAGES.items():
            target = Path(argv[0]) / uri
            ensure_dir(target.parent, "folder of the made pages")
            write_atomic(target, make())
            print(target)
    except VtsError as exc:
        print(f"docs_site: {exc}", file=sys.stderr)
        return exc.exit_code
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
