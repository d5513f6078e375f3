"""The results store: round trips, tolerance history, one-transaction runs, kill -9, concurrent
readers and the default path (its schema, upgrades and PostgreSQL portability:
tests/integration/test_store_schema.py).

Tests taking ``store``/``store_url`` run on both back ends: an SQLite file and a database on
the session's throwaway PostgreSQL server (tests/pgserver.py). The SQLite-only ones (PRAGMAs,
the WAL, raw sqlite3 access) use ``sqlite_store``/``db``; where the property matters on
PostgreSQL too it has a counterpart here or in tests/integration/test_store_writers.py (kill -9)."""

import hashlib
import os
import random
import re
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from store_kit import _check_file, _is_pg, _raw, _sql
from vts_hw.store import SCHEMA_VERSION, ResultsStore, RunHandle, default_url
from vts_hw.store.errors import StoreError
from vts_hw.store.store import _new_id
from vts_hw.tolerance import State, Window

DRIFT = Window.symmetric(1.0, 2.0, "px")  # |x| <= 1 OK, <= 2 TOLERANCE, else ACTION
MISSING = Window(tolerance_high=0, action_high=1, unit="markers")
T0 = 1_700_000_000.0  # a fixed epoch for reproducible histories


# -- round trip -----------------------------------------------------------------------------


def test_round_trip_with_statuses_from_windows_and_artifacts(store, store_url, tmp_path):
    store.set_tolerance("drift_x_px", DRIFT, effective_from=T0)
    store.set_tolerance("markers_missing", MISSING, effective_from=T0)
    frame = tmp_path / "cam1.jpg"
    frame.write_bytes(b"\xff\xd8 not really a jpeg \xff\xd9" * 100)
    with store.begin_run(
        "drift", rig="room3", operator="ak", notes="morning", config_digest="c0ffee", started=T0 + 100
    ) as run:
        assert isinstance(run, RunHandle)
        assert run.measure("cam1", "drift_x_px", 0.4) is State.OK
        assert run.measure("cam2", "drift_x_px", -1.5) is State.TOLERANCE
        assert run.measure("cam1", "markers_missing", 0, unit="markers") is State.OK
        assert run.measure("cam1", "brightness", 17.0, unit="DN") is State.OK  # no window
        assert run.measure("cam2", "brightness", 3.0, status="ACTION") is State.ACTION  # given
        sha = run.artifact(frame)
        run.artifact(frame, kind="snapshot")
    assert sha == hashlib.sha256(frame.read_bytes()).hexdigest()

    [r] = store.runs()
    assert r == store.run(run.run_id)
    assert (r.procedure, r.rig, r.operator, r.notes, r.config_digest) == ("drift", "room3", "ak", "morning", "c0ffee")
    assert r.started == T0 + 100 and r.finished >= r.started
    assert r.status == "ACTION"  # worst of the five
    import vts_hw

    assert r.software_version == vts_hw.__version__

    ms = store.measurements(run_id=r.id)
    drift_id = store.tolerance("drift_x_px", at=T0)[0]
    assert [(m.subject, m.metric, m.value, m.unit, m.status, m.tolerance_id, m.started) for m in ms] == [
        ("cam1", "drift_x_px", 0.4, "px", State.OK, drift_id, T0 + 100),  # unit from the window
        ("cam2", "drift_x_px", -1.5, "px", State.TOLERANCE, drift_id, T0 + 100),
        ("cam1", "markers_missing", 0.0, "markers", State.OK, store.tolerance("markers_missing")[0], T0 + 100),
        ("cam1", "brightness", 17.0, "DN", State.OK, None, T0 + 100),
        ("cam2", "brightness", 3.0, "", State.ACTION, None, T0 + 100),
    ]
    arts = store.artifacts(r.id)
    assert [(a.path, a.sha256, a.kind) for a in arts] == [(str(frame), sha, "frame"), (str(frame), sha, "snapshot")]
    # filters
    assert [m.subject for m in store.measurements(metric="drift_x_px")] == ["cam1", "cam2"]
    assert len(store.measurements(metric=("drift_x_px", "brightness"), subject="cam2")) == 2
    assert store.measurements(procedure="other") == [] and len(store.measurements(procedure=("other", "drift"))) == 5
    assert store.measurements(since=T0 + 101) == [] and len(store.measurements(since=T0 + 100)) == 5
    assert store.runs(status="ACTION") == [r] and store.runs(status=("OK", "TOLERANCE")) == []
    assert store.runs(procedure="drift", since=T0) == [r] and store.runs(since=T0 + 101) == []
    with pytest.raises(KeyError):
        store.run(999)
    _check_file(store_url)


def test_runs_and_measurements_come_oldest_first_by_run_start(store):
    # written newest first: the order must come from the run start, not the id
    for started in (T0 + 30, T0 + 10, T0 + 20):
        with store.begin_run("drift", started=started) as run:
            run.measure("a", "m", started - T0)
            run.measure("b", "m", started - T0 + 0.5)
    assert [r.started - T0 for r in store.runs()] == [10, 20, 30]
    assert [m.value for m in store.measurements(metric="m")] == [10, 10.5, 20, 20.5, 30, 30.5]


@pytest.mark.parametrize(
    "values, expected",
    [
        ([], "OK"),
        ([0.1, -0.9], "OK"),
        ([0.1, 1.5, -0.2], "TOLERANCE"),
        ([1.5, -2.5, 0.0], "ACTION"),
        ([None], "ACTION"),  # could not be measured
        ([float("nan"), 0.0], "ACTION"),
    ],
)
def test_run_status_is_the_worst_of_its_measurements(store, values, expected):
    store.set_tolerance("drift_x_px", DRIFT, effective_from=T0)
    run = store.begin_run("drift")
    for v in values:
        run.measure("cam1", "drift_x_px", v)
    assert run.finish().status == expected
    assert all(m.value is None or m.value == m.value for m in store.measurements())  # NaN stored as None


def test_finish_status_given_and_handle_closed_after(store):
    run = store.begin_run("sync")
    run.measure("cam1", "m", 1.0, status=State.TOLERANCE)
    with pytest.raises(ValueError):
        run.finish(status="aborted")  # abort() is the way to abort
    with pytest.raises(ValueError):
        run.measure("cam1", "m", 1.0, status="BAD")
    r = run.finish(status="error", notes="camera 2 unreachable")
    assert (r.status, r.notes) == ("error", "camera 2 unreachable")
    assert len(store.measurements(run_id=r.id)) == 1  # an error run keeps what it measured
    assert run.done
    for call in (lambda: run.measure("a", "m", 1.0), run.finish, lambda: run.abort("late")):
        with pytest.raises(RuntimeError):
            call()


def test_begin_run_commits_a_running_row_at_once(store, store_url):
    run = store.begin_run("drift", rig="room3")
    # another connection sees it before finish
    [row] = _sql(store_url, "SELECT status, host, pid FROM runs WHERE id = :id", params={"id": run.run_id})
    assert row[0] == "running" and row[2] == os.getpid() and row[1]
    assert store.mark_dead_runs_aborted() == 0  # our own, live process
    run.finish()


# -- tolerance history ---------------------------------------------------------------------


def test_a_later_tolerance_change_leaves_old_results_and_windows_alone(store):
    first = store.set_tolerance("drift_x_px", DRIFT, effective_from=T0, note="commissioning")
    with store.begin_run("drift", started=T0 + 86400) as run:
        assert run.measure("cam1", "drift_x_px", 1.5) is State.TOLERANCE
    before = store.measurements()

    wider = Window.symmetric(2.0, 4.0, "px")
    second = store.set_tolerance("drift_x_px", wider, effective_from=T0 + 2 * 86400, note="new mount")
    assert second != first
    # identical to the one in effect then: nothing added
    assert store.set_tolerance("drift_x_px", wider, effective_from=T0 + 3 * 86400) == second
    assert store.set_tolerance("drift_x_px", DRIFT, effective_from=T0 + 100) == first

    assert store.measurements() == before  # status and window id unchanged
    assert store.runs()[0].status == "TOLERANCE"
    assert store.tolerance("drift_x_px", at=T0 + 86400) == (first, DRIFT)
    assert store.tolerance("drift_x_px", at=T0 + 2 * 86400) == (second, wider)
    assert store.tolerance("drift_x_px") == (second, wider)
    assert store.tolerance("drift_x_px", at=T0 - 1) is None
    assert store.tolerances(at=T0 + 1) == {"drift_x_px": (first, DRIFT)}

    # a new run is judged with the window in effect at its start, or at the time given
    with store.begin_run("drift", started=T0 + 5 * 86400) as run:
        assert run.measure("cam1", "drift_x_px", 1.5) is State.OK
        assert run.measure("cam1", "drift_x_px", 1.5, at=T0 + 86400) is State.TOLERANCE
    assert [m.tolerance_id for m in store.measurements(run_id=run.run_id)] == [second, first]


def test_sync_tolerances_adds_only_what_changed(store, store_url):
    windows = {"drift_x_px": DRIFT, "markers_missing": MISSING}
    assert store.sync_tolerances(windows, at=T0) == ["drift_x_px", "markers_missing"]
    assert store.sync_tolerances(windows, at=T0 + 10) == []
    changed = dict(windows, markers_missing=Window(tolerance_high=1, action_high=2, unit="markers"))
    assert store.sync_tolerances(changed, at=T0 + 20) == ["markers_missing"]
    assert store.sync_tolerances({"drift_x_px": DRIFT}, at=T0 + 30) == []  # others keep theirs
    now = store.tolerances(at=T0 + 30)
    assert now["markers_missing"][1] == changed["markers_missing"] and now["drift_x_px"][1] == DRIFT
    assert store.tolerances(at=T0 + 10)["markers_missing"][1] == MISSING
    assert _sql(store_url, "SELECT count(*) FROM tolerances") == [(3,)]  # append-only


# -- one transaction ----------------------------------------------------------------------


def _fail_artifact_inserts(url: str) -> None:
    """A database-level failure in the middle of finish(): after the run update and the
    measurements are written, the artifact insert is refused by the database itself."""
    if _is_pg(url):
        _sql(
            url,
            "CREATE FUNCTION fail() RETURNS trigger LANGUAGE plpgsql AS "
            "$$ BEGIN RAISE EXCEPTION 'injected failure'; END $$",
            "CREATE TRIGGER fail_artifacts BEFORE INSERT ON artifacts FOR EACH ROW EXECUTE FUNCTION fail()",
        )
    else:
        _sql(
            url,
            "CREATE TRIGGER fail_artifacts BEFORE INSERT ON artifacts "
            "BEGIN SELECT RAISE(ABORT, 'injected failure'); END",
        )


def _allow_artifact_inserts(url: str) -> None:
    _sql(url, "DROP TRIGGER fail_artifacts" + (" ON artifacts" if _is_pg(url) else ""))


def test_a_failure_inside_finish_stores_nothing_of_the_run(store, store_url, tmp_path):
    frame = tmp_path / "f.jpg"
    frame.write_bytes(b"frame")
    run = store.begin_run("drift")
    for i in range(50):
        run.measure(f"cam{i % 2}", "drift_x_px", i / 100)
    run.artifact(frame)
    _fail_artifact_inserts(store_url)
    with pytest.raises(Exception, match="injected failure"):
        run.finish(notes="should not appear")
    assert store.measurements() == [] and store.artifacts(run.run_id) == []
    r = store.run(run.run_id)
    assert (r.status, r.finished, r.notes) == ("running", None, "")
    assert not run.done
    _check_file(store_url)
    # the handle kept everything: once the database accepts it, the run is stored whole
    _allow_artifact_inserts(store_url)
    assert run.finish().status == "OK"
    assert len(store.measurements(run_id=run.run_id)) == 50 and len(store.artifacts(run.run_id)) == 1


def test_context_manager_aborts_when_its_finish_fails(store, store_url, tmp_path):
    frame = tmp_path / "f.jpg"
    frame.write_bytes(b"frame")
    _fail_artifact_inserts(store_url)
    with pytest.raises(Exception, match="injected failure"):
        with store.begin_run("drift") as run:
            run.measure("cam1", "m", 1.0)
            run.artifact(frame)
    r = store.run(run.run_id)
    assert r.status == "aborted" and "finish failed" in r.notes and "injected failure" in r.notes
    assert store.measurements() == []


def test_context_manager_aborts_on_exception(store):
    with pytest.raises(ZeroDivisionError):
        with store.begin_run("drift", notes="operator note") as run:
            run.measure("cam1", "drift_x_px", 0.1)
            1 / 0
    r = store.run(run.run_id)
    assert r.status == "aborted" and r.finished is not None
    assert r.notes.startswith("operator note\naborted: unexpected error (ZeroDivisionError): division by zero")
    assert "1 measurement(s) not stored" in r.notes
    assert store.measurements() == [] and store.artifacts(r.id) == []


def test_a_users_error_is_noted_by_its_sentence_not_its_class(store):
    from vts_hw.errors import DataError

    with pytest.raises(DataError):
        with store.begin_run("drift") as run:
            raise DataError("camera cam2 has no drift baseline")
    assert store.run(run.run_id).notes == "aborted: camera cam2 has no drift baseline"


def test_context_manager_aborts_on_keyboard_interrupt(store):
    with pytest.raises(KeyboardInterrupt):
        with store.begin_run("drift") as run:
            run.measure("cam1", "drift_x_px", 0.1)
            raise KeyboardInterrupt
    r = store.run(run.run_id)
    assert r.status == "aborted" and "interrupted (KeyboardInterrupt)" in r.notes
    assert store.measurements() == []


def test_explicit_abort_and_finish_inside_the_block(store):
    with store.begin_run("drift") as run:
        run.abort("phantom not in place")
    assert store.run(run.run_id).notes == "aborted: phantom not in place"
    with store.begin_run("drift") as run:
        run.measure("c", "m", 1.0)
        r = run.finish(status="TOLERANCE")
    assert store.run(run.run_id) == r and r.status == "TOLERANCE"  # not finished twice


# -- kill -9 --------------------------------------------------------------------------------

WRITER = r"""
import random, sys, time
from vts_hw.store import ResultsStore
from vts_hw.tolerance import Window

url, seed, frame, count = sys.argv[1], int(sys.argv[2]), sys.argv[3], int(sys.argv[4])
rng = random.Random(seed)
store = ResultsStore(url)
store.sync_tolerances({"drift_x_px": Window.symmetric(1.0, 2.0, "px")}, at=0.0)
print("open", flush=True)
i = 0
while count < 0 or i < count:
    i += 1
    if rng.random() < 0.1:   # tolerance writes get killed too
        store.set_tolerance("drift_x_px", Window.symmetric(rng.uniform(0.5, 1.5), 2.0, "px"))
    n = rng.randint(1, 40)
    run = store.begin_run("writer", notes=f"n={n}")
    print("begun", run.run_id, flush=True)
    for k in range(n):
        run.measure(f"cam{k % 2}", "drift_x_px", rng.uniform(-3.0, 3.0))
        if k % 10 == 0:
            time.sleep(0.004)      # acquisition between measurements
    run.artifact(frame)
    if rng.random() < 0.1:
        run.abort("operator cancelled")
    else:
        run.finish()
    print("ended", run.run_id, flush=True)
"""


def _writer(tmp_path: Path, url: str, seed: int, count: int) -> subprocess.Popen:
    script = tmp_path / "writer.py"
    script.write_text(WRITER)
    frame = tmp_path / "frame.jpg"
    if not frame.exists():
        frame.write_bytes(os.urandom(4096))
    return subprocess.Popen(
        [sys.executable, str(script), url, str(seed), str(frame), str(count)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=tmp_path,
    )


def _n_of(run) -> int:
    return int(re.match(r"n=(\d+)", run.notes).group(1))


def _check_runs_whole(store: ResultsStore, frame: Path, where: str) -> int:
    """Every run is complete or aborted-without-data; return how many are complete."""
    sha = hashlib.sha256(frame.read_bytes()).hexdigest()
    complete = 0
    for r in store.runs():
        ms = store.measurements(run_id=r.id)
        arts = store.artifacts(r.id)
        assert r.status != "running", f"{where}: run {r.id} still running after open"
        if r.status == "aborted":
            assert ms == [] and arts == [], f"{where}: aborted run {r.id} has data"
            continue
        complete += 1
        assert len(ms) == _n_of(r), f"{where}: run {r.id} has {len(ms)} of {_n_of(r)} measurements"
        assert [(a.sha256, a.path) for a in arts] == [(sha, str(frame))], f"{where}: run {r.id} artifacts"
        assert r.status == max((m.status for m in ms), key=lambda s: s.rank).value
        assert r.finished is not None
    return complete


@pytest.mark.slow
def test_store_survives_kill_9_at_random_moments(tmp_path):
    db = tmp_path / "results.sqlite"
    url = f"sqlite:///{db}"
    seed = int(os.environ.get("VTS_KILL_SEED", random.SystemRandom().randrange(1 << 30)))
    rng = random.Random(seed)
    frame = tmp_path / "frame.jpg"
    dead_found = complete = 0
    # at least 6 kills; more (up to 20) until one has landed inside a run: on a loaded machine
    # a random moment can fall between runs several times in a row
    for i in range(20):
        if i >= 6 and dead_found and complete:
            break
        where = f"kill {i} (VTS_KILL_SEED={seed})"
        proc = _writer(tmp_path, url, seed + i, count=-1)
        if i == 0:
            time.sleep(rng.uniform(0.0, 0.8))  # anywhere from start-up through schema creation
        else:
            assert proc.stdout.readline() == "open\n", f"{where}: {proc.stderr.read()}"
            time.sleep(rng.uniform(0.0, 0.4))
        proc.kill()  # SIGKILL
        out, err = proc.communicate()
        assert proc.returncode == -9, f"{where}: writer ended by itself: {err}"
        begun = [int(x) for x in re.findall(r"^begun (\d+)$", out, re.M)]
        ended = {int(x) for x in re.findall(r"^ended (\d+)$", out, re.M)}
        if not db.exists():
            continue
        _check_file(db)
        with ResultsStore(url) as store:  # opening marks the killed run aborted
            assert store.schema_version == SCHEMA_VERSION
            assert store.runs(status="running") == []
            complete = _check_runs_whole(store, frame, where)
            if begun and begun[-1] not in ended:
                # killed inside a run (or after its last commit but before it said so)
                r = store.run(begun[-1])
                if r.status == "aborted" and "ended without finishing" in r.notes:
                    dead_found += 1
        _check_file(db)
    assert complete > 0, f"no run completed (VTS_KILL_SEED={seed})"
    assert dead_found >= 1, f"no kill landed inside a run (VTS_KILL_SEED={seed})"


def test_a_run_left_running_by_a_dead_process_is_aborted_on_open(store_url):
    code = (
        "import sys; from vts_hw.store import ResultsStore\n"
        "s = ResultsStore(sys.argv[1]); h = s.begin_run('drift', notes='left behind')\n"
        "h.measure('cam1', 'm', 1.0); print(h.run_id)\n"
        "import os; os._exit(0)\n"
    )  # exits without finishing or aborting
    out = subprocess.run([sys.executable, "-c", code, store_url], capture_output=True, text=True, check=True)
    run_id = int(out.stdout)
    assert _sql(store_url, "SELECT status FROM runs WHERE id = :id", params={"id": run_id}) == [("running",)]
    # one more "running" row from another host: not ours to judge
    _sql(
        store_url,
        "INSERT INTO runs (procedure, started, status, host, pid, uid) "
        "VALUES ('x', 0, 'running', 'elsewhere', 1, 'elsewhere1')",
    )
    with ResultsStore(store_url) as store:
        r = store.run(run_id)
        assert r.status == "aborted" and r.finished is None
        assert r.notes.startswith("left behind\naborted: its process (pid ")
        assert [x.procedure for x in store.runs(status="running")] == ["x"]
        assert store.mark_dead_runs_aborted() == 0
        assert store.measurements() == []


# -- concurrency ---------------------------------------------------------------------------


def test_readers_are_not_blocked_by_a_writer_holding_a_big_transaction(sqlite_store, db):
    store = sqlite_store
    with store.begin_run("drift") as run:
        run.measure("cam1", "m", 1.0)
    writer = _raw(db)
    writer.execute("PRAGMA cache_size = 1")  # forces the writer to spill pages before commit
    writer.execute("BEGIN IMMEDIATE")
    writer.executemany(
        "INSERT INTO runs (procedure, started, status, notes, uid) VALUES ('big', 0, 'OK', ?, ?)",
        [("x" * 500, f"big{i}") for i in range(3000)],
    )
    try:
        # a reader that would give up after 0.2 s sees the committed state at once
        with ResultsStore(str(db), busy_timeout=0.2) as reader:
            # (a reader blocked by the writer would fail with "database is locked" after 0.2 s)
            assert [r.procedure for r in reader.runs()] == ["drift"]
            assert len(reader.measurements()) == 1
    finally:
        writer.execute("COMMIT")
        writer.close()
    assert len(store.runs(procedure="big")) == 3000


@pytest.mark.slow
def test_concurrent_readers_see_whole_runs_while_a_writer_writes(tmp_path, store_url):
    url = store_url
    ResultsStore(url).close()
    proc = _writer(tmp_path, url, seed=7, count=40)
    frame = tmp_path / "frame.jpg"
    seen: list[int] = []
    errors: list[BaseException] = []

    def read_loop():
        try:
            with ResultsStore(url, busy_timeout=1.0) as reader:
                while proc.poll() is None:
                    ended = reader.runs(status=("OK", "TOLERANCE", "ACTION"))
                    # one snapshot per call: every run finished in it has all its measurements
                    ms = reader.measurements(procedure="writer")
                    for r in ended:
                        assert sum(m.run_id == r.id for m in ms) >= _n_of(r)
                    by_run = {}
                    for m in ms:
                        by_run[m.run_id] = by_run.get(m.run_id, 0) + 1
                    for run_id, n in by_run.items():
                        assert n == _n_of(reader.run(run_id)), f"run {run_id}: partial"
                    seen.append(len(ended))
        except BaseException as exc:  # reported by the main thread
            errors.append(exc)

    threads = [threading.Thread(target=read_loop) for _ in range(3)]
    for t in threads:
        t.start()
    out, err = proc.communicate(timeout=60)
    for t in threads:
        t.join(timeout=30)
    assert proc.returncode == 0, err
    assert not errors, errors[0]
    assert len(seen) > 10 and len(set(seen)) > 3, "readers did not overlap the writer"
    with ResultsStore(url) as store:
        assert len(store.runs()) == 40
        _check_runs_whole(store, frame, "after concurrent writes")


# -- where it lives ---------------------------------------------------------------------------


def test_default_path_honours_xdg_data_home(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert default_url() == f"sqlite:///{tmp_path}/xdg/vts-hw/results.sqlite"
    with ResultsStore() as store:
        assert store.url == default_url()
        assert repr(store) == f"ResultsStore('{default_url()}')"
    assert (tmp_path / "xdg" / "vts-hw" / "results.sqlite").is_file()

    monkeypatch.setenv("XDG_DATA_HOME", "relative/dir")  # the spec says: ignore it
    assert default_url() == f"sqlite:///{tmp_path}/home/.local/share/vts-hw/results.sqlite"
    monkeypatch.delenv("XDG_DATA_HOME")
    assert default_url() == f"sqlite:///{tmp_path}/home/.local/share/vts-hw/results.sqlite"
    assert default_url().startswith("sqlite:////")


def test_a_plain_path_is_a_sqlite_file(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with ResultsStore("sub/r.sqlite") as store:
        assert store.url == f"sqlite:///{tmp_path}/sub/r.sqlite"
    with ResultsStore(tmp_path / "p.sqlite") as store:
        assert store.url.endswith("/p.sqlite")
    store.close()
    with pytest.raises(RuntimeError, match="closed"):
        store.runs()


def test_a_new_row_without_its_id_is_a_store_error():
    """An insert whose primary key SQLAlchemy does not give back (no row, or None in it: a key
    the database made without returning it) is one StoreError, not a TypeError from int(None)."""
    assert _new_id(SimpleNamespace(inserted_primary_key=(7,))) == 7
    for key in (None, (None,)):
        with pytest.raises(StoreError, match="gave no id for the row just added"):
            _new_id(SimpleNamespace(inserted_primary_key=key))
