"""A simulated QATrack+ on 127.0.0.1: the part of its REST API the push uses, with faults.

Modelled on QATrack+'s own code and API guide (qatrackplus/qatrackplus: qatrack/api/urls.py,
qatrack/api/qa/{views,filters,serializers}.py, docs/api/guide.rst), with Django REST
framework's shapes:

- ``POST /api/get-token/`` (form or JSON username/password): ``{"token": ...}``; a wrong
  login: 400 ``{"non_field_errors": ["Unable to log in with provided credentials."]}``;
- every other call needs ``Authorization: Token KEY``: 401 ``{"detail": "Invalid token."}``
  or ``{"detail": "Authentication credentials were not provided."}``;
- ``GET /api/qa/unittestcollections/`` and ``GET /api/qa/testlistinstances/``: limit/offset
  pages ``{count, next, previous, results}`` (10 a page), filters ``unit__name``,
  ``unit__name__icontains``, ``test_list__name``, ``test_list__name__icontains``, ``active``;
  ``user_key``, ``unit_test_collection`` (an id);
- ``POST /api/qa/testlistinstances/``: 201 with the instance (``url``, ``site_url``, ``tests``
  ...); 400 as QATrack+ words it: a required field, an unknown assignment ("Invalid hyperlink -
  Object does not exist."), a test that is not a dictionary, "Missing data for tests: ...",
  "Wrong value type (number/string) for tests: ...", the user key already used, attachments
  not base64. Like QATrack+, values for macros not in the test list are ignored.

Faults (``server.fault``): ``None``; ``"slow"`` (every answer after ``slow_s``); ``"500"``
(Django's plain server-error page); ``("400", message)`` (a POST refused with that message);
``"lose_answer"`` (a POST is stored, then answered only after ``slow_s``: the client times
out although the instance exists). ``down()`` stops listening, ``up()`` listens again on the
same port; ``add_instance(key)`` puts an instance with that user key there (a duplicate).
"""

from __future__ import annotations

import json
import re
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from numbers import Number
from urllib.parse import parse_qs, urlencode, urlsplit

BASE64_RE = re.compile(r"^([A-Za-z0-9+/]{4})*([A-Za-z0-9+/]{4}|[A-Za-z0-9+/]{3}=|[A-Za-z0-9+/]{2}==)$")
PAGE = 10
FAULTS = ("slow", "500", "400", "lose_answer", "down", "add_instance")
"""Every fault the peer injects: the values of ``fault`` (``"400"`` as the tuple's head) and the
methods that take it down or put a duplicate there; docs/faults.md has a row for each."""


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = False
    allow_reuse_address = True


class QATrackSim:
    """A QATrack+ site with ``units`` (unit name -> test list names assigned) and ``lists``
    (test list name -> its test macros, all numeric)."""

    def __init__(self, lists: dict[str, list[str]], units: dict[str, list[str]], token: str = "sim-token",
                 users: dict[str, str] | None = None, port: int = 0):
        self.lists = {name: list(macros) for name, macros in lists.items()}
        self.token = token
        self.users = dict(users or {})
        self.utcs: list[dict] = []   # id, unit, test_list, active
        for unit, names in units.items():
            for name in names:
                self.utcs.append({"id": len(self.utcs) + 1, "unit": unit, "test_list": name, "active": True})
        self.instances: list[dict] = []
        self.requests: list[tuple[str, str, str]] = []   # method, path, Authorization header
        self.posts = 0
        self.last_post: dict | None = None   # the body of the last instance created
        self.fault = None
        self.slow_s = 2.0
        self._lock = threading.Lock()
        self._port = port
        self._server: _Server | None = None
        self._thread: threading.Thread | None = None

    # -- life -------------------------------------------------------------------------------

    def up(self) -> "QATrackSim":
        self._server = _Server(("127.0.0.1", self._port), _handler(self))
        self._port = self._server.server_address[1]
        self._thread = threading.Thread(target=self._server.serve_forever, args=(0.05,), daemon=True, name="qatrack-sim")
        self._thread.start()
        return self

    def down(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    def __enter__(self) -> "QATrackSim":
        return self.up() if self._server is None else self

    def __exit__(self, *exc) -> None:
        self.down()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self._port}/"

    # -- data -------------------------------------------------------------------------------

    def add_instance(self, user_key: str, utc_id: int = 1, tests: dict | None = None) -> dict:
        with self._lock:
            return self._store_instance(self.utcs[utc_id - 1], {"user_key": user_key, "tests": tests or {},
                                                                 "work_started": None, "work_completed": None,
                                                                 "comment": "", "attachments": []})

    def _store_instance(self, utc: dict, data: dict) -> dict:
        n = len(self.instances) + 1
        tli = {"id": n, "url": f"{self.url}api/qa/testlistinstances/{n}/",
               "site_url": f"{self.url}qa/session/details/{n}/",
               "unit_test_collection": f"{self.url}api/qa/unittestcollections/{utc['id']}/",
               "test_list": f"{self.url}api/qa/testlists/{list(self.lists).index(utc['test_list']) + 1}/",
               "day": 0, "in_progress": False, "include_for_scheduling": True,
               "work_started": data.get("work_started"), "work_completed": data.get("work_completed"),
               "user_key": data.get("user_key"), "comment": data.get("comment") or "",
               "tests": {m: {"value": data["tests"].get(m, {}).get("value"),
                             "skipped": bool(data["tests"].get(m, {}).get("skipped", False)),
                             "comment": data["tests"].get(m, {}).get("comment", "")}
                         for m in self.lists[utc["test_list"]]},
               "attachments": [a["filename"] for a in data.get("attachments") or []],
               "attachment_bytes": sum(len(a["value"]) for a in data.get("attachments") or [])}
        self.instances.append(tli)
        return tli

    def utc_json(self, u: dict) -> dict:
        tl = f"{self.url}api/qa/testlists/{list(self.lists).index(u['test_list']) + 1}/"
        return {"url": f"{self.url}api/qa/unittestcollections/{u['id']}/",
                "unit": f"{self.url}api/units/units/{sorted({x['unit'] for x in self.utcs}).index(u['unit']) + 1}/",
                "frequency": None, "assigned_to": f"{self.url}api/auth/groups/1/", "visible_to": [],
                "tests_object": tl, "next_test_list": tl, "next_day": 0, "due_date": None,
                "auto_schedule": False, "active": u["active"], "name": u["test_list"], "object_id": u["id"],
                "content_type": f"{self.url}api/contenttypes/contenttypes/31/", "last_instance": None}

    # -- the API ----------------------------------------------------------------------------

    def validate(self, data) -> tuple[dict | None, dict | None]:
        """(the assignment, None) or (None, a DRF-shaped 400 body)."""
        if not isinstance(data, dict):
            return None, {"non_field_errors": ["Invalid data. Expected a dictionary, but got list."]}
        errors: dict[str, list[str]] = {}
        utc = None
        ref = data.get("unit_test_collection")
        if ref in (None, ""):
            errors["unit_test_collection"] = ["This field is required."]
        else:
            m = re.search(r"/api/qa/unittestcollections/(\d+)/$", str(ref))
            if not m:
                errors["unit_test_collection"] = ["Invalid hyperlink - No URL match."]
            elif not 1 <= int(m.group(1)) <= len(self.utcs):
                errors["unit_test_collection"] = ["Invalid hyperlink - Object does not exist."]
            else:
                utc = self.utcs[int(m.group(1)) - 1]
        tests = data.get("tests")
        if tests is None:
            errors["tests"] = ["This field is required."]
        elif not isinstance(tests, dict):
            errors["tests"] = [f'Expected a dictionary of items but got type "{type(tests).__name__}".']
        else:
            bad = ['"%s"' % k for k, v in tests.items() if not isinstance(v, dict)]
            if bad:
                errors["tests"] = ["%s field(s) have errors. Test data must be a dictionary " % ", ".join(bad)]
        key = data.get("user_key")
        if key and any(i["user_key"] == key for i in self.instances):
            errors["user_key"] = ["test list instance with this user key already exists."]
        for a in data.get("attachments") or []:
            if not isinstance(a, dict) or "filename" not in a or "value" not in a:
                errors["attachments"] = ['`attachments` field must be list of form [{"filename": "file_name.txt", '
                                         '"value": "<base64 encoded bytes|text>", "encoding": "<base64|text>], ...]']
            elif a.get("encoding", "base64") == "base64" and not BASE64_RE.match(a["value"]):
                errors["attachments"] = ["base64 encoding requested but content does not appear to be base64"]
        if errors:
            return None, errors
        msgs = []
        missing = [m for m in self.lists[utc["test_list"]] if m not in tests]
        wrong = [m for m in self.lists[utc["test_list"]] if m in tests and not tests[m].get("skipped")
                 and not isinstance(tests[m].get("value"), Number)]
        if missing:
            msgs.append("Missing data for tests: %s" % ", ".join(missing))
        if wrong:
            msgs.append("Wrong value type (number/string) for tests: %s\nIf these are composite tests with "
                        "missing dependencies, they should be marked as skipped in your request (e.g. "
                        "{'tests': {'%s': {'skipped': True}}})" % (", ".join(wrong), wrong[0]))
        if data.get("work_started") and data.get("work_completed") and \
                str(data["work_completed"]) < str(data["work_started"]):
            msgs.append("work_completed date must be after work_started")
        if msgs:
            return None, {"non_field_errors": ["\n".join(msgs)]}
        return utc, None


def _page(sim: QATrackSim, path: str, items: list[dict], query: dict) -> dict:
    limit = int(query.get("limit", [PAGE])[0])
    offset = int(query.get("offset", [0])[0])
    flat = {k: v[0] for k, v in query.items()}

    def link(off):
        return f"{sim.url}{path.lstrip('/')}?" + urlencode({**flat, "limit": limit, "offset": off})
    return {"count": len(items), "next": link(offset + limit) if offset + limit < len(items) else None,
            "previous": link(max(offset - limit, 0)) if offset > 0 else None,
            "results": items[offset:offset + limit]}


def _handler(sim: QATrackSim):
    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"

        def log_message(self, *args):   # quiet
            pass

        def _answer(self, code: int, body, content_type="application/json", extra=None):
            raw = (json.dumps(body) if content_type == "application/json" else str(body)).encode()
            self.send_response(code)
            self.send_header("Content-Type", content_type)
            self.send_header("Content-Length", str(len(raw)))
            for k, v in (extra or {}).items():
                self.send_header(k, v)
            self.end_headers()
            self.wfile.write(raw)

        def _body(self):
            n = int(self.headers.get("Content-Length") or 0)
            raw = self.rfile.read(n) if n else b""
            if (self.headers.get("Content-Type") or "").startswith("application/json"):
                return json.loads(raw or b"null")
            return {k: v[0] for k, v in parse_qs(raw.decode()).items()}

        def _authorised(self) -> bool:
            auth = self.headers.get("Authorization")
            if not auth:
                self._answer(401, {"detail": "Authentication credentials were not provided."},
                             extra={"WWW-Authenticate": "Token"})
                return False
            if auth != f"Token {sim.token}":
                self._answer(401, {"detail": "Invalid token."}, extra={"WWW-Authenticate": "Token"})
                return False
            return True

        def _faulty(self) -> bool:
            fault = sim.fault
            if fault == "slow":
                time.sleep(sim.slow_s)
            if fault == "500":
                self._answer(500, "<h1>Server Error (500)</h1>", "text/html")
                return True
            return False

        def do_GET(self):
            parts = urlsplit(self.path)
            sim.requests.append(("GET", parts.path, self.headers.get("Authorization") or ""))
            if self._faulty() or not self._authorised():
                return
            q = parse_qs(parts.query)
            one = {k: v[0] for k, v in q.items()}
            with sim._lock:
                if parts.path == "/api/qa/unittestcollections/":
                    items = [u for u in sim.utcs if _utc_matches(u, one)]
                    self._answer(200, _page(sim, parts.path, [sim.utc_json(u) for u in items], q))
                elif parts.path == "/api/qa/testlistinstances/":
                    items = [{k: v for k, v in i.items() if k not in ("id", "attachment_bytes")}
                             for i in sim.instances if _tli_matches(i, one)]
                    self._answer(200, _page(sim, parts.path, items, q))
                else:
                    self._answer(404, {"detail": "Not found."})

        def do_POST(self):
            parts = urlsplit(self.path)
            sim.requests.append(("POST", parts.path, self.headers.get("Authorization") or ""))
            try:
                data = self._body()
            except ValueError:
                self._answer(400, {"detail": "JSON parse error - Expecting value: line 1 column 1 (char 0)"})
                return
            if self._faulty():
                return
            if parts.path == "/api/get-token/":
                user, pw = (data or {}).get("username"), (data or {}).get("password")
                if user in sim.users and sim.users[user] == pw:
                    self._answer(200, {"token": sim.token})
                else:
                    self._answer(400, {"non_field_errors": ["Unable to log in with provided credentials."]})
                return
            if not self._authorised():
                return
            if parts.path != "/api/qa/testlistinstances/":
                self._answer(405, {"detail": 'Method "POST" not allowed.'})
                return
            if isinstance(sim.fault, tuple) and sim.fault[0] == "400":
                self._answer(400, {"non_field_errors": [sim.fault[1]]})
                return
            with sim._lock:
                utc, errors = sim.validate(data)
                if errors:
                    self._answer(400, errors)
                    return
                tli = sim._store_instance(utc, data)
                sim.posts += 1
                sim.last_post = data
            if sim.fault == "lose_answer":
                time.sleep(sim.slow_s)
            self._answer(201, {k: v for k, v in tli.items() if k not in ("id", "attachment_bytes")},
                         extra={"Location": tli["url"]})

    return Handler


def _utc_matches(u: dict, q: dict) -> bool:
    checks = [("unit__name", lambda v: u["unit"] == v),
              ("unit__name__icontains", lambda v: v.lower() in u["unit"].lower()),
              ("test_list__name", lambda v: u["test_list"] == v),
              ("test_list__name__icontains", lambda v: v.lower() in u["test_list"].lower()),
              ("active", lambda v: u["active"] == (v.lower() in ("true", "1")))]
    return all(test(q[k]) for k, test in checks if k in q)


def _tli_matches(i: dict, q: dict) -> bool:
    if "user_key" in q and i["user_key"] != q["user_key"]:
        return False
    if "unit_test_collection" in q and not i["unit_test_collection"].endswith(f"/{q['unit_test_collection']}/"):
        return False
    return True

