"""The documentation site builds with --strict (a broken link or a missing page fails), and its
generated pages say what the code holds: every command, every exit code, every rig.yaml key,
every decision note (mkdocs.yml, tools/docs_site.py; docs/decisions/0097-docs-by-reader.md).

`mkdocs build` runs as a user runs it (`make docs`): a subprocess, once for the module."""

from __future__ import annotations

import html
import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from mkdocs.config import load_config
from mkdocs.exceptions import PluginError
from mkdocs.structure.files import File, Files

from vts_hw.cli import COMMANDS, command_tree
from vts_hw.config import RigConfig

ROOT = Path(__file__).resolve().parents[2]
#: the exit codes every command keeps (README, vts_hw/errors.py and the QA results' codes)
EXIT_CODES = (0, 2, 3, 4, 5, 10, 20, 130)


def _generator():
    """tools/docs_site.py, the site's hook, as mkdocs loads it (a file, not a package)."""
    spec = importlib.util.spec_from_file_location("docs_site", ROOT / "tools" / "docs_site.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _build(config: Path, site: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(config), "--site-dir", str(site)],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=240,
    )


def _text(page: Path) -> str:
    """The page's words, without its tags."""
    return html.unescape(re.sub(r"<[^>]+>", "", page.read_text()))


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("site")
    done = _build(ROOT / "mkdocs.yml", out)
    assert done.returncode == 0, done.stdout + done.stderr
    return out


def test_the_site_builds_strict_with_a_page_per_reader(site):
    for section in ("operate", "commission", "physics", "reference", "develop", "decisions"):
        assert (site / section / "index.html").is_file(), section
    assert (site / "index.html").is_file()
    # the files that stayed where they were are in the site too
    for page in ("faults", "security", "design", "listmode-format"):
        assert (site / page / "index.html").is_file(), page
    # the README's sync session, which the tests cite, is on the sync page with its glob
    sync = _text(site / "physics" / "sync" / "index.html")
    assert "vts sync analyze scan1 --listmode sim/spect/scan-*.vtslm -o sync.html" in sync


def test_every_command_is_on_the_commands_page(site):
    text = _text(site / "reference" / "commands" / "index.html")
    for name in COMMANDS:
        assert f"vts {name}" in text, name
    for path, command in command_tree():
        assert " ".join(("vts", *path)) in text, path
        for param in command.params:
            for opt in param.opts:
                if opt.startswith("-") and not getattr(param, "hidden", False):
                    assert opt in text, (path, opt)


def test_every_exit_code_and_rig_yaml_key_and_decision(site):
    codes = _text(site / "reference" / "exit-codes" / "index.html")
    for code in EXIT_CODES:
        assert re.search(rf"^\s*{code}\s*$", codes, re.M), code
    assert "DataError" in codes and "NoBaseline" in codes
    keys = _text(site / "reference" / "rig-yaml" / "index.html")
    for key in RigConfig.model_fields:
        assert key in keys, key
    for key in ("cameras[].password_env", "trigger.watchdog_s", "motion.alert_mm", "drift_x_px"):
        assert key in keys, key
    decisions = _text(site / "decisions" / "index.html")
    notes = sorted((ROOT / "docs" / "decisions").glob("[0-9][0-9][0-9][0-9]-*.md"))
    assert len(notes) > 90
    for note in notes:
        assert (site / "decisions" / note.stem / "index.html").is_file(), note.name
        assert note.name[:4] in decisions, note.name


def test_a_link_to_a_missing_page_fails_the_build(tmp_path):
    """The same config and pages, one page given a link to a page that is not there: the build
    stops (exit 1) naming the link."""
    docs = tmp_path / "docs"
    shutil.copytree(ROOT / "docs", docs)
    page = docs / "operate" / "index.md"
    page.write_text(page.read_text() + "\nSee [the missing page](no-such-page.md).\n")
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    config["docs_dir"] = str(docs)
    config["hooks"] = [str(ROOT / h) for h in config["hooks"]]
    (tmp_path / "mkdocs.yml").write_text(yaml.safe_dump(config, allow_unicode=True))
    done = _build(tmp_path / "mkdocs.yml", tmp_path / "site")
    assert done.returncode != 0
    assert "no-such-page.md" in done.stdout + done.stderr


def test_a_page_written_by_hand_over_a_made_one_stops_the_build(tmp_path):
    """docs/reference/commands.md written by hand would hide the page made from the code: the hook
    refuses it, naming the file."""
    gen = _generator()
    config = load_config(str(ROOT / "mkdocs.yml"))
    hand = tmp_path / "commands.md"
    hand.write_text("# Commands\n")
    files = Files([File("reference/commands.md", str(tmp_path), str(tmp_path / "site"), False)])
    with pytest.raises(PluginError, match="docs/reference/commands.md exists, but it is a generated page"):
        gen.on_files(files, config)


def test_an_exit_code_without_a_meaning_stops_the_build(monkeypatch):
    """A code the code sets (5: NoBaseline) that the page cannot explain stops the build, naming it
    and where it is set."""
    gen = _generator()
    monkeypatch.delitem(gen.EXIT_MEANINGS, 5)
    with pytest.raises(PluginError, match=r"exit code 5 is set by the code \(`NoBaseline`"):
        gen.exit_codes_page()


def test_the_made_pages_into_a_folder_that_cannot_be_one_is_one_sentence(tmp_path, capsys):
    """`python tools/docs_site.py OUTDIR` with a file as OUTDIR: one sentence naming it, exit 3,
    the file as it was."""
    gen = _generator()
    taken = tmp_path / "taken"
    taken.write_text("mine\n")
    assert gen.main([str(taken)]) == 3
    err = capsys.readouterr().err
    assert err.startswith(f"docs_site: {taken}/reference: could not be written") and "Traceback" not in err
    assert taken.read_text() == "mine\n"
    assert gen.main([str(tmp_path / "made")]) == 0
    assert "vts qa daily" in (tmp_path / "made" / "reference" / "commands.md").read_text()


def _messages_naming_pages(root: Path, folders) -> list[tuple[str, int, str]]:
    """(file, line, page) of every page of this project (`docs/...md`, `README...`) a string of
    the code names: its messages and help, not its docstrings (which may cite other projects')."""
    import ast

    out = []
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
            docs = {
                id(n.body[0].value)
                for n in ast.walk(tree)
                if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                and n.body
                and isinstance(n.body[0], ast.Expr)
                and isinstance(n.body[0].value, ast.Constant)
            }
            for node in ast.walk(tree):
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
                    for page in re.findall(r"docs/[\w/.-]+\.md|README[^\s\"')]*", node.value):
                        out.append((str(path.relative_to(root)), node.lineno, page))
    return out


def test_every_page_a_message_names_exists(tmp_path):
    """A message or help text that sends the reader to a page names one that is there (the README's
    sections moved to the site: a message still saying "see the README's QATrack+ section" sent the
    reader nowhere). Planted: a message naming a page that is not there is found."""
    named = _messages_naming_pages(ROOT, ("vts_hw", "drivers", "procedures", "sim_devices"))
    assert named, "no message names a page: the scan reads nothing"
    missing = [
        (f, line, page)
        for f, line, page in named
        if page.startswith("README") or not (ROOT / page.split("#")[0]).is_file()
    ]
    assert missing == [], missing
    planted = tmp_path / "planted"
    planted.mkdir()
    (planted / "m.py").write_text('def f():\n    raise SystemExit("see docs/operate/nowhere.md")\n')
    assert _messages_naming_pages(tmp_path, ("planted",)) == [("planted/m.py", 2, "docs/operate/nowhere.md")]
