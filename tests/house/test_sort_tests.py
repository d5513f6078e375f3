"""tools/sort-tests (decision 0105), run as the lead runs it, on a small git checkout of its own
in tmp_path: the script and a table of kinds, two test modules, a helper, a doc, a fault table,
durations.json. It moves each module into its kind's folder and rewrites every reference; run
again it does nothing; a module the table does not know stops it before anything changes."""

from __future__ import annotations

import errno
import importlib.machinery
import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "tools" / "sort-tests"

TABLE = """unit = ["test_alpha.py"]
integration = ["test_beta.py"]
"""
ALPHA = '''"""Alpha (the end to end case: test_beta.py)."""
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DATA = Path(__file__).parent / "data" / "x.json"
AS_TEXT = "Path(__file__).resolve().parents[1]"     # code held as text: left as it is


def test_alpha():
    said = "see test_beta.py"       # compared by a test: left as it is
    assert "test_beta.py" in said
'''
BETA = """from test_alpha import REPO


def test_beta():
    assert REPO.is_dir()
"""
CONFTEST = """from pathlib import Path
TARGET = Path(__file__).parent / "test_beta.py"
"""
# (the glob split in two: whole, tools/sort-tests would rewrite it here too when it moves this module)
DOC = (
    """Run `tests/test_alpha.py`; the store's tests are `tests/"""
    + """test_store*.py`; test_beta.py (**b**).
| fault | test |
| --- | --- |
| a | tests/test_beta.py::test_beta |
"""
)


def _git(cwd: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True, text=True).stdout


@pytest.fixture()
def checkout(tmp_path) -> Path:
    root = tmp_path / "repo"
    (root / "tools").mkdir(parents=True)
    (root / "tests" / "data").mkdir(parents=True)
    (root / "docs").mkdir()
    shutil.copy(SCRIPT, root / "tools" / "sort-tests")
    (root / "tools" / "test-kinds.toml").write_text(TABLE)
    (root / "tests" / "test_alpha.py").write_text(ALPHA)
    (root / "tests" / "test_beta.py").write_text(BETA)
    (root / "tests" / "conftest.py").write_text(CONFTEST)
    (root / "tests" / "helper.py").write_text("# a helper: stays (test_alpha.py uses it)\n")
    (root / "tests" / "data" / "x.json").write_text("{}")
    (root / "tests" / "durations.json").write_text(json.dumps({"tests/test_alpha.py": 1.0, "tests/test_beta.py": 2.0}))
    (root / "docs" / "faults.md").write_text(DOC)
    (root / "docs" / "crlf.md").write_bytes(b"see tests/test_alpha.py\r\nend\r\n")
    _git(root, "init", "-q")
    _git(root, "add", ".")
    _git(root, "-c", "user.name=t", "-c", "user.email=t@example.invalid", "commit", "-q", "-m", "start")
    return root


def _sort(root: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(root / "tools" / "sort-tests"), *args],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_the_modules_move_to_their_kind_and_every_reference_follows(checkout):
    p = _sort(checkout)
    assert p.returncode == 0, p.stderr
    assert "moved 2 test module(s)" in p.stdout and "unit 1, integration 1" in p.stdout
    tests = checkout / "tests"
    assert sorted(f.relative_to(tests).as_posix() for f in tests.rglob("test_*.py")) == [
        "integration/test_beta.py",
        "unit/test_alpha.py",
    ]
    assert (tests / "helper.py").exists() and (tests / "data" / "x.json").exists() and (tests / "conftest.py").exists()
    assert "tests/test_alpha.py -> tests/unit/test_alpha.py" in _git(checkout, "status", "--short")  # git mv: a rename

    alpha = (tests / "unit" / "test_alpha.py").read_text()
    assert "(the end to end case: tests/integration/test_beta.py)" in alpha  # a docstring's bare name
    assert 'said = "see test_beta.py"' in alpha and 'assert "test_beta.py" in said' in alpha  # code left alone
    assert "REPO = Path(__file__).resolve().parents[2]" in alpha  # one folder deeper
    assert 'Path(__file__).parents[1] / "data"' in alpha
    assert 'AS_TEXT = "Path(__file__).resolve().parents[1]"' in alpha
    assert 'Path(__file__).parent / "integration" / "test_beta.py"' in (tests / "conftest.py").read_text()
    assert "# a helper: stays (tests/unit/test_alpha.py uses it)" in (tests / "helper.py").read_text()
    assert json.loads((tests / "durations.json").read_text()) == {
        "tests/unit/test_alpha.py": 1.0,
        "tests/integration/test_beta.py": 2.0,
    }
    doc = (checkout / "docs" / "faults.md").read_text()
    assert "Run `tests/unit/test_alpha.py`" in doc and "`tests/*/test_store*.py`" in doc
    assert "tests/integration/test_beta.py (**b**)" in doc and "| tests/integration/test_beta.py::test_beta |" in doc
    assert (checkout / "docs" / "crlf.md").read_bytes() == b"see tests/unit/test_alpha.py\r\nend\r\n"  # line ends kept

    # the moved modules find the repository, tests/data and each other's helpers
    env_path = f"{tests / 'unit'}:{tests / 'integration'}"
    run = subprocess.run(
        [
            sys.executable,
            "-c",
            "import test_beta, test_alpha; assert test_alpha.DATA.exists(); "
            "assert test_alpha.REPO == test_beta.REPO; print(test_alpha.REPO)",
        ],
        cwd=checkout,
        capture_output=True,
        text=True,
        env={"PYTHONPATH": env_path},
        timeout=60,
    )
    assert run.returncode == 0 and run.stdout.strip() == str(checkout), run.stderr

    again = _sort(checkout)
    assert again.returncode == 0 and "nothing to do" in again.stdout, again.stderr
    assert (tests / "unit" / "test_alpha.py").read_text() == alpha


def test_a_module_the_table_does_not_know_stops_it_before_anything_changes(checkout):
    (checkout / "tests" / "test_gamma.py").write_text("def test_gamma():\n    assert True\n")
    (checkout / "tests" / "test_delta.py").write_text("from pathlib import Path\nHERE = Path(__file__).name\n")
    (checkout / "elsewhere").mkdir()
    (checkout / "elsewhere" / "test_epsilon.py").write_text("def test_epsilon():\n    assert True\n")
    (checkout / "tests" / "test_epsilon.py").symlink_to("../elsewhere/test_epsilon.py")
    (checkout / "tools" / "test-kinds.toml").write_text(
        TABLE.replace('["test_beta.py"]', '["test_beta.py", "test_delta.py", "test_epsilon.py"]')
    )
    _git(checkout, "add", "tests/test_delta.py", "elsewhere", "tests/test_epsilon.py")
    before = _git(checkout, "status", "--short")
    p = _sort(checkout)
    assert p.returncode == 2, p.stdout
    assert "nothing changed" in p.stderr
    assert "tests/test_gamma.py: not in tools/test-kinds.toml" in p.stderr  # named
    assert "tests/test_delta.py:2: its own __file__ used in a way this script does not know" in p.stderr
    assert "tests/test_epsilon.py: a symbolic link (moved one folder deeper" in p.stderr  # (it would dangle)
    assert "Traceback" not in p.stderr
    assert _git(checkout, "status", "--short") == before
    assert (checkout / "tests" / "test_alpha.py").read_text() == ALPHA


@pytest.mark.parametrize(
    "table, said",
    [
        (
            'unit = ["test_alpha.py"]\nsmoke = ["test_beta.py"]\n',
            "tools/test-kinds.toml: unknown kind 'smoke' (one of unit, ",
        ),
        (
            'unit = ["test_alpha.py", "test_beta.py"]\nhouse = ["test_beta.py"]\n',
            "test_beta.py is under both unit and house",
        ),
        ('unit = ["alpha.py"]\n', "'alpha.py' under unit is not a test module's name (test_x.py)"),
        ('unit = ["test_alpha.py"\n', "tools/test-kinds.toml: cannot read the table of kinds ("),
    ],
)
def test_a_table_it_cannot_use_is_one_sentence_and_exit_2(checkout, table, said):
    (checkout / "tools" / "test-kinds.toml").write_text(table)
    p = _sort(checkout)
    assert p.returncode == 2 and p.stderr.startswith("sort-tests: nothing changed: ") and said in p.stderr, p.stderr
    assert "Traceback" not in p.stderr and p.stderr.count("\n") == 1


def test_changes_not_committed_in_a_file_it_would_touch_stop_it(checkout):
    (checkout / "docs" / "faults.md").write_text(DOC + "| b | a row being written |\n")
    p = _sort(checkout)
    assert p.returncode == 2 and "docs/faults.md: has changes not committed; commit them first" in p.stderr, p.stderr
    assert (checkout / "tests" / "test_alpha.py").exists() and not (checkout / "tests" / "unit").exists()


def test_stopped_half_way_it_puts_the_checkout_back(checkout, monkeypatch, capsys):
    """A rewrite that fails after the modules moved (a full disk): every file as committed again."""
    path = str(checkout / "tools" / "sort-tests")
    spec = importlib.util.spec_from_file_location(
        "sort_tests_copy", path, loader=importlib.machinery.SourceFileLoader("sort_tests_copy", path)
    )
    script = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, script)  # (its dataclass looks itself up there)
    spec.loader.exec_module(script)
    write = Path.write_bytes

    def full_disk(self, *args, **kwargs):
        if self.name == "faults.md":
            raise OSError(errno.ENOSPC, "No space left on device", str(self))
        return write(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_bytes", full_disk)
    assert script.main([]) == 3
    said = capsys.readouterr().err
    assert "stopped half-way ([Errno 28] No space left on device" in said and "the checkout is back as it was" in said
    assert _git(checkout, "status", "--porcelain") == ""
    assert (checkout / "tests" / "test_alpha.py").read_text() == ALPHA and not (checkout / "tests" / "unit").exists()


KILLED_AFTER_THE_MOVES = """import importlib.machinery, importlib.util, os, signal, sys
from pathlib import Path
path = sys.argv[1]
loader = importlib.machinery.SourceFileLoader("sort_tests_copy", path)
spec = importlib.util.spec_from_file_location("sort_tests_copy", path, loader=loader)
script = importlib.util.module_from_spec(spec)
sys.modules[spec.name] = script
spec.loader.exec_module(script)
Path.write_bytes = lambda self, *a, **k: os.kill(os.getpid(), signal.SIGKILL)  # the first rewrite
script.main([])
"""


def test_killed_after_its_moves_a_second_run_finishes_the_job(checkout):
    """kill -9 between the `git mv`s and the rewrites: the modules moved (staged) as committed.
    Run again, it rewrites what the first run did not, the moved modules' own paths too."""
    killed = subprocess.run(
        [sys.executable, "-c", KILLED_AFTER_THE_MOVES, str(checkout / "tools" / "sort-tests")],
        cwd=checkout,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert killed.returncode == -9, killed.stderr
    tests = checkout / "tests"
    assert (tests / "unit" / "test_alpha.py").read_text() == ALPHA  # moved, not rewritten
    p = _sort(checkout)
    assert p.returncode == 0, p.stderr
    alpha = (tests / "unit" / "test_alpha.py").read_text()
    assert "REPO = Path(__file__).resolve().parents[2]" in alpha  # one folder deeper
    assert 'Path(__file__).parents[1] / "data"' in alpha
    assert "Run `tests/unit/test_alpha.py`" in (checkout / "docs" / "faults.md").read_text()
    again = _sort(checkout)
    assert again.returncode == 0 and "nothing to do" in again.stdout, again.stderr
    assert (tests / "unit" / "test_alpha.py").read_text() == alpha
