"""Who may do what on the console (issue 23 §3): users, roles, sessions, HTTPS, the action log.

Unit tests of the hashing (salted scrypt with its parameters, constant-time check), the
sessions (idle and absolute limits on a clock of the test's own, logout, a disabled user, a name
locked after wrong passwords) and the action details (no secret kept; a store that fails loses
none). The guard in process (Starlette's TestClient, with a small physicist-only route of the
test's own): without users the person here is `local`; with users a page needs a session, an
operator is refused a physicist's action with a sentence, the page token is the session's, a
POST from another site is refused, an event stream ends with its session. `vts console user
add/list/remove` with the password from an environment variable (and from the prompt). Serving
off this machine is refused before anything is bound without users or HTTPS; a bad certificate
or key is one sentence naming the file. `vts console` as users run it, over HTTPS and in
Chromium: tests/console/test_console_auth_served.py.
"""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from click.testing import CliRunner
from starlette.responses import JSONResponse, StreamingResponse
from starlette.routing import Route
from starlette.testclient import TestClient

from console_live import log_in, run_vts
from vts_hw.console import guard
from vts_hw.console.actions import MemoryActions, StoreActions, clean
from vts_hw.console.app import Console, create_app
from vts_hw.console.sessions import LOCK_AFTER, Auth
from vts_hw.console.users import add_user, hash_password, verify_password
from vts_hw.errors import UsageError
from vts_hw.sim_devices.tls import self_signed
from vts_hw.store import ResultsStore, StoreError

pytestmark = pytest.mark.timeout(180)
ANN_PW, PHIL_PW = "ann-runs-the-scans-7", "phil-sets-baselines-9"


# -- hashing, sessions, details ----------------------------------------------------------------------


def test_a_password_is_kept_as_a_salted_scrypt_hash_with_its_parameters():
    a, b = hash_password(ANN_PW), hash_password(ANN_PW)
    assert a != b  # a salt of its own each time
    kind, n, r, p, salt, digest = a.split("$")
    assert (kind, n, r, p) == ("scrypt", "32768", "8", "1") and len(salt) >= 22 and len(digest) >= 43
    assert ANN_PW not in a
    assert verify_password(a, ANN_PW) and verify_password(b, ANN_PW)
    assert not verify_password(a, ANN_PW + "x") and not verify_password(a, "")
    for broken in ("", "plain", "md5$1$2$3$4$5", a.replace("scrypt", "bcrypt"), a[:-4], "scrypt$0$8$1$AA==$AA=="):
        assert verify_password(broken, ANN_PW) is False
    # the parameters are read from the hash: one made with others (a later, stronger default) still checks
    import vts_hw.console.users as users

    old = (users.SCRYPT_N, users.SCRYPT_R)
    users.SCRYPT_N, users.SCRYPT_R = 2**12, 4
    try:
        light = hash_password("another-password")
    finally:
        users.SCRYPT_N, users.SCRYPT_R = old
    assert light.split("$")[1:3] == ["4096", "4"] and verify_password(light, "another-password")


@pytest.fixture()
def cheap_hashes(monkeypatch):
    """Hashes of a lower cost where the cost is not what is tested (the parameters are in each hash)."""
    import vts_hw.console.users as users

    monkeypatch.setattr(users, "SCRYPT_N", 2**10)


class Clock:
    def __init__(self):
        self.t = 1_000_000.0

    def __call__(self):
        return self.t


def _user(name, role, password):
    return SimpleNamespace(name=name, role=role, password=hash_password(password))


def test_sessions_end_when_idle_at_their_limit_on_logout_and_when_the_user_goes(cheap_hashes):
    clock = Clock()
    people = [_user("ann", "operator", ANN_PW), _user("phil", "physicist", PHIL_PW)]
    auth = Auth(required=True, load_users=lambda: list(people), idle_s=60, max_s=600, clock=clock)
    assert auth.refresh_users() == 2
    assert auth.login("ann", "wrong-password") is None and auth.login("nobody", ANN_PW) is None
    s = auth.login("ann", ANN_PW)
    assert s.user == "ann" and s.role == "operator" and auth.session(s.key) is s
    other = auth.login("ann", ANN_PW)
    assert other.key != s.key and other.token != s.token  # a token per session
    clock.t += 59
    assert auth.session(s.key) is s
    auth.touch(s)  # a request: idle counts again from now
    clock.t += 59
    assert auth.session(s.key) is s and auth.session(other.key) is None  # other was idle 118 s
    auth.touch(s)
    for _ in range(12):  # kept in use, still ends at its limit
        clock.t += 59
        if auth.session(s.key) is None:
            break
        auth.touch(s)
    assert auth.session(s.key) is None and clock.t - s.created > 600 >= clock.t - 59 - s.created
    p = auth.login("phil", PHIL_PW)
    assert auth.logout(p.key) is p and auth.session(p.key) is None
    a, p = auth.login("ann", ANN_PW), auth.login("phil", PHIL_PW)
    people[:] = [_user("ann", "physicist", ANN_PW)]  # ann made physicist, phil removed
    auth.refresh_users()
    assert auth.session(a.key) is None and auth.session(p.key) is None
    assert auth.login("phil", PHIL_PW) is None and auth.login("ann", ANN_PW).role == "physicist"
    assert auth.session("") is None and auth.session("made-up") is None


def test_wrong_passwords_lock_the_name_for_a_while(cheap_hashes):
    clock = Clock()
    auth = Auth(required=True, load_users=lambda: [_user("ann", "operator", ANN_PW)], clock=clock)
    auth.refresh_users()
    for _ in range(LOCK_AFTER):
        assert auth.login("ann", "guess") is None
    assert auth.locked_for("ann") == 60 and auth.login("ann", ANN_PW) is None  # even the right one
    assert auth.locked_for("phil") == 0
    clock.t += 61
    assert auth.login("ann", ANN_PW) is not None


def test_action_details_keep_no_secret_and_a_store_that_fails_loses_none(tmp_path):
    detail = {
        "camera": "cam1",
        "url": "http://root:s3cret@10.0.0.5/axis-cgi/mjpg/video.cgi",
        "password": "s3cret",
        "qatrack_token": "Tk9f8e",
        "nested": [{"Authorization": "Token Tk9f8e"}],
        "n": 3,
    }
    kept = clean(detail)
    assert "s3cret" not in repr(kept) and "Tk9f8e" not in repr(kept)
    assert kept["url"] == "http://***@10.0.0.5/axis-cgi/mjpg/video.cgi" and kept["camera"] == "cam1" and kept["n"] == 3
    mem = MemoryActions("room3")
    mem.record("ann", "LED on", detail, role="operator")
    assert "s3cret" not in repr(mem.recent())

    db = tmp_path / "r.sqlite"
    ResultsStore(db).close()
    broken = {"now": True}

    def open_write():
        if broken["now"]:
            raise StoreError(f"{db}: cannot write to the results store (disk full)")
        return ResultsStore(db)

    log = StoreActions(open_write, lambda: ResultsStore(db, mode="read"), "room3")
    log.record("ann", "scan started", {"camera": "cam1"}, role="operator")
    assert [a.what for a in log.recent()] == ["scan started"] and len(log.pending) == 1  # kept, listed
    broken["now"] = False
    log.record("ann", "scan stopped", detail)
    assert log.pending == []
    with ResultsStore(db, mode="read") as store:
        acts, n = store.actions()
    assert n == 2 and [a.what for a in acts] == ["scan stopped", "scan started"]
    assert acts[1].role == "operator" and acts[0].rig == "room3" and "s3cret" not in repr(acts)
    assert b"s3cret" not in db.read_bytes() + (Path(f"{db}-wal").read_bytes() if Path(f"{db}-wal").exists() else b"")


# -- the guard, in process -------------------------------------------------------------------------------


def _app(console):
    """The console's application with a physicist-only action and an endless event stream of the test's own."""
    app = create_app(console)

    async def sign_off(request):
        refused = guard.refuse(console, request, guard.PHYSICIST)
        if refused is not None:
            return refused
        user, role = guard.user_of(console, request)
        return JSONResponse({"signed": user, "role": role})

    async def stream(request):
        async def chunks():
            while True:
                yield b"data: tick\n\n"
                import asyncio

                await asyncio.sleep(0.01)

        return StreamingResponse(chunks(), media_type="text/event-stream")

    app.router.routes[:0] = [Route("/test/sign-off", sign_off, methods=["POST"]), Route("/test/stream", stream)]
    return app


@pytest.fixture(scope="module")
def people_store(tmp_path_factory):
    import vts_hw.console.users as users

    db = tmp_path_factory.mktemp("people") / "results.sqlite"
    with pytest.MonkeyPatch.context() as mp, ResultsStore(db) as store:
        mp.setattr(users, "SCRYPT_N", 2**10)  # (cheaper to check; the cost is tested above)
        add_user(store, "ann", "operator", ANN_PW)
        add_user(store, "phil", "physicist", PHIL_PW)
    return db


@pytest.fixture()
def with_users(people_store):
    clock = Clock()
    clock.t = time.time()

    def load():
        with ResultsStore(people_store, mode="read") as store:
            return store.users(active_only=True)

    auth = Auth(required=True, load_users=load, idle_s=60, max_s=600, clock=clock)
    auth.refresh_users()
    console = Console(
        "room3",
        None,
        None,
        None,
        open_store=lambda: ResultsStore(people_store, mode="read"),
        actions=MemoryActions("room3"),
        auth=auth,
    )
    with TestClient(_app(console), base_url="http://127.0.0.1:8040") as client:
        yield client, console, clock


def _login(client, name, password, next_="/history"):
    return log_in(client, name, password, next_)


def test_without_users_on_this_machine_the_person_is_local_and_may_do_everything():
    console = Console("room3", None, None, None, token="page-token")
    with TestClient(_app(console), base_url="http://127.0.0.1:8040") as client:
        r = client.post("/test/sign-off", headers={"X-Console-Token": "page-token"})
        assert r.status_code == 200 and r.json() == {"signed": "local", "role": "physicist"}
        assert client.post("/test/sign-off").status_code == 403
        assert client.get("/session").json()["required"] is False
        assert client.get("/login").status_code in (404, 405)  # no login page without users


def test_with_users_a_page_needs_a_session_and_an_action_its_role(with_users):
    client, console, _ = with_users
    r = client.get("/history", headers={"Accept": "text/html"}, follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/login?next=%2Fhistory"
    assert client.get("/api/room").status_code == 401 and "log in first" in client.get("/api/room").json()["error"]
    r = client.post("/test/sign-off", headers={"X-Console-Token": console.console_token})
    assert r.status_code == 401  # the console's own token is no session's
    login = client.get("/login?next=/history")
    assert login.status_code == 200 and 'name="password"' in login.text and 'value="/history"' in login.text

    r = _login(client, "ann", "not-her-password")
    assert r.status_code == 401 and "wrong user name or password" in r.text
    assert "vts_session" not in r.headers.get("set-cookie", "")  # (only a new form's token)
    r = _login(client, "nobody", ANN_PW)
    assert r.status_code == 401 and "wrong user name or password" in r.text
    r = client.post("/login", data={"name": "ann", "password": ANN_PW}, headers={"Origin": "http://evil.example"})
    assert r.status_code == 403 and "another site" in r.json()["error"]
    r = _login(client, "ann", ANN_PW, next_="//evil.example/x")
    assert r.status_code == 303 and r.headers["location"] == "/"  # never to another site
    cookie = r.headers["set-cookie"]
    assert cookie.startswith("vts_session=") and "HttpOnly" in cookie and "SameSite=strict" in cookie
    assert "Secure" not in cookie  # plain HTTP on this machine
    ann = next(iter(console.auth._sessions.values()))
    page = client.get("/history")
    assert page.status_code == 200 and ann.key not in page.text and ANN_PW not in page.text
    assert client.get("/session").json()["user"] == "ann"

    r = client.post("/test/sign-off", headers={"X-Console-Token": ann.token})
    assert r.status_code == 403 and r.json()["error"] == "refused: ann is an operator; this needs a physicist"
    r = client.post("/test/sign-off", headers={"X-Console-Token": console.console_token})
    assert r.status_code == 403 and "did not come from the console's page" in r.json()["error"]
    r = client.post("/test/sign-off", headers={"X-Console-Token": ann.token, "Origin": "http://evil.example"})
    assert r.status_code == 403 and "another site" in r.json()["error"]

    with TestClient(client.app, base_url="http://127.0.0.1:8040") as phil_client:
        assert _login(phil_client, "phil", PHIL_PW).status_code == 303
        phil = next(s for s in console.auth._sessions.values() if s.user == "phil")
        r = phil_client.post("/test/sign-off", headers={"X-Console-Token": ann.token})  # another session's
        assert r.status_code == 403
        r = phil_client.post("/test/sign-off", headers={"X-Console-Token": phil.token})
        assert r.status_code == 200 and r.json() == {"signed": "phil", "role": "physicist"}
    acts = [(a.user, a.what, a.role) for a in console.actions.recent()]
    assert ("ann", "logged in", "operator") in acts and ("phil", "logged in", "physicist") in acts
    assert ("ann", "login refused", "") in acts and ("(not a user)", "login refused", "") in acts

    # logging out is an action of the page too: without its token (a stray form of this site) it is refused
    assert client.post("/logout", follow_redirects=False).status_code == 403
    assert client.get("/session").json()["user"] == "ann"
    assert client.post("/logout", follow_redirects=False, headers={"X-Console-Token": ann.token}).status_code == 303
    assert client.get("/session").status_code == 401 and ("ann", "logged out", "operator") in [
        (a.user, a.what, a.role) for a in console.actions.recent()
    ]


def test_an_event_stream_ends_when_its_session_does(with_users):
    client, console, clock = with_users
    assert _login(client, "ann", ANN_PW).status_code == 303
    got = 0
    with client.stream("GET", "/test/stream") as r:
        assert r.status_code == 200
        for chunk in r.iter_bytes():
            got += chunk.count(b"tick")
            if got >= 3:
                clock.t += 601  # past the session's limit while it streams
            assert got < 1000, "the stream went on after its session ended"
    assert got >= 3 and client.get("/session").status_code == 401


# -- vts console user ... ------------------------------------------------------------------------------------


def _vts_here(args, env, capsys, monkeypatch):
    """`vts ARGS` in this process (as main() runs it: errors one sentence and an exit code)."""
    from vts_hw.cli import main

    for k, v in env.items():
        monkeypatch.setenv(k, v)
    try:
        main([str(a) for a in args])
        code = 0
    except SystemExit as exc:
        code = exc.code
    got = capsys.readouterr()
    return SimpleNamespace(returncode=code, stdout=got.out, stderr=got.err)


def test_user_add_list_and_remove_with_the_password_never_on_the_command_line(tmp_path, capsys, monkeypatch):
    db = tmp_path / "results.sqlite"
    env = {"VTS_STORE": f"sqlite:///{db}", "ANN_PW": ANN_PW, "SHORT_PW": "short"}
    monkeypatch.delenv("VTS_CONFIG", raising=False)
    monkeypatch.delenv("UNSET_PW", raising=False)
    monkeypatch.chdir(tmp_path)
    p = run_vts(
        ["console", "user", "add", "ann", "--role", "operator", "--password-env", "ANN_PW"], {**os.environ, **env}
    )  # as users run it, once
    assert p.returncode == 0 and p.stdout.startswith("user ann (operator) added in sqlite:///"), p.stderr
    # from the prompt, asked twice without echo, at a terminal (CliRunner's input stands for one)
    from vts_hw.cli import _register, cli, common

    _register()
    with monkeypatch.context() as m:
        m.setattr(common, "_terminal", lambda: True)
        r = CliRunner().invoke(
            cli,
            ["--store", f"sqlite:///{db}", "console", "user", "add", "phil", "--role", "physicist"],
            input=f"{PHIL_PW}\n{PHIL_PW}\n",
        )
    assert r.exit_code == 0 and "user phil (physicist) added" in r.output and PHIL_PW not in r.output, r.output
    # no terminal (a script, a pipe, /dev/null): one sentence naming --password-env, never "interrupted"
    p = _vts_here(["console", "user", "add", "bob", "--role", "operator"], env, capsys, monkeypatch)
    assert p.returncode == 2 and "--password-env" in p.stderr and "interrupted" not in p.stderr, p.stderr
    for args, said in (
        (["add", "ann", "--role", "physicist", "--password-env", "ANN_PW"], "already exists"),
        (["add", "bob", "--role", "operator", "--password-env", "SHORT_PW"], "too short"),
        (["add", "bob", "--role", "operator", "--password-env", "UNSET_PW"], "UNSET_PW"),
        (["add", "bob", "--role", "admin", "--password-env", "ANN_PW"], "admin"),
        (["add", "local", "--role", "operator", "--password-env", "ANN_PW"], "reserved"),
        (["add", "bob", "--role", "operator", "--password", ANN_PW], "--password"),
        (["remove", "nobody"], "no user 'nobody'"),
    ):
        p = _vts_here(["console", "user", *args], env, capsys, monkeypatch)
        assert p.returncode == 2 and said in p.stderr and "Traceback" not in p.stderr, (args, p.stderr)
    p = _vts_here(["console", "user", "list"], env, capsys, monkeypatch)
    assert p.returncode == 0 and [ln.split()[:2] for ln in p.stdout.splitlines()] == [
        ["ann", "operator"],
        ["phil", "physicist"],
    ]
    assert "may log in" in p.stdout and "scrypt" not in p.stdout
    p = _vts_here(["console", "user", "remove", "ann"], env, capsys, monkeypatch)
    assert p.returncode == 0 and "user ann disabled" in p.stdout
    p = _vts_here(["console", "user", "list", "--json"], env, capsys, monkeypatch)
    import json

    users = {u["name"]: u for u in json.loads(p.stdout)["users"]}
    assert users["ann"]["active"] is False and users["phil"]["active"] is True
    assert "password" not in json.dumps(users)
    store_bytes = b"".join(f.read_bytes() for f in tmp_path.iterdir() if f.is_file())
    assert ANN_PW.encode() not in store_bytes and PHIL_PW.encode() not in store_bytes and b"scrypt$" in store_bytes
    p = _vts_here(
        ["console", "user", "list"], {**env, "VTS_STORE": f"sqlite:///{tmp_path / 'none.sqlite'}"}, capsys, monkeypatch
    )
    assert p.returncode == 3 and "none.sqlite" in p.stderr and len(p.stderr.strip().splitlines()) == 1


# -- serving off this machine, HTTPS ----------------------------------------------------------------------------


def test_off_this_machine_without_users_or_https_it_is_refused_before_anything_is_bound(tmp_path, monkeypatch, capsys):
    from vts_hw.console import serve as srv
    from vts_hw.room import Room

    monkeypatch.setattr(srv, "bind", lambda *a: pytest.fail("bound a socket before refusing"))
    monkeypatch.setattr(Room, "cameras", property(lambda self: pytest.fail("opened the cameras before refusing")))
    cert, key = self_signed(tmp_path / "tls")
    empty = tmp_path / "empty.sqlite"
    ResultsStore(empty).close()
    gone = tmp_path / "gone.sqlite"
    with ResultsStore(tmp_path / "left.sqlite") as store:
        add_user(store, "ann", "operator", ANN_PW)
        store.disable_user("ann")
    rig = SimpleNamespace(rig="room3", cameras=[])

    def refused(store, **kw):
        with pytest.raises(UsageError) as info:
            srv.serve(rig, port=0, open_store=lambda: ResultsStore(store, mode="read"), **kw)
        assert info.value.exit_code == 2 and "\n" not in str(info.value)
        return str(info.value)

    assert "needs users and login over HTTPS" in refused(empty, host="0.0.0.0")
    said = refused(empty, host="0.0.0.0", certfile=str(cert), keyfile=str(key), server_names=("vts.example",))
    assert "has no console user who may log in" in said and "vts console user add" in said
    proxied = {"behind_proxy": True, "server_names": ("vts.example",)}
    assert "no console user" in refused(empty, host="192.168.1.20", proxy="192.168.1.1", **proxied)
    assert "no console user" in refused(tmp_path / "left.sqlite", host="127.0.0.1", **proxied)  # disabled
    assert "could not be read" in refused(gone, host="127.0.0.1", **proxied)
    assert not gone.exists()  # and nothing was created
    assert refused(empty, host="127.0.0.1", login=True).startswith("refused to require a login")
    assert "go together" in refused(empty, host="0.0.0.0", certfile=str(cert))
    # the command: one sentence, exit 2 (a camera nobody answers on: it is never opened)
    rig_yaml = tmp_path / "rig.yaml"
    rig_yaml.write_text(
        "rig: room3\ncameras:\n  - {name: cam1, host: 127.0.0.1, port: 9, user: root, password_env: CAM1_PW}\n"
    )
    env = {"VTS_STORE": f"sqlite:///{empty}", "VTS_CONFIG": str(rig_yaml)}
    for args, said in (
        (["--host", "0.0.0.0"], "needs users and login over HTTPS"),
        (["--behind-proxy", "--server-name", "vts.example"], "has no console user who may log in"),
        (["--login"], "refused to require a login"),
    ):
        p = _vts_here(["console", *args, "--port", "0"], env, capsys, monkeypatch)
        assert p.returncode == 2 and said in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr


def test_a_bad_certificate_or_key_is_one_sentence_naming_the_file(tmp_path, capsys, monkeypatch):
    from vts_hw.console.serve_checks import check_tls

    cert, key = self_signed(tmp_path / "a")
    cert2, key2 = self_signed(tmp_path / "b")
    text = tmp_path / "notes.txt"
    text.write_text("not a certificate\n")
    locked = tmp_path / "locked-key.pem"
    subprocess.run(
        ["openssl", "pkey", "-in", str(key), "-aes256", "-passout", "pass:secret", "-out", str(locked)],
        check=True,
        capture_output=True,
    )
    assert check_tls(str(cert), str(key)) is True and check_tls(None, None) is False
    for c, k, said in (
        (tmp_path / "none.pem", key, f"{tmp_path / 'none.pem'}: no such file (--certfile)"),
        (cert, tmp_path / "none.pem", f"{tmp_path / 'none.pem'}: no such file (--keyfile)"),
        (text, key, f"{text}: not a PEM certificate (--certfile)"),
        (key, key, f"{key}: not a PEM certificate (--certfile)"),
        (cert, text, f"{text}: not a PEM private key (--keyfile)"),
        (cert, key2, f"{key2}: not the private key of the certificate {cert} (--keyfile)"),
        (cert, locked, f"{locked}: the private key is encrypted"),
    ):
        with pytest.raises(UsageError) as info:
            check_tls(str(c), str(k))
        assert str(info.value).startswith(said), str(info.value)
    for c, k in ((str(cert), None), (None, str(key))):  # one without the other: said by check_tls itself
        with pytest.raises(UsageError, match="^--certfile and --keyfile go together"):
            check_tls(c, k)
    p = _vts_here(["console", "--certfile", str(cert), "--keyfile", str(key2), "--port", "0"], {}, capsys, monkeypatch)
    assert (
        p.returncode == 2
        and p.stderr.startswith(f"vts: {key2}: not the private key")
        and len(p.stderr.strip().splitlines()) == 1
    ), p.stderr


def test_a_login_is_taken_only_from_the_form_the_console_showed(with_users):
    """Login CSRF: another page may post the login form (an Origin it cannot forge is checked
    first); the form must also bring back the token of a form this console showed, kept in a
    cookie only /login is sent. A token of any bytes is a refusal, never a 500."""
    client, console, _ = with_users
    for csrf_token in (None, "", "not-the-one", "\u00e9t\u00e9"):
        data = {"name": "ann", "password": ANN_PW, "next": "/"}
        if csrf_token is not None:
            data["csrf_token"] = csrf_token
        client.get("/login")  # a form shown (its cookie set)
        r = client.post("/login", data=data, follow_redirects=False)
        assert r.status_code == 400 and "not one the console gave" in r.text, (csrf_token, r.status_code)
        assert "vts_session" not in r.headers.get("set-cookie", "") and not console.auth._sessions
    assert log_in(client, "ann", ANN_PW).status_code == 303  # the form as shown: in
    ann = next(iter(console.auth._sessions.values()))
    for token in (b"\xe9\xe9", b"\xff" * 40, ann.token.encode() + b"\x80"):  # any bytes in the page token
        r = client.post("/test/sign-off", headers={"X-Console-Token": token})
        assert r.status_code == 403 and "did not come from the console's page" in r.json()["error"]
        r = client.post("/logout", headers={"X-Console-Token": token}, follow_redirects=False)
        assert r.status_code == 403
    assert client.get("/session").json()["user"] == "ann"
