"""`vts store migrate`: a store copied SQLite -> PostgreSQL -> SQLite whole and verified; twice
adds nothing; room stores merged into one department store; a copy that differs is named;
the drift report from the PostgreSQL copy has the same numbers as from the SQLite original."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from sqlalchemy import create_engine, text

from inprocess_cli import run
from test_report import NOW, populate
from vts_hw.report import build_drift_report
from vts_hw.store import ResultsStore
from vts_hw.store.copy import copy_store, table_counts, verify
from vts_hw.store.paths import to_url


@pytest.fixture(scope="module")
def demo_store(tmp_path_factory) -> str:
    """The drift report tests' 60 days, plus artifact records, outbox rows and a run still
    running (its process alive: this test's), in an SQLite file."""
    d = tmp_path_factory.mktemp("demo")
    frame = d / "cam1.jpg"
    frame.write_bytes(b"frame bytes")
    url = f"sqlite:///{d / 'results.sqlite'}"
    with ResultsStore(url) as s:
        populate(s)
        for r in s.runs(procedure="daily")[:3]:
            s.outbox_add(r.id, "qatrack", f"vts-{r.uid}")
        item = s.outbox_items("qatrack")[0]
        s.outbox_record(item.id, "sent", remote="http://qa.example/tli/1")
        with s.begin_run("steps", rig="vts", started=NOW) as h:
            h.measure("spheres", "slope_z", 1.001)
            h.artifact(frame, kind="plot")
        s.begin_run("daily", rig="vts", notes="still going")  # left running, by a live process
        # the console's action log (copied) and a user (not copied: its hash stays here)
        s.log_actions(
            [
                {
                    "at": NOW - 60,
                    "user": "ann",
                    "role": "operator",
                    "what": "LED on",
                    "detail": {"camera": "cam1"},
                    "rig": "vts",
                },
                {"at": NOW - 30, "user": "ann", "role": "operator", "what": "scan started", "rig": "vts"},
            ]
        )
        s.put_user("ann", "operator", "scrypt$32768$8$1$c2FsdA==$aGFzaA==")
    return url


def _vts(*args, env=None):
    """`vts ARGS` in this process (tests/inprocess_cli.py)."""
    return run(*args, env=env)


def _table(stdout: str) -> dict:
    """The CLI's verification table: table -> (source, in target, new, ok)."""
    out = {}
    for line in stdout.splitlines():
        parts = line.split()
        if len(parts) == 7 and parts[0] in ("runs", "tolerances", "measurements", "artifacts", "outbox", "actions"):
            out[parts[0]] = (int(parts[1]), int(parts[2]), int(parts[3]), parts[6])
    return out


def test_sqlite_to_postgresql_and_back_whole_and_verified_twice_adds_nothing(demo_store, pg_url, tmp_path):
    with ResultsStore(demo_store) as src:
        counts = table_counts(src)
    assert counts["runs"] == 66 and counts["artifacts"] == 1 and counts["outbox"] == 3 and counts["actions"] == 2
    p = _vts("store", "migrate", "--from", demo_store, "--to", pg_url)
    assert p.returncode == 0, p.stderr
    t = _table(p.stdout)
    assert t == {name: (n, n, n, "ok") for name, n in counts.items()}, p.stdout
    assert "1 run(s) still running in the source were copied as running" in p.stderr
    assert "copying runs: 66/66" in p.stderr
    assert "the source's 1 console user(s) were not copied" in p.stderr
    with ResultsStore(pg_url, mode="read") as t:
        assert t.users() == [] and [a.what for a in t.actions()[0]] == ["scan started", "LED on"]
    p = _vts("store", "migrate", "--from", demo_store, "--to", pg_url)
    assert p.returncode == 0 and "0 new" in p.stdout, p.stdout + p.stderr
    assert _table(p.stdout) == {name: (n, n, 0, "ok") for name, n in counts.items()}

    back = f"sqlite:///{tmp_path / 'back.sqlite'}"
    p = _vts("store", "migrate", "--from", pg_url, "--to", back, "--json")
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert data["ok"] and data["new"] == counts and data["running_copied"] == 1
    with ResultsStore(demo_store) as a, ResultsStore(back) as b:
        assert table_counts(b) == counts
        for ra, rb in zip(a.runs(), b.runs()):
            assert (ra.uid, ra.status, ra.notes, ra.started, ra.finished) == (
                rb.uid,
                rb.status,
                rb.notes,
                rb.started,
                rb.finished,
            )
            assert [(m.subject, m.metric, m.value, m.status) for m in a.measurements(run_id=ra.id)] == [
                (m.subject, m.metric, m.value, m.status) for m in b.measurements(run_id=rb.id)
            ]
        assert [(o.key, o.state, o.remote) for o in a.outbox_items("qatrack", states=("pending", "sent"))] == [
            (o.key, o.state, o.remote) for o in b.outbox_items("qatrack", states=("pending", "sent"))
        ]
        # every measurement's window is the same window (by content) in the copy
        wa = {w: win for w, win in a.tolerances(at=NOW).values()}
        wb = {w: win for w, win in b.tolerances(at=NOW).values()}
        assert sorted(map(repr, wa.values())) == sorted(map(repr, wb.values()))


def test_room_stores_merge_into_one_department_store(tmp_path, pg_url):
    rooms = []
    for room in ("room1", "room2"):
        url = f"sqlite:///{tmp_path / room}.sqlite"
        with ResultsStore(url) as s:
            for day in range(5):
                with s.begin_run("daily", rig=room, started=1e9 + day * 86400) as h:
                    h.measure("cam1", "drift_x_px", day * 0.1)
        rooms.append(url)
    with ResultsStore(pg_url) as dept:  # the department store already holds another room's run
        with dept.begin_run("daily", rig="room3", started=1e9) as h:
            h.measure("cam1", "drift_x_px", 0.5)
        for url in rooms:
            with ResultsStore(url) as room:
                rep = copy_store(room, dept)
                assert rep.ok and rep.new["runs"] == 5 and rep.new["measurements"] == 5
        for url in rooms:
            with ResultsStore(url) as room:
                again = copy_store(room, dept)
                assert again.ok and sum(again.new.values()) == 0 and again.skipped_runs == 5
        assert sorted({r.rig for r in dept.runs()}) == ["room1", "room2", "room3"]
        assert len(dept.runs()) == 11 and len(dept.measurements()) == 11


def test_a_copy_that_differs_is_named_and_exits_3(tmp_path):
    src = f"sqlite:///{tmp_path / 'a.sqlite'}"
    dst = f"sqlite:///{tmp_path / 'b.sqlite'}"
    with ResultsStore(src) as s:
        with s.begin_run("daily", rig="r") as h:
            h.measure("cam1", "drift_x_px", 0.25)
    assert _vts("store", "migrate", "--from", src, "--to", dst).returncode == 0
    engine = create_engine(to_url(dst))
    with engine.begin() as conn:  # the copy's value changed behind our back
        conn.execute(text("UPDATE measurements SET value = 0.26"))
    engine.dispose()
    p = _vts("store", "migrate", "--from", src, "--to", dst)
    assert p.returncode == 3 and "table(s) measurements" in p.stderr, p.stdout + p.stderr
    assert _table(p.stdout)["measurements"] == (1, 0, 0, "MISMATCH") and _table(p.stdout)["runs"][3] == "ok"
    with ResultsStore(src) as a, ResultsStore(dst) as b:
        assert [c.table for c in verify(a, b) if not c.ok] == ["measurements"]


def test_bad_arguments_are_one_sentence(tmp_path):
    src = tmp_path / "a.sqlite"
    ResultsStore(src).close()
    cases = [
        (["--from", str(tmp_path / "missing.sqlite"), "--to", str(tmp_path / "b.sqlite")], 3, "does not exist"),
        (["--from", "postgresql://u:hunter2@127.0.0.1/x", "--to", str(src)], 2, "--from-password-env"),
        (["--from", str(src), "--to", f"sqlite:///{src}"], 2, "the same store"),
        (["--from", str(src), "--to", "postgresql://u@127.0.0.1:1/x"], 3, "cannot read the results store"),
        (["--from", str(src), "--to", "nodb://x"], 3, "no SQLAlchemy dialect"),
    ]
    for args, code, words in cases:
        p = _vts("store", "migrate", *args)
        assert p.returncode == code and words in p.stderr, (args, p.returncode, p.stderr)
        assert "Traceback" not in p.stderr and "hunter2" not in p.stderr
    assert not (tmp_path / "missing.sqlite").exists()
    p = _vts("store", "migrate", "--help")
    assert p.returncode == 0 and "Exit status" in p.stdout


def test_the_drift_report_from_the_postgresql_copy_has_the_same_numbers(demo_store, pg_url, tmp_path):
    with ResultsStore(demo_store) as src, ResultsStore(pg_url) as pg:
        assert copy_store(src, pg).ok
        a = build_drift_report(src, tmp_path / "sqlite.html", now=NOW, rig="vts").results_data()
        b = build_drift_report(pg, tmp_path / "pg.html", now=NOW, rig="vts").results_data()
    assert a.pop("out") != b.pop("out")
    assert a["cameras"] and a["cameras"]["cam2"]  # the report has its numbers ...
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)  # ... the same on both


def test_a_store_being_written_is_copied_in_whole_runs(pg_url, tmp_path):
    """A writer finishing runs while the copy reads: every run in the copy is whole as of one
    moment (running with nothing, or ended with all its measurements and its artifact)."""
    from store_writers import HERE

    frame = tmp_path / "frame.jpg"
    frame.write_bytes(b"x" * 100)
    ResultsStore(pg_url).close()
    writer = subprocess.Popen(
        [sys.executable, str(HERE), pg_url, "3", "150", str(tmp_path / "done"), str(frame)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    copy = f"sqlite:///{tmp_path / 'copy.sqlite'}"
    try:
        assert writer.stdout.readline().startswith("open")
        copies = 0
        while writer.poll() is None or copies < 2:
            with ResultsStore(pg_url) as src, ResultsStore(copy) as dst:
                copy_store(src, dst)
            copies += 1
    finally:
        writer.wait(timeout=120)
    assert writer.returncode == 0, writer.stderr.read()
    with ResultsStore(copy) as dst:
        runs = dst.runs()
        assert len(runs) > 0
        for r in runs:
            ms, arts = dst.measurements(run_id=r.id), dst.artifacts(r.id)
            if r.status in ("running", "aborted"):
                assert ms == [] and arts == [], r
            else:
                assert len(ms) == int(r.notes.split("=")[1]) and len(arts) == 1, r


def test_a_later_copy_brings_a_run_that_has_ended_and_a_push_that_went_on(tmp_path, pg_url):
    src = f"sqlite:///{tmp_path / 'room.sqlite'}"
    with ResultsStore(src) as s:
        with s.begin_run("daily", rig="room1", started=1e9) as h:
            h.measure("cam1", "drift_x_px", 0.1)
        done = s.run(h.run_id)
        item = s.outbox_add(done.id, "qatrack", f"vts-run-{done.uid}")
        live = s.begin_run("daily", rig="room1", started=1e9 + 86400)  # still going at the first copy
        live.measure("cam1", "drift_x_px", 0.2)
        p = _vts("store", "migrate", "--from", src, "--to", pg_url, "--json")
        assert p.returncode == 0, p.stderr
        first = json.loads(p.stdout)
        assert first["running_copied"] == 1 and first["new"]["measurements"] == 1 and first["ok"]

        live.artifact(__file__, kind="plot")
        live.finish()  # the run ends, and the push of the other goes on
        s.outbox_record(item.id, "sent", remote="http://qa.example/api/qa/testlistinstances/7/")
        p = _vts("store", "migrate", "--from", src, "--to", pg_url)
        assert p.returncode == 0, p.stdout + p.stderr
        assert "brought over: 1 run(s) that have ended since an earlier copy, 1 outbox row(s)" in p.stdout
        assert all(ok == "ok" for *_, ok in _table(p.stdout).values()), p.stdout
        with ResultsStore(pg_url) as t:
            copied = t.run_by_uid(s.run(live.run_id).uid)
            assert copied.status == "OK" and copied.finished is not None
            assert [m.value for m in t.measurements(run_id=copied.id)] == [0.2]
            assert [a.kind for a in t.artifacts(copied.id)] == ["plot"]
            sent = t.outbox_items("qatrack")
            assert [(o.state, o.remote, o.attempts) for o in sent] == [
                ("sent", "http://qa.example/api/qa/testlistinstances/7/", 1)
            ]
            assert table_counts(t) == table_counts(s)

        p = _vts("store", "migrate", "--from", src, "--to", pg_url)
        assert p.returncode == 0 and "0 new" in p.stdout and "brought over" not in p.stdout, p.stdout
