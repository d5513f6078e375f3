"""A simulated QATrack+ 3.1 on 127.0.0.1: the part of its REST API the push uses, with faults.

As strict as the real server on everything the push sends and reads: tests/interop/test_qatrack_peer.py
sends the same conversation (tests/qatrack_conversation.py) to this stand-in and compares its
answers with the real server's, recorded once into tests/data/qatrack_real_answers.json by
``python tests/qatrack_conversation.py record`` against ``../shared/interop/qatrack/run-qatrack.sh``.
The site's rules (work times in its zone, field errors, the list's rules) are in
:mod:`.qatrack_site`; this module is the HTTP around them, as Django and DRF answer:

- ``POST /api/get-token/`` (form or JSON): ``{"token": ...}``; a wrong login: 400
  ``{"non_field_errors": ["Unable to log in with provided credentials."]}``;
- every other API call needs ``Authorization: Token KEY`` (401 ``Invalid token.`` or
  ``Authentication credentials were not provided.``, with ``WWW-Authenticate: Token``); a POST
  needs the user's add permission, a PATCH its change permission (403 "You do not have
  permission to perform this action.");
- ``GET /api/qa/unittestcollections/`` and ``GET /api/qa/testlistinstances/`` (``qa`` or
  ``qc``): limit/offset pages of 100 ``{count, next, previous, results}``; filters
  ``unit__name``, ``test_list__name``, ``active``; ``user_key``; ``GET .../N/`` one of them;
- ``POST /api/qa/testlistinstances/``: 201 with the new instance (``Location`` its url) or 400;
- an API path without its final slash: 301 to it (Django's APPEND_SLASH); an unknown API
  path: 404 HTML; anything outside ``/api/``: 302 to the site's login page (a wrong base URL).

Faults (``server.fault``): ``None``; ``"slow"`` (every answer after ``slow_s``); ``"500"``
(the server-error page); ``("400", message)`` (a POST refused with that message); ``"trickle"``
(the status and headers at once, then the body one byte every ``trickle_s`` seconds);
``"lose_answer"`` (a POST is stored, then answered only after ``slow_s``: the client times
out although the instance exists). ``down()`` stops listening, ``up()`` listens again on the
same port; ``add_instance(key)`` puts an instance with that user key there (a duplicate).
"""

from __future__ import annotations

import datetime as _dt
import json
import re
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from urllib.parse import parse_qs, urlencode, urlsplit

from vts_hw.sim_devices.qatrack_site import NO_PERMISSION, Site, show_time

PAGE = 100
FAULTS = ("slow", "500", "400", "lose_answer", "trickle", "down", "add_instance")
"""Every fault the peer injects: the values of ``fault`` (``"400"`` as the tuple's head) and the
methods that take it down or put a duplicate there; docs/faults.md has a row for each."""
ERROR_PAGE = (
    '<!DOCTYPE html>\n<html lang="en-us"><head><title>example.com: Error {code} : {what}</title></head>'
    "<body><h1>Error {code}</h1><p>{what}</p></body></html>\n"
)
ROUTE = re.compile(r"^/api/(?:(get-token)|q[ac]/(unittestcollections|testlistinstances))/(?:(\d+)/)?$")


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = False
    allow_reuse_address = True


class QATrackSim:
    """A QATrack+ site with ``units`` (unit name -> test list names assigned) and ``lists``
    (test list name -> its test macros, all numeric), in ``time_zone`` (its TIME_ZONE). ``token``
    is the push user's ("vts", who may add instances); ``users`` name -> password exchange for it."""

    def __init__(
        self,
        lists: dict[str, list[str]],
        units: dict[str, list[str]],
        token: str = "sim-token",
        users: dict[str, str] | None = None,
        port: int = 0,
        time_zone: str = "America/Toronto",
        admin_token: str = "sim-admin-token",
    ):
        self.site = Site(lists, units, time_zone)
        self.token = token
        self.users = dict(users or {})
        self.accounts: dict[str, dict] = {}  # token -> {name, id, perms}
        self.add_user("admin", token=admin_token, perms=("add", "change"))
        self.add_user("vts", token=token, perms=("add",))
        self.requests: list[tuple[str, str, str]] = []  # method, path, Authorization header
        self.posts = 0
        self.last_post: dict | None = None  # the body of the last instance created
        self.fault = None
        self.slow_s = 2.0
        self.trickle_s = 0.5
        self._lock = threading.Lock()
        self._port = port
        self._server: _Server | None = None

    def add_user(self, name: str, token: str, perms=("add",)) -> None:
        """A user of the site with a token and permissions (``add``, ``change`` of instances)."""
        ids = {a["name"]: a["id"] for a in self.accounts.values()}
        self.accounts[token] = {"name": name, "id": ids.get(name, 2 + len(ids)), "perms": set(perms)}

    # -- life -------------------------------------------------------------------------------

    def up(self) -> QATrackSim:
        self._server = _Server(("127.0.0.1", self._port), _handler(self))
        self._port = self._server.server_address[1]
        threading.Thread(target=self._server.serve_forever, args=(0.05,), daemon=True, name="qatrack-sim").start()
        return self

    def down(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def __enter__(self) -> QATrackSim:
        return self.up() if self._server is None else self

    def __exit__(self, *exc) -> None:
        self.down()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self._port}/"

    # -- data -------------------------------------------------------------------------------

    @property
    def utcs(self) -> list[dict]:
        return self.site.utcs

    @property
    def instances(self) -> list[dict]:
        """What the site holds, one dict per instance: url, user_key, work times (as the site
        shows them), comment, tests {macro: {value, skipped, comment}}, attachment names and bytes."""
        z = self.site.zone
        return [
            {
                "url": f"{self.url}api/qc/testlistinstances/{i['id']}/",
                "user_key": i["user_key"],
                "work_started": self.site_time(i["work_started"]),
                "work_completed": self.site_time(i["work_completed"]),
                "comment": i["comment"] or "",
                "tests": i["tests"],
                "zone": z.key,
                "attachments": [a["filename"] for a in i["attachments"]],
                "attachment_bytes": sum(a["size"] for a in i["attachments"]),
            }
            for i in self.site.instances
        ]

    def site_time(self, value) -> str | None:
        return show_time(value, self.site.zone)

    def add_instance(self, user_key: str, utc_id: int = 1, tests: dict | None = None) -> dict:
        with self._lock:
            utc = self.site.utcs[utc_id - 1]
            now = _dt.datetime.now(_dt.UTC)
            given = tests or {}
            fields = {
                "unit_test_collection": utc,
                "work_started": now,
                "work_completed": now,
                "user_key": user_key,
                "comment": None,
                "attachments": [],
                "tests": {
                    m: {"value": given.get(m, {}).get("value"), "skipped": m not in given, "comment": ""}
                    for m in self.site.lists[utc["test_list"]]
                },
            }
            self.site.add(fields, "admin", 2)
        return self.instances[-1]


def _page(root: str, path: str, items: list[dict], query: dict) -> dict:
    limit = int(query.get("limit", [PAGE])[0])
    offset = int(query.get("offset", [0])[0])
    flat = {k: v[0] for k, v in query.items()}

    def link(off):
        return f"{root}{path.lstrip('/')}?" + urlencode({**flat, "limit": limit, "offset": off})

    return {
        "count": len(items),
        "next": link(offset + limit) if offset + limit < len(items) else None,
        "previous": link(max(offset - limit, 0)) if offset > 0 else None,
        "results": items[offset : offset + limit],
    }


def _handler(sim: QATrackSim):
    site = sim.site

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args):  # quiet
            pass

        def _answer(self, code: int, body=None, content_type="application/json", extra=None):
            if content_type == "application/json":
                raw = json.dumps(body).encode()
            else:
                raw = str(body or "").encode()
                content_type = "text/html; charset=utf-8"
            self.send_response(code)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(raw)))
            for k, v in (extra or {}).items():
                self.send_header(k, v)
            self.end_headers()
            if sim.fault == "trickle":
                try:
                    for k in range(len(raw)):
                        self.wfile.write(raw[k : k + 1])
                        self.wfile.flush()
                        time.sleep(sim.trickle_s)
                except OSError:  # the client gave up
                    pass
                return
            self.wfile.write(raw)

        def _raw(self) -> bytes:
            n = int(self.headers.get("Content-Length") or 0)
            return self.rfile.read(n) if n else b""

        def _body(self, raw: bytes):
            if (self.headers.get("Content-Type") or "").startswith("application/json"):
                return json.loads(raw or b"null")
            return {k: v[0] for k, v in parse_qs(raw.decode()).items()}

        def _account(self) -> dict | None:
            """The caller's account, or None after answering 401."""
            auth = self.headers.get("Authorization")
            if not auth or not auth.startswith("Token "):
                self._answer(
                    401,
                    {"detail": "Authentication credentials were not provided."},
                    extra={"WWW-Authenticate": "Token"},
                )
                return None
            account = sim.accounts.get(auth[6:].strip())
            if account is None:
                self._answer(401, {"detail": "Invalid token."}, extra={"WWW-Authenticate": "Token"})
            return account

        def _faulty(self) -> bool:
            fault = sim.fault
            if fault == "slow":
                time.sleep(sim.slow_s)
            if fault == "500":
                self._answer(500, ERROR_PAGE.format(code=500, what="Server Error"), "text/html")
                return True
            return False

        def _route(self, method: str):
            """(kind, collection, id) of an API path, or None after answering as Django does."""
            path = urlsplit(self.path).path
            sim.requests.append((method, path, self.headers.get("Authorization") or ""))
            if not path.startswith("/api/"):
                self._answer(302, "", "text/html", {"Location": f"/accounts/login/?next={path}"})
                return None
            m = ROUTE.match(path)
            if m is None and ROUTE.match(path + "/"):
                self._answer(301, "", "text/html", {"Location": path + "/"})
                return None
            if m is None:
                self._answer(404, ERROR_PAGE.format(code=404, what="Resource not found"), "text/html")
                return None
            return m.group(1) or m.group(2), (int(m.group(3)) if m.group(3) else None)

        def do_GET(self):
            route = self._route("GET")
            if route is None or self._faulty():
                return
            kind, n = route
            if kind == "get-token":
                self._answer(405, {"detail": 'Method "GET" not allowed.'})
                return
            if self._account() is None:
                return
            parts = urlsplit(self.path)
            q = parse_qs(parts.query)
            one = {k: v[0] for k, v in q.items()}
            with sim._lock:
                if kind == "unittestcollections":
                    items = [
                        site.utc_json(sim.url, u) for u in site.utcs if n in (None, u["id"]) and _utc_matches(u, one)
                    ]
                else:
                    items = [
                        site.instance_json(sim.url, i)
                        for i in site.instances
                        if n in (None, i["id"]) and ("user_key" not in one or i["user_key"] == one["user_key"])
                    ]
            if n is not None:
                self._answer(200, items[0]) if items else self._answer(404, {"detail": "Not found."})
            else:
                self._answer(200, _page(sim.url, parts.path, items, q))

        def do_PATCH(self):
            self._raw()
            route = self._route("PATCH")
            if route is None or self._faulty():
                return
            account = self._account()
            if account is not None:
                if "change" not in account["perms"]:
                    self._answer(403, {"detail": NO_PERMISSION})
                else:
                    self._answer(405, {"detail": 'Method "PATCH" not allowed.'})

        def do_POST(self):
            raw = self._raw()
            route = self._route("POST")
            if route is None:
                return
            kind, n = route
            if kind == "get-token":
                try:
                    data = self._body(raw)
                except ValueError as exc:
                    self._answer(400, {"detail": f"JSON parse error - {exc}"})
                    return
                if self._faulty():
                    return
                user, pw = (data or {}).get("username"), (data or {}).get("password")
                if user in sim.users and sim.users[user] == pw:
                    self._answer(200, {"token": sim.token})
                else:
                    self._answer(400, {"non_field_errors": ["Unable to log in with provided credentials."]})
                return
            if self._faulty():
                return
            account = self._account()
            if account is None:
                return
            if kind != "testlistinstances" or n is not None:
                self._answer(405, {"detail": 'Method "POST" not allowed.'})
                return
            if "add" not in account["perms"]:
                self._answer(403, {"detail": NO_PERMISSION})
                return
            try:
                data = self._body(raw)
            except ValueError as exc:
                self._answer(400, {"detail": f"JSON parse error - {exc}"})
                return
            if isinstance(sim.fault, tuple) and sim.fault[0] == "400":
                self._answer(400, {"non_field_errors": [sim.fault[1]]})
                return
            with sim._lock:
                fields, errors = site.validate(data)
                if errors:
                    self._answer(400, errors)
                    return
                record = site.add(fields, account["name"], account["id"])
                sim.posts += 1
                sim.last_post = data
            if sim.fault == "lose_answer":
                time.sleep(sim.slow_s)
            made = site.created_json(sim.url, record)
            self._answer(201, made, extra={"Location": made["url"]})

    return Handler


def _utc_matches(u: dict, q: dict) -> bool:
    checks = [
        ("unit__name", lambda v: u["unit"] == v),
        ("test_list__name", lambda v: u["test_list"] == v),
        ("active", lambda v: u["active"] == (v.lower() in ("true", "1"))),
    ]
    return all(test(q[k]) for k, test in checks if k in q)
