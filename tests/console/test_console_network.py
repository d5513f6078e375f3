"""The console's network defences (issue 32 §1, docs/security.md): what it serves, to whom, under
which names, and with which headers.

* Files: with files named like every secret and store file (sim.env, *.env, the store and its
  -wal/-shm, rig.yaml, keys, .pgpass; links to them) in the scans folder and its scan folders,
  EVERY route of the app (enumerated from ``app.routes``), every method, path parameters filled
  with those names and with traversal forms (``..``, ``%2e%2e``, ``%2f``, absolute paths), sent
  byte for byte over a real socket to the console served by uvicorn, without users and with
  (not logged in, operator, physicist): no answer holds a secret's bytes, a password hash or a
  camera password, and every answer carries the security headers. A scan's own outputs are
  served, by number only. ``--scans-dir`` a folder of scans only (refused, exit 2, otherwise).
* Host and DNS rebinding: only the names the console serves under are answered (400 with a
  sentence otherwise, static files and the login page included); a POST's Origin (or Referer)
  is checked against the same names and the port the request came in on. In Chromium, a name
  of another site resolved to 127.0.0.1 gets the 400, and its script's POST (with the real
  token) switches nothing.
* A login never in clear off this machine: plain HTTP only on loopback or to the proxy named
  with --proxy (every other peer refused; X-Forwarded-* from it only), refused in one sentence
  before anything binds otherwise. HSTS over HTTPS only.
* The pages satisfy their Content-Security-Policy in Chromium (no violation reported), the
  reports run sandboxed.
"""

from __future__ import annotations

import http.client
import itertools
import os
import re
import secrets
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from starlette.routing import Mount, Route
from starlette.testclient import TestClient

import vts_hw.console.users as users
from console_live import FORM_TOKEN, LiveConsole, chromium, until
from inprocess_cli import vts
from vts_hw.console import serve as srv
from vts_hw.console.app import Console, create_app
from vts_hw.console.headers import DOCUMENT_CSP, PAGE_CSP
from vts_hw.console.hosts import Reach, parse_host
from vts_hw.console.scan_analysis import MotionJob
from vts_hw.console.scan_run import ScanRun
from vts_hw.console.scans_folder import default_scans_dir
from vts_hw.console.sessions import Auth
from vts_hw.console.users import add_user
from vts_hw.drivers.registry import open_camera
from vts_hw.errors import UsageError
from vts_hw.room import Room
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.tls import self_signed
from vts_hw.store import ResultsStore

pytestmark = pytest.mark.timeout(300)
ANN_PW, PHIL_PW = "ann-runs-the-scans-7", "phil-sets-baselines-9"
SECRET_NAMES = (
    "sim.env",
    "cameras.env",
    ".env",
    "results.sqlite",
    "results.sqlite-wal",
    "results.sqlite-shm",
    "results.sqlite-journal",
    "rig.yaml",
    "key.pem",
    "sim-camera-key.pem",
    ".pgpass",
    "id_ed25519",
    "unsaved.json",
)
SCAN = "scan-20250101T000000Z"
REPORT_BYTES = b"<!doctype html><title>motion report</title><p>the scan's own report</p>"


# -- the names and origins, in process ---------------------------------------------------------------------


def test_a_host_header_is_parsed_strictly_and_origins_are_the_consoles_own():
    assert parse_host("LocalHost:8040") == ("localhost", 8040)
    assert parse_host("[::1]:8040") == ("::1", 8040) and parse_host("127.0.0.1") == ("127.0.0.1", None)
    for bad in (
        "",
        ":8040",
        "[::1",
        "[127.0.0.1]:80",
        "a b",
        "localhost.",
        "host:0",
        "host:99999",
        "host:80x",
        "evil.example:8040:1",
        "-bad.example",
        "x" * 300,
    ):
        assert parse_host(bad) is None, bad
    local = Reach.local()
    assert local.answers("127.0.0.1:8040") == "" and local.answers("[::1]:1") == ""
    for host in ("evil.example", "evil.example:8040", "127.0.0.1.nip.io:8040", "127.1", "2130706433", "localhost."):
        assert "refused" in local.answers(host), host
    assert "without a Host" in local.answers(None)
    assert local.origin_ok("http://127.0.0.1:8040", 8040) and local.origin_ok("http://localhost:8040", 8040)
    for origin in (
        "http://127.0.0.1:8041",
        "https://127.0.0.1:8040",
        "http://localhost:3000",
        "null",
        "http://evil.example:8040",
        "http://127.0.0.1:8040/x",
        "http://u@127.0.0.1:8040",
        "file://",
    ):
        assert not local.origin_ok(origin, 8040), origin
    proxied = Reach.build("127.0.0.1", behind_proxy=True, server_names=("vts.example", "other.example:8443"))
    assert proxied.origin_ok("https://vts.example", 8040) and proxied.origin_ok("https://other.example:8443", 8040)
    assert not proxied.origin_ok("http://vts.example", 8040) and not proxied.origin_ok("https://vts.example:8443", 1)
    assert proxied.answers("vts.example") == "" and "refused" in proxied.answers("vts.example.evil.example")


class _Hub:
    names = ()


def _app(reach):
    return create_app(Console("room3", _Hub(), None, None, token="page-token", reach=reach))


def _post_led(client, **headers):
    """A POST through the guard (the LED of a camera the console has not: 404 once past it)."""
    return client.post("/camera/cam9/led", json={"on": False}, headers={"X-Console-Token": "page-token", **headers})


def test_only_the_consoles_names_are_answered_and_a_post_only_from_its_own_origin():
    with TestClient(_app(Reach.local()), base_url="http://127.0.0.1:8040", raise_server_exceptions=False) as c:
        for path in ("/", "/static/console.css", "/session", "/events", "/history", "/login", "/nothing"):
            r = c.get(path, headers={"Host": "evil.example:8040"})
            assert r.status_code == 400 and "does not answer to the name 'evil.example'" in r.text, path
            assert r.headers["content-security-policy"] == PAGE_CSP and r.headers["x-frame-options"] == "DENY"
        r = c.post(
            "/camera/cam9/led",
            json={"on": False},
            headers={
                "Host": "evil.example:8040",
                "Origin": "http://evil.example:8040",
                "X-Console-Token": "page-token",
            },
        )
        assert r.status_code == 400  # the rebinding attack's POST
        assert c.get("/session", headers={"Host": "LOCALHOST:8040"}).status_code == 200
        assert c.get("/session", headers={"Host": "[::1]:8040"}).status_code == 200
        assert c.get("/session", headers={"Host": "a b"}).status_code == 400
        r = c.get("/static/console.css")
        assert r.status_code == 200 and "no-store" not in r.headers.get("cache-control", "")
        assert r.headers["content-security-policy"] == PAGE_CSP and r.headers["x-frame-options"] == "DENY"
        r = c.get("/session")
        assert r.headers["cache-control"] == "no-store" and r.headers["x-content-type-options"] == "nosniff"
        assert r.headers["referrer-policy"] == "same-origin" and "strict-transport-security" not in r.headers
        # the origin: the console's own names on the port the request came in on
        assert _post_led(c, Origin="http://127.0.0.1:8040").status_code == 404  # past the guard
        assert _post_led(c, Origin="http://localhost:8040").status_code == 404
        assert _post_led(c).status_code == 404  # not a browser: the token
        for origin in (
            "http://evil.example",
            "http://localhost:3000",
            "null",
            "https://127.0.0.1:8040",
            "http://127.0.0.1:8041",
        ):
            r = _post_led(c, Origin=origin)
            assert r.status_code == 403 and "another site" in r.json()["error"], origin
        assert _post_led(c, Referer="http://evil.example/page").status_code == 403
        assert _post_led(c, Referer="http://127.0.0.1:8040/").status_code == 404
        assert _post_led(c, **{"Sec-Fetch-Site": "cross-site"}).status_code == 403
        assert _post_led(c, **{"Sec-Fetch-Site": "same-site"}).status_code == 403


def test_hsts_over_https_only_and_the_proxy_believed_from_its_address_only():
    with TestClient(_app(Reach(tls=True)), base_url="https://127.0.0.1:8443") as c:
        assert c.get("/session").headers["strict-transport-security"].startswith("max-age=")
        assert (
            c.post(
                "/camera/cam9/led",
                json={"on": True},
                headers={"X-Console-Token": "page-token", "Origin": "https://127.0.0.1:8443"},
            ).status_code
            == 404
        )
    reach = Reach.build("0.0.0.0", proxy="10.0.0.2", server_names=("vts.example",))
    app = _app(reach)
    with TestClient(app, base_url="http://vts.example", client=("10.0.0.9", 5000)) as c:  # another computer
        r = c.get("/login")
        assert r.status_code == 403 and "through its HTTPS proxy only (10.0.0.2)" in r.text
        assert r.headers["x-frame-options"] == "DENY"
    with TestClient(app, base_url="http://vts.example", client=("10.0.0.2", 5000)) as c:  # the proxy
        r = c.get("/session", headers={"X-Forwarded-Proto": "https", "X-Forwarded-For": "10.0.0.77"})
        assert r.status_code == 200 and r.headers["strict-transport-security"].startswith("max-age=")
        assert (
            c.post(
                "/camera/cam9/led",
                json={"on": True},
                headers={
                    "X-Console-Token": "page-token",
                    "Origin": "https://vts.example",
                    "X-Forwarded-Proto": "https",
                },
            ).status_code
            == 404
        )
        assert (
            c.post(
                "/camera/cam9/led",
                json={"on": True},
                headers={"X-Console-Token": "page-token", "Origin": "http://vts.example"},
            ).status_code
            == 403
        )
        assert c.get("/session", headers={"Host": "evil.example"}).status_code == 400
    with TestClient(app, base_url="http://127.0.0.1:8040", client=("127.0.0.1", 5000)) as c:  # this machine
        r = c.get("/session", headers={"X-Forwarded-Proto": "https"})  # not the proxy: not believed
        assert r.status_code == 200 and "strict-transport-security" not in r.headers


# -- refused before anything binds --------------------------------------------------------------------------


def test_plain_http_off_this_machine_and_a_scans_folder_of_anything_else_are_refused_before_binding(
    tmp_path, monkeypatch
):
    monkeypatch.setattr(srv, "bind", lambda *a: pytest.fail("bound a socket before refusing"))
    monkeypatch.setattr(Room, "cameras", property(lambda self: pytest.fail("opened the cameras before refusing")))
    rig = SimpleNamespace(rig="room3", cameras=[])

    def refused(**kw):
        with pytest.raises(UsageError) as info:
            srv.serve(rig, port=0, **kw)
        assert info.value.exit_code == 2 and "\n" not in str(info.value)
        return str(info.value)

    assert "in plain HTTP" in refused(host="0.0.0.0", behind_proxy=True, server_names=("vts.example",))
    assert "in plain HTTP" in refused(host="192.168.1.20", behind_proxy=True, server_names=("vts.example",))
    assert "--server-name" in refused(host="127.0.0.1", behind_proxy=True)
    assert "not an IP address" in refused(host="0.0.0.0", proxy="proxy.example", server_names=("vts.example",))
    assert "not the address of one machine" in refused(host="0.0.0.0", proxy="0.0.0.0", server_names=("v.example",))
    assert "not a host name" in refused(host="127.0.0.1", behind_proxy=True, server_names=("*.example",))
    cert, key = self_signed(tmp_path / "tls")  # names 127.0.0.1 and localhost only
    assert "no name to answer to" in refused(host="0.0.0.0", certfile=str(cert), keyfile=str(key))

    # the scans folder: a new one is made 0700; one holding anything but scans is refused, naming it
    fresh = tmp_path / "new" / "scans"
    monkeypatch.setattr(srv, "_auth", lambda *a: None)
    with pytest.raises(pytest.fail.Exception, match="bound a socket"):
        srv.serve(rig, port=0, scans_dir=str(fresh))
    assert fresh.is_dir() and fresh.stat().st_mode & 0o777 == 0o700
    with pytest.raises(pytest.fail.Exception, match="bound a socket"):
        srv.serve(rig, port=0)  # the default: beside the per-user store
    assert default_scans_dir().is_dir() and default_scans_dir().parent.name == "vts-hw"
    (fresh / SCAN).mkdir()
    (fresh / "my-scan").mkdir()
    (fresh / "my-scan" / "manifest.json").write_text("{}")
    with pytest.raises(pytest.fail.Exception, match="bound a socket"):
        srv.serve(rig, port=0, scans_dir=str(fresh))  # scans only: served
    for name in SECRET_NAMES:
        (fresh / name).write_text("x")
        said = refused(scans_dir=str(fresh))
        assert f"holds {name!r}, a file" in said and str(fresh) in said, said
        (fresh / name).unlink()
    (fresh / "sim").mkdir()
    assert "'sim', a folder that is not a scan" in refused(scans_dir=str(fresh))
    (fresh / "sim").rmdir()
    (fresh / "scan-link").symlink_to(tmp_path)
    assert "'scan-link', a link" in refused(scans_dir=str(fresh))
    (fresh / "scan-link").unlink()
    os.chmod(fresh, 0o777)
    assert "anyone may write into it" in refused(scans_dir=str(fresh))
    os.chmod(fresh, 0o700)
    (tmp_path / "a-file").write_text("x")
    assert "is not a folder" in refused(scans_dir=str(tmp_path / "a-file"))


def test_the_command_refuses_plain_http_off_this_machine_in_one_sentence(capsys, monkeypatch, tmp_path):
    monkeypatch.setenv("VTS_STORE", f"sqlite:///{tmp_path / 'none.sqlite'}")
    monkeypatch.delenv("VTS_CONFIG", raising=False)
    for args, said in (
        (["--host", "0.0.0.0"], "needs users and login over HTTPS"),
        (["--host", "0.0.0.0", "--behind-proxy"], "in plain HTTP"),
        (["--behind-proxy"], "--server-name"),
        (["--proxy", "nginx"], "not an IP address"),
    ):
        code, out, err = vts(capsys, "console", *args, "--port", "0")
        assert code == 2 and said in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    assert not (tmp_path / "none.sqlite").exists()


# -- every route, every method, with the names of every secret ------------------------------------------------


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """Two consoles on one simulated rig, served by uvicorn on 127.0.0.1: without users, and with
    an operator and a physicist; the scans folder full of files named like secrets."""
    folder = tmp_path_factory.mktemp("network")
    scans = folder / "scans"
    scans.mkdir(mode=0o700)
    db = folder / "results.sqlite"
    with pytest.MonkeyPatch.context() as mp, ResultsStore(db) as store:
        mp.setattr(users, "SCRYPT_N", 2**10)
        add_user(store, "ann", "operator", ANN_PW)
        add_user(store, "phil", "physicist", PHIL_PW)
    hashes = re.findall(
        rb"scrypt\$[^\x00'\"]{40,}",
        b"".join(p.read_bytes() for p in folder.iterdir() if p.name.startswith("results.sqlite")),
    )
    assert len(hashes) >= 2
    with SimRig(n_cameras=2, seed=11) as rig, rig.env():
        rig_yaml, _ = rig.write(folder / "rig")
        env_secrets = [v.encode() for v in rig.env_vars().values()]
        marks = _plant(scans, folder, db)
        consoles = []
        for with_users in (False, True):
            cams = {c.name: open_camera(c) for c in rig.config().cameras}
            live = LiveConsole(cams, "sim", lambda: ResultsStore(db, mode="read"), rig_config=rig.config())
            live.console.scans_dir = scans
            if with_users:

                def load():
                    with ResultsStore(db, mode="read") as s:
                        return s.users(active_only=True)

                live.console.auth = Auth(required=True, load_users=load)
                live.console.auth.refresh_users()
            consoles.append((live, cams))
        with consoles[0][0] as local, consoles[1][0] as guarded:
            for live in (local, guarded):
                _a_finished_scan(live, scans)
            yield SimpleNamespace(
                rig=rig,
                local=local,
                guarded=guarded,
                scans=scans,
                secrets=[*marks, *hashes, *env_secrets, ANN_PW.encode(), PHIL_PW.encode()],
            )
        for _, cams in consoles:
            for c in cams.values():
                c.close()


def _plant(scans: Path, folder: Path, db: Path) -> list[bytes]:
    """Files named like every secret (each its own marker) in the scans folder, a scan folder and
    beside the store; links to them from inside the scans folder. The markers."""
    marks = []
    (scans / SCAN / "motion").mkdir(parents=True)
    (scans / SCAN / "manifest.json").write_text('{"status": "complete"}')
    (scans / "scan-other").mkdir()
    for where in (scans, scans / SCAN, scans / "scan-other", folder):
        for name in SECRET_NAMES:
            mark = f"SECRET-{secrets.token_hex(8)}-{name}".encode()
            marks.append(mark)
            path = where / name
            if path.exists():
                continue
            path.write_bytes(mark + b"\n")
    (scans / SCAN / "motion" / "motion-report.html").write_bytes(REPORT_BYTES)
    (scans / SCAN / "motion" / "leak.html").symlink_to(folder / "sim.env")  # a link out of the scan
    (scans / SCAN / "motion" / "store.html").symlink_to(db)
    (scans / "scan-elsewhere").symlink_to(folder)  # a scan that is a link
    return marks


def _a_finished_scan(live, scans: Path) -> None:
    """The Scan page's desk as after a scan and its analysis: the analysis's listed outputs are
    the report, two links out of the scan, and (as if its list were wrong) names out of it."""
    desk = live.console.scan_desk
    run = ScanRun(live.console.rig_config, scans / SCAN, live.hub, lambda *a: [], user="local")
    run.phase = "stopped"
    job = MotionJob(live.console.rig_config, run.folder, lambda: None)
    job.state, job.files = (
        "done",
        [
            "motion/motion-report.html",
            "motion/leak.html",
            "motion/store.html",
            "../sim.env",
            "/etc/passwd",
            f"{scans}/sim.env",
            "motion/../../rig.yaml",
        ],
    )
    desk.run, desk.job = run, job


def _fills(folder: Path) -> list[str]:
    """What a path parameter is filled with: every secret's name, traversal, absolute paths."""
    out = [
        *SECRET_NAMES,
        "..",
        ".",
        "%2e%2e",
        "%2E%2E",
        "..%2fsim.env",
        "%2e%2e%2fsim.env",
        "..%5csim.env",
        "....%2f%2fsim.env",
        "%2fetc%2fpasswd",
        "%252e%252e%252fsim.env",
        "scan-elsewhere",
        "scan-other",
        SCAN,
        "0",
        "1",
        "2",
        "3",
        "4",
        "5",
        "6",
        "99999999999999999999999",
        "-1",
        "cam1%00",
        "%00",
    ]
    for name in ("sim.env", "results.sqlite"):
        out.append(str(folder / name).replace("/", "%2f"))
    return out


def _paths(app, folder: Path, scans: Path) -> list[tuple[str, list[str]]]:
    """(path, methods) for every route of ``app``, each path parameter filled every way."""
    out = []
    fills = _fills(folder)
    for route in app.routes:
        if isinstance(route, Mount):  # the static files: any path under it
            tails = [
                *fills,
                "../app.py",
                "..%2fapp.py",
                "%2e%2e/%2e%2e/hosts.py",
                f"..{'/..' * 12}{folder}/sim.env",
                f"{scans}/sim.env",
                "console.css/../../app.py",
            ]
            out += [(f"{route.path}/{t}", ["GET"]) for t in tails] + [(f"{route.path}/console.css", ["HEAD", "PUT"])]
            continue
        assert isinstance(route, Route)
        methods = sorted(route.methods or {"GET"}) + ["PUT"]
        params = re.findall(r"{([^}:]+)(?::[^}]+)?}", route.path)
        if not params:
            out.append((route.path, methods))
            continue
        # a number's place: only what could match it, and traversal (anything else matches no route)
        last = [f for f in fills if f.isdigit() or "%2" in f] if route.path.endswith(":int}") else fills
        # the last parameter every way; one before it (a scan, a run) each way that names something
        heads = [[SCAN, "scan-elsewhere", "1", "%2e%2e"]] * (len(params) - 1)
        for i, combo in enumerate(itertools.product(*heads, last)):
            path = route.path
            for value in combo:
                path = re.sub(r"{[^}]+}", lambda _, value=value: value, path, count=1)
            # HEAD and a method the route has not: once per route
            out.append((path, methods if i == 0 else [m for m in methods if m not in ("HEAD", "PUT")]))
        if "path" in params or route.path.startswith("/scan/files/"):  # several segments
            out += [
                (f"/scan/files/{SCAN}/{t}", ["GET"])
                for t in (
                    "motion/leak.html",
                    "motion/../../rig.yaml",
                    "../sim.env",
                    "..%2f..%2frig%2frig.yaml",
                    f"..{'/..' * 12}{folder}/sim.env",
                    "motion/store.html",
                )
            ]
    return out


class _Raw:
    """Requests sent as given, byte for byte (no client-side normalisation of the path), each on
    a connection of its own (a kept-alive one waited tens of ms a request); an event stream is
    read for its first events. ``send`` -> (status, headers, body)."""

    def __init__(self, port):
        self.port, self.conn = port, None

    def send(self, method, path, headers, body=None):
        try:
            return self._send(method, path, headers, body)
        finally:
            self.close()

    def _send(self, method, path, headers, body):
        conn = self.conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=30)
        conn.putrequest(method, path, skip_accept_encoding=True)
        for k, v in headers.items():
            conn.putheader(k, v)
        data = body or b""
        if method in ("POST", "PUT"):
            conn.putheader("Content-Type", "application/json")
            conn.putheader("Content-Length", str(len(data)))
        conn.endheaders(data or None)
        r = conn.getresponse()
        if not r.getheader("content-type", "").startswith("text/event-stream"):
            return r.status, r.getheaders(), r.read()
        conn.sock.settimeout(0.5)
        got, end = b"", time.monotonic() + 0.3
        while time.monotonic() < end and got.count(b"\n\n") < 2:
            try:
                chunk = r.read1(8192)
            except TimeoutError:
                break
            if not chunk:
                break
            got += chunk
        return r.status, r.getheaders(), got

    def close(self):
        if self.conn is not None:
            self.conn.close()
            self.conn = None


def _login(live, name, password) -> tuple[str, str]:
    """(cookie header, page token) of a new session of ``name``."""
    port = int(live.url.rsplit(":", 1)[1].strip("/"))
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    conn.request("GET", "/login")  # the form first, as a browser: its token and cookie
    shown = conn.getresponse()
    csrf_token = FORM_TOKEN.search(shown.read().decode()).group(1)
    form_cookie = shown.getheader("set-cookie").split(";", 1)[0]
    body = f"name={name}&password={password}&next=/&csrf_token={csrf_token}".encode()
    conn.request(
        "POST",
        "/login",
        body=body,
        headers={
            "Content-Type": "application/x-www-form-urlencoded",
            "Origin": live.url.rstrip("/"),
            "Cookie": form_cookie,
        },
    )
    r = conn.getresponse()
    r.read()
    conn.close()
    assert r.status == 303, r.status
    cookie = r.getheader("set-cookie").split(";", 1)[0]
    token = next(s.token for s in live.console.auth._sessions.values() if s.key == cookie.split("=", 1)[1])
    return cookie, token


def _walk(live, folder, scans, who, cookie="", token=""):
    port = int(live.url.rsplit(":", 1)[1].strip("/"))
    app = live.server.server.config.app  # the app as served: its routes enumerated, never a hand list
    seen = []
    raw = _Raw(port)
    for path, methods in sorted(_paths(app, folder, scans), key=lambda pm: pm[0] == "/logout"):  # (that last)
        for method in methods:
            headers = {"Cookie": cookie} if cookie else {}
            # a POST with the page token only where the path names something (else it would start a scan, ...)
            if method == "POST" and token and "{" not in path and re.search(r"/(camera|aim|alert)/", path):
                headers["X-Console-Token"] = token
            status, hdrs, body = raw.send(method, path, headers, b'{"on": false}' if method == "POST" else None)
            seen.append((who, method, path, status, dict((k.lower(), v) for k, v in hdrs), body))
    raw.close()
    return seen


def test_no_route_serves_a_secret_to_anyone_whatever_the_path(served):
    folder = served.scans.parent
    seen = _walk(served.local, folder, served.scans, "local", token=served.local.console.console_token)
    seen += _walk(served.guarded, folder, served.scans, "nobody")
    for name, pw in (("ann", ANN_PW), ("phil", PHIL_PW)):
        cookie, token = _login(served.guarded, name, pw)
        seen += _walk(served.guarded, folder, served.scans, name, cookie, token)
    assert len(seen) > 1500, len(seen)
    leaks, bare = [], []
    for who, method, path, status, hdrs, body in seen:
        blob = body + repr(hdrs).encode()
        leaks += [(who, method, path, status, s[:40]) for s in served.secrets if s in blob]
        if not (
            hdrs.get("x-frame-options") == "DENY"
            and hdrs.get("x-content-type-options") == "nosniff"
            and hdrs.get("content-security-policy") in (PAGE_CSP, DOCUMENT_CSP)
        ):
            bare.append((who, method, path, status))
    assert leaks == [], leaks[:10]
    assert bare == [], bare[:10]
    # the scan's own report is served, by number, to whoever may see the Scan page; nothing else of it
    got = {(w, s) for w, m, p, s, _, b in seen if m == "GET" and p == f"/scan/files/{SCAN}/0" and b == REPORT_BYTES}
    assert got == {("local", 200), ("ann", 200), ("phil", 200)}, "; ".join(
        str(x)
        for x in [(w, m, s, b[:100]) for w, m, p, s, _, b in seen if p == f"/scan/files/{SCAN}/0" and w != "nobody"]
    )
    report = next(h for w, m, p, s, h, _ in seen if w == "local" and m == "GET" and p == f"/scan/files/{SCAN}/0")
    assert report["content-security-policy"] == DOCUMENT_CSP and "sandbox" in DOCUMENT_CSP
    others = {s for w, m, p, s, *_ in seen if p.startswith("/scan/files/") and p != f"/scan/files/{SCAN}/0"}
    assert others <= {400, 401, 404, 405}, others
    # not logged in: the login page and the static files, nothing else
    opened = {p for w, m, p, s, *_ in seen if w == "nobody" and s < 300}
    assert opened and all(p == "/login" or p.startswith("/static/") for p in opened), sorted(opened)[:10]


# -- in Chromium: DNS rebinding, and the pages within their policy -----------------------------------------------


def test_in_chromium_a_rebound_name_reads_nothing_and_the_pages_keep_their_policy(served):
    live = served.local
    port = int(live.url.rsplit(":", 1)[1].strip("/"))
    rig = served.rig
    rig.sources["cam1"].set_led(True)
    with chromium("--host-resolver-rules=MAP evil.example 127.0.0.1") as b:
        pg = b.new_page(viewport={"width": 1366, "height": 768})
        violations = []
        pg.on("console", lambda m: violations.append(m.text) if "Content Security Policy" in m.text else None)
        pg.on("pageerror", lambda e: violations.append(f"page error: {e}"))
        # the attacker's page on evil.example, its name resolved to this machine
        r = pg.goto(f"http://evil.example:{port}/")
        assert r.status == 400 and "does not answer to the name 'evil.example'" in pg.inner_text("body")
        assert live.console.console_token not in pg.content()
        status = pg.evaluate(
            """async ([token]) => (await fetch('/camera/cam1/led', {method: 'POST',
            headers: {'Content-Type': 'application/json', 'X-Console-Token': token},
            body: JSON.stringify({on: false})})).status""",
            [live.console.console_token],
        )
        assert status == 400 and rig.servers["cam1"].source.led_on()  # even with the real token
        # the console's own pages: within their Content-Security-Policy
        pg.goto(live.url)
        assert until(lambda: pg.eval_on_selector('section[data-camera="cam1"] img', "e => e.dataset.seq"), 30)
        for path in ("scan", "qa", "history", "history/actions"):
            pg.goto(live.url + path)
            pg.wait_for_load_state("load")
        for path in ("history/drift-report", "history/rooms/"):
            r = pg.goto(live.url + path)
            assert r.headers["content-security-policy"] == DOCUMENT_CSP
            # the report's own inline script ran, in its sandbox
            assert until(lambda: pg.evaluate("document.body.dataset.plotsLoaded") is not None, 10), path
        pg.wait_for_timeout(500)
        assert violations == [], violations
