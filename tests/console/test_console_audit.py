"""The console's action log is durable and says what happened (issue 32 §1, "Durable audit" and a
console action on a full disk).

* A Scan-page scan on a full disk (a real small tmpfs, tests/fsfaults.py: root, as CI runs):
  ``scan not started`` and why in the action log, no scan folder left behind, the page's state
  still served. A drift baseline whose store is on a full disk: ``drift baseline not set`` and
  why, never "set"; the action kept while the store cannot take it and written once it can.
  Two simulated Axis cameras over HTTP; the console served in process (Starlette's TestClient).
* Lock-outs: the wrong password that locks a name is ``locked out``, each try while locked
  ``login refused: locked``, under the name only when it is a user's.
* A store that is not ours (a foreign SQLite file), one it cannot write (a read-only mount) or
  none at all: the console is refused in one sentence before a camera is opened (exit 3, 2),
  the foreign file byte-identical; a good store gets ``console started`` first.
"""

from __future__ import annotations

import hashlib
import shutil
import sqlite3
import time
from types import SimpleNamespace

import pytest
from starlette.testclient import TestClient

from console_live import log_in
from vts_hw.console import refusals, users
from vts_hw.console.actions import StoreActions, durable_actions
from vts_hw.console.app import Console, create_app
from vts_hw.console.hub import FramesHub
from vts_hw.console.markers import MarkerWorker
from vts_hw.console.names import MarkerNames
from vts_hw.console.room import RoomFacts
from vts_hw.console.sessions import LOCK_AFTER, Auth
from vts_hw.console.users import add_user
from vts_hw.drivers.registry import open_camera
from vts_hw.errors import UsageError
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore, StoreError

pytestmark = pytest.mark.timeout(300)
BASE = "http://127.0.0.1:8040"
TOKEN = "page-token-of-the-test"


@pytest.fixture(scope="module")
def sim():
    with SimRig(n_cameras=2, seed=6) as rig, rig.env():
        cfg = rig.config()
        cams = {c.name: open_camera(c) for c in cfg.cameras}
        names = MarkerNames()
        hub = FramesHub(cams, idle_close_s=1.0)
        markers = MarkerWorker(hub, 2.0, names)
        try:
            yield cfg, cams, hub, markers, names
        finally:
            markers.close()
            hub.close()
            for c in cams.values():
                c.close()


def _served(sim, db, scans):
    cfg, cams, hub, markers, names = sim
    read = lambda: ResultsStore(db, mode="read")  # noqa: E731
    console = Console(
        cfg.rig,
        hub,
        markers,
        RoomFacts(cams, cfg.rig, read, names=names),
        open_store=read,
        token=TOKEN,
        rig_config=cfg,
        scans_dir=scans,
        actions=StoreActions(lambda: ResultsStore(db), read, cfg.rig),
    )
    return console, TestClient(create_app(console), base_url=BASE)


def _until(check, timeout=120.0):
    end = time.monotonic() + timeout
    while not check() and time.monotonic() < end:
        time.sleep(0.05)
    return check()


def test_a_scan_on_a_full_disk_is_recorded_as_not_started_and_leaves_no_folder(sim, small_disk, tmp_path):
    disk = small_disk(256)
    db = tmp_path / "results.sqlite"
    ResultsStore(db).close()
    scans = disk.path / "scans"
    scans.mkdir()
    disk.fill()
    console, client = _served(sim, db, scans)
    with client:
        r = client.post("/scan/start", json={"reference_s": 2, "duration_s": 5}, headers={"X-Console-Token": TOKEN})
        assert r.status_code == 200, r.text
        scan = r.json()["scan"]
        assert _until(lambda: not console.scan_desk.busy())
        state = client.get("/scan/state")
        assert state.status_code == 200 and state.json()["phase"] == "failed"
        assert "no space left on device" in state.json()["error"]
        acts = [a for a in console.actions.recent(20) if a.detail.get("scan") == scan]
        assert [a.what for a in acts] == ["scan not started"]  # never "scan started"
        assert "no space left on device" in acts[0].detail["why"] and acts[0].user == "local"
        assert acts[0].detail["folder"] == "none left (nothing was written)"
        assert list(scans.iterdir()) == [] and disk.files() == {}
    console.aim.close()


def test_a_baseline_whose_store_is_on_a_full_disk_is_recorded_as_not_set(sim, small_disk, tmp_path):
    disk = small_disk(1024)
    db = disk.path / "results.sqlite"
    ResultsStore(db).close()
    disk.fill()
    console, client = _served(sim, db, tmp_path / "scans")
    with client:
        r = client.post("/qa/baseline", json={"confirm": True, "frames": 2}, headers={"X-Console-Token": TOKEN})
        assert r.status_code == 202, r.text
        console.qa_jobs.wait(120)
        job = console.qa_jobs.snapshot()
        assert job["state"] == "failed" and job["error"]
        (act,) = console.actions.pending  # the store cannot take it yet: kept
        assert act.what == "drift baseline not set" and act.detail["why"] == job["error"]
        assert act.detail["cameras"] == ["cam1", "cam2"]
        disk.free_up()
        client.post("/camera/cam1/led", json={"on": False}, headers={"X-Console-Token": TOKEN})
        assert console.actions.pending == []
    with ResultsStore(db, mode="read") as store:
        logged = [(a.what, a.detail.get("why")) for a in store.actions()[0]]
        assert ("drift baseline not set", job["error"]) in logged and "drift baseline set" not in [w for w, _ in logged]
        assert [r for r in store.runs() if r.procedure == "drift-baseline"] == []
    console.aim.close()


def _with_users(db, user: str, password: str, monkeypatch, hub=None) -> Console:
    """A console of room3 whose store ``db`` holds one operator, ``user`` (scrypt made cheap)."""
    monkeypatch.setattr(users, "SCRYPT_N", 2**10)
    with ResultsStore(db) as store:
        add_user(store, user, "operator", password)

    def load():
        with ResultsStore(db, mode="read") as store:
            return store.users(active_only=True)

    auth = Auth(required=True, load_users=load)
    auth.refresh_users()
    read = lambda: ResultsStore(db, mode="read")  # noqa: E731
    return Console(
        "room3",
        hub,
        None,
        None,
        open_store=read,
        auth=auth,
        actions=StoreActions(lambda: ResultsStore(db), read, "room3"),
    )


def test_each_lock_out_and_each_try_while_locked_is_in_the_action_log(tmp_path, monkeypatch):
    db = tmp_path / "results.sqlite"
    console = _with_users(db, "ann", "ann-password-1", monkeypatch)
    with TestClient(create_app(console), base_url=BASE) as client:

        def login(name, password, next_="/"):
            return log_in(client, name, password, next_)

        for sly in ("/\t/evil.example", "/\n/evil.example", "/ /evil.example", "//evil.example", "/\\evil.example"):
            r = login("ann", "ann-password-1", sly)  # a browser drops a tab: //evil.example
            assert r.status_code == 303 and r.headers["location"] == "/", (sly, r.headers["location"])
        assert login("ann", "ann-password-1", "/history?page=2").headers["location"] == "/history?page=2"
        for _ in range(LOCK_AFTER):
            assert login("ann", "wrong-password").status_code == 401
            assert login("mallory-ann-password-1", "x").status_code == 401  # a password typed as a name
        r = login("ann", "ann-password-1")  # the right one, while locked
        assert r.status_code == 429 and "too many wrong passwords" in r.text
        assert login("ann", "ann-password-1").status_code == 429
    with ResultsStore(db, mode="read") as store:
        acts = [(a.user, a.what) for a in reversed(store.actions(limit=100)[0])]
        detail = {a.what: a.detail for a in store.actions(limit=100)[0]}
    assert acts.count(("ann", "logged in")) == 6
    assert acts.count(("ann", "login refused")) == LOCK_AFTER and acts.count(("ann", "locked out")) == 1
    assert acts.index(("ann", "locked out")) == acts.index(("ann", "login refused")) + 2 * LOCK_AFTER - 1
    assert acts.count(("ann", "login refused: locked")) == 2
    assert acts.count(("(not a user)", "locked out")) == 1  # the name never logged: not a user's
    assert not any("mallory" in u for u, _ in acts)
    assert detail["locked out"]["for_s"] == 60 and detail["login refused: locked"]["locked_for_s"] > 0


def test_a_store_that_is_not_ours_or_cannot_be_written_refuses_the_console(tmp_path, small_disk, monkeypatch):
    from vts_hw.console import serve as srv
    from vts_hw.room import Room

    monkeypatch.setattr(Room, "cameras", property(lambda self: pytest.fail("opened the cameras before refusing")))
    rig = SimpleNamespace(rig="room3", cameras=[])
    foreign = tmp_path / "notes.sqlite"
    with sqlite3.connect(foreign) as conn:
        conn.execute("CREATE TABLE notes (id INTEGER PRIMARY KEY, text TEXT)")
        conn.execute("INSERT INTO notes (text) VALUES ('not a vts store')")
    conn.close()
    before = hashlib.sha256(foreign.read_bytes()).hexdigest()
    disk = small_disk(512)
    ours = disk.path / "results.sqlite"
    ResultsStore(ours).close()
    disk.read_only()
    bound = []
    real_bind = srv.bind
    monkeypatch.setattr(srv, "bind", lambda *a: bound.append(real_bind(*a)) or bound[-1])

    def refused(db, exc=StoreError, code=3):
        with pytest.raises(exc) as info:
            srv.serve(
                rig,
                port=0,
                open_store=lambda: ResultsStore(db, mode="read"),
                open_write_store=None if db is None else lambda: ResultsStore(db),
                scans_dir=str(tmp_path / "s"),
            )
        assert info.value.exit_code == code and "\n" not in str(info.value)
        assert bound and bound[-1].fileno() == -1  # the port let go
        return str(info.value)

    said = refused(foreign)
    assert said.startswith("refused to serve the console: its action log cannot be kept in the results store")
    assert "is not a vts-hw results store" in said and str(foreign) in said
    assert hashlib.sha256(foreign.read_bytes()).hexdigest() == before
    said = refused(ours)  # a store of ours on a read-only mount
    assert said.startswith("refused to serve the console: its action log cannot be kept") and str(ours) in said
    assert "needs a results store to keep its action log" in refused(None, UsageError, 2)

    good = tmp_path / "good.sqlite"
    log = durable_actions(
        lambda: ResultsStore(good), lambda: ResultsStore(good, mode="read"), "room3", "http://127.0.0.1:8040/"
    )
    with ResultsStore(good, mode="read") as store:
        (act,), _ = store.actions()
    assert (act.user, act.what, act.detail) == ("local", "console started", {"address": "http://127.0.0.1:8040/"})
    assert log.pending == []
    shutil.rmtree(tmp_path / "s", ignore_errors=True)


def test_a_spray_of_names_keeps_the_lock_outs_and_bounded_memory(monkeypatch):
    import vts_hw.console.sessions as sessions

    monkeypatch.setattr(sessions, "FAILS_KEPT", 20)
    monkeypatch.setattr(sessions, "dummy_check", lambda password: False)  # (no user: the cost is not tested here)
    auth = Auth(required=True, load_users=lambda: [])
    for _ in range(LOCK_AFTER):
        auth.login("ann", "guess")
    for i in range(200):
        auth.login(f"sprayed-{i}", "guess")
    assert len(auth._fails) <= 21 and auth.locked_for("ann") > 0


def test_every_refused_action_is_in_the_log_and_a_flood_of_them_is_counted_not_copied(tmp_path, monkeypatch):
    """A POST refused by the door or the guard (another site's, no session, without the page's
    token, a role too low) is an action refused: in the log with why and what was asked; a page
    sending hundreds is one line per kind every refusals.EVERY_S, with how many were held back."""
    now = [1000.0]
    db = tmp_path / "results.sqlite"
    console = _with_users(db, "olga", "olga-password-1", monkeypatch, hub=SimpleNamespace(names=["cam1"]))
    console.refusals = refusals.Refusals(console.actions, clock=lambda: now[0])
    with TestClient(create_app(console), base_url=BASE) as client:
        for _ in range(200):  # no session: the door refuses
            assert client.post("/camera/cam1/led", json={"on": False}).status_code == 401
        r = log_in(client, "olga", "olga-password-1")
        assert r.status_code == 303
        assert client.post("/camera/cam1/led", json={"on": False}).status_code == 403  # no token
        assert (
            client.post("/camera/cam1/led", json={"on": False}, headers={"Origin": "http://evil.example"}).status_code
            == 403
        )  # another site
        now[0] += refusals.EVERY_S + 1
        client.cookies.clear()
        assert client.post("/scan/stop", json={}).status_code == 401  # after EVERY_S: a line, with the count
    with ResultsStore(db, mode="read") as store:
        refused = [a for a in reversed(store.actions(limit=100)[0]) if a.what == refusals.WHAT]
    kinds = [(a.user, a.detail["kind"]) for a in refused]
    assert kinds[0] == ("(no session)", refusals.NO_SESSION) and refused[0].detail["asked"] == "POST /camera/cam1/led"
    assert ("olga", refusals.NOT_THE_PAGE) in kinds and ("(no session)", refusals.ANOTHER_SITE) in kinds
    last = refused[-1]
    assert last.detail["kind"] == refusals.NO_SESSION and last.detail["asked"] == "POST /scan/stop"
    assert last.detail["held back since the last"] == 199  # the flood: counted, not copied
    assert len(refused) <= 5 and "evil.example" in next(
        a.detail["why"] for a in refused if a.detail["kind"] == refusals.ANOTHER_SITE
    )
