import os
import re
import tempfile
from pathlib import Path

import pytest

import vts_hw  # noqa: F401  (first: one BLAS thread, decision 0075, before anything loads NumPy)
from module_order import longest_first
from timeline import pytest_runtest_protocol  # noqa: F401  (VTS_TIMELINE=FILE: where the time goes)

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("VTS_SHARED_DATA", REPO.parent / "shared" / "data"))


def pytest_configure(config):
    """No test writes the user's own results store (the per-user default, used when a rig.yaml
    names none): the per-user data folder is a fresh one for the session (and its commands)."""
    os.environ["XDG_DATA_HOME"] = tempfile.mkdtemp(prefix="vts-test-data-")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """../shared/data beside the checkout (real Axis frames, real checkerboard pairs)."""
    assert SHARED_DATA.is_dir(), f"real test data missing: {SHARED_DATA} (set VTS_SHARED_DATA)"
    return SHARED_DATA


@pytest.fixture(scope="session")
def axis_frames(shared_data) -> Path:
    return shared_data / "axis-frames"


@pytest.fixture()
def sim_rig():
    """A fresh simulated rig of two cameras for each test (no state leaks between tests)."""
    from vts_hw.sim_devices.rig import SimRig

    with SimRig(n_cameras=2, seed=1) as rig, rig.env():
        yield rig


@pytest.fixture()
def cam1(sim_rig):
    from vts_hw.drivers.registry import open_camera

    with open_camera(sim_rig.config().camera("cam1")) as cam:
        yield cam


from console_live import browser  # noqa: E402  (fixture: Debian's Chromium, one per test module)
from fsfaults import readonly_dir, small_disk  # noqa: E402  (fixtures: a full disk, a read-only folder)
from store_kit import db, sqlite_store, store  # noqa: E402  (fixtures: a fresh results store, its SQLite file)

SHARED_FIXTURES = (
    readonly_dir,
    small_disk,
    browser,
    db,
    sqlite_store,
    store,
)  # every test's, though written in those modules


# -- PostgreSQL: one throwaway server for the session, a fresh database per test ----------------


@pytest.fixture(scope="session")
def pg_server():
    """A PostgreSQL server of the session's own (tests/pgserver.py), started on first use."""
    from pgserver import PgServer

    server = PgServer().start()
    yield server
    server.stop()


@pytest.fixture()
def pg_url(pg_server):
    """The URL of a fresh, empty database on the session's server (superuser, unix socket),
    dropped after the test."""
    name = pg_server.new_database()
    yield pg_server.url(name)
    pg_server.drop_database(name)


@pytest.fixture(params=["sqlite", "postgresql"])
def store_url(request, tmp_path) -> str:
    """A fresh results store's URL on each back end: an SQLite file, a PostgreSQL database."""
    if request.param == "sqlite":
        return f"sqlite:///{tmp_path / 'data' / 'results.sqlite'}"
    return request.getfixturevalue("pg_url")


# -- the real QATrack+ (../shared/interop/qatrack): started while the rest of the suite runs ---------
# One process starts it: the session's only process, or with pytest-xdist (make test runs two
# workers) the controller, which outlives the workers; the real_qatrack tests are one module run by
# one worker (make test's --dist loadscope; they restart the one server in other zones), handed out
# when half the suite's time is (tests/module_order.py). (With --dist loadgroup the module's own
# xdist_group mark keeps them on one worker.)

_REAL_QATRACK = None


def _real_qatrack():
    global _REAL_QATRACK
    if _REAL_QATRACK is None:
        from qatrack_real import RealQATrack

        _REAL_QATRACK = RealQATrack()
    return _REAL_QATRACK


def _xdist_worker(config) -> bool:
    return hasattr(config, "workerinput")


def _xdist_controller(config) -> bool:
    return not _xdist_worker(config) and bool(getattr(config.option, "numprocesses", None))


REAL_QATRACK_MARKS = {"real_qatrack", "interop", "xdist_group", "timeout", "parametrize"}  # its module's


def _selects(expr: str, marks: set[str]) -> bool:
    """Whether `-m EXPR` selects a test with these marks (names, and, or, not, parentheses); an
    expression read otherwise counts as selecting it."""
    if not expr.strip():
        return True
    words = re.sub(r"\w+", lambda m: m[0] if m[0] in ("and", "or", "not") else str(m[0] in marks), expr)
    if not re.fullmatch(r"(?:\s|\(|\)|\bTrue\b|\bFalse\b|\band\b|\bor\b|\bnot\b)*", words):
        return True
    try:
        return bool(eval(words, {"__builtins__": {}}))  # (only True, False, and, or, not, parentheses)
    except SyntaxError:
        return True


def _may_select_real_qatrack(config) -> bool:
    """Whether the session's arguments can reach tests/interop/test_qatrack_real.py (the controller of
    an xdist session collects nothing, so it judges by the arguments and -m)."""
    if not _selects(config.option.markexpr or "", REAL_QATRACK_MARKS):
        return False  # (-m unit, -m "not real_qatrack", ...)
    target = (Path(__file__).parent / "interop" / "test_qatrack_real.py").resolve()
    args = [a.split("::")[0] for a in config.args] or [str(Path(__file__).parent)]
    for a in args:
        p = Path(a).resolve()
        if p == target or (p.is_dir() and target.is_relative_to(p)):
            return True
    return False


def kinds(config) -> set[str]:
    """The kinds of test, each a folder of tests/: the markers pyproject.toml describes as "kind:"."""
    return {m.split(":")[0] for m in config.getini("markers") if m.split(":")[1:2] == [" kind"]}


def pytest_itemcollected(item):
    """Each test marked with its kind, the folder it is in (tests/unit/, tests/console/, ...), so
    that `pytest -m console` runs the console's tests (tools/sort-tests put the modules there;
    decision 0105; tests/house/test_kind_markers.py: no test module outside them)."""
    folder = item.path.parent
    if folder.parent == REPO / "tests" and folder.name in kinds(item.config):
        item.add_marker(folder.name)


def pytest_sessionstart(session):
    if _xdist_controller(session.config) and _may_select_real_qatrack(session.config):
        _real_qatrack().start_in_background()
        _real_qatrack().note_when_started()


@pytest.hookimpl(trylast=True)  # after -m has deselected (pytest -m unit starts no QATrack+)
def pytest_collection_modifyitems(session, config, items):
    """The longest modules first (tests/module_order.py), the real QATrack+'s where half the
    time is handed out; the real server starts installing now (unless an xdist controller
    started it)."""
    real = {i.nodeid.split("::")[0] for i in items if i.get_closest_marker("real_qatrack")}
    items[:] = longest_first(items, late=real)
    if real and not _xdist_worker(config):
        _real_qatrack().start_in_background()


def pytest_sessionfinish(session, exitstatus):
    if _REAL_QATRACK is not None and _REAL_QATRACK.started_by_us and not _xdist_worker(session.config):
        _REAL_QATRACK.stop()


@pytest.fixture(scope="session")
def real_qatrack(request):
    """The real QATrack+ 3.1 on 127.0.0.1 (tests/qatrack_real.py), once it is up."""
    if _xdist_worker(request.config):
        return _real_qatrack().wait_for_other()
    return _real_qatrack().wait()
