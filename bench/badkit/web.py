"""The class "web" of bench/bad_inputs.py (issue 32 §5): every route and method of the room
console (read from its code: badkit/web_surface.py), as each who may send it (the person at a
console without users; with users: nobody logged in, an operator, a physicist), with the bad
inputs an attacker or a careless page sends. The console is `vts console` as users run it, on a
simulated rig started once, with secrets planted where a careless server would serve them
(badkit/web_peer.py). The families, each over its whole surface:

* ``anonymous``: every endpoint with no session (a console with users): refused (401, or 303 to
  the login page), but for the login page and the static files;
* ``host``: a foreign ``Host`` (DNS rebinding: ``evil.example``, with our port, a name ending in
  ours): refused, whatever the route;
* ``origin``: every POST with our token and a foreign ``Origin``, ``Origin: null``, only a foreign
  ``Referer``, only ``Sec-Fetch-Site: cross-site``: refused, nothing changed;
* ``token``: every POST without the page token, with a wrong one, with another session's;
* ``script``: ``<script>`` (and an attribute breaker) in every path, query, body and form slot:
  never back unescaped in an answer a browser would render (HTML, or anything without
  ``X-Content-Type-Options: nosniff``);
* ``traversal``: ``..``, encoded, absolute, backslashed and secret names in every path slot;
* ``numbers``: 1e309, nan, inf, -inf, 2**64, -1 and a 23-digit number in every path, query and
  body slot; in a body accepted (2xx) by a route that reads it: a false OK;
* ``bodies``: every POST with malformed, non-object, deeply nested, huge JSON and wrong content
  types: a route that reads a body must not act on one (2xx: a false OK);
* ``repeated``: every query slot given twice (two values each accepted alone): answered 2xx is
  one taken silently;
* ``headers``: every page's security headers (CSP with frame-ancestors, nosniff, Referrer-Policy);
* ``many clients``: 50 event streams and 50 requests at once: every request answered, and once
  they are closed the console lets go of the cameras' streams and its sockets;
* ``stop``: Ctrl-C stops it (exit 0).

Every case is judged by: an answer (else a hang), status < 500 and no traceback (in the answer or
on the console's stderr), no secret's bytes (badkit/web_peer.PlantedRig._secrets), no redirect off the
console, and, for a POST, nothing changed (each LED read from the camera, the aim checks, the scan
and QA jobs, the scans folder, the store's runs, outbox and users, the sessions) and no entry in
the action log but a refusal. A change or an acceptance by a request from elsewhere (host, origin,
token, anonymous) is a security finding; by a bad input of the page's own user, a false OK.

Run as a script (its own process: it uses threads; the sweep forks): ``web.py ROOT [--full]``
prints the cases' verdicts as JSON. Without ``--full`` (make test) each endpoint meets each family
with the first value of each list, as one of the identities in turn; ``--full`` every value as
every identity.
"""

from __future__ import annotations

import json
import os
import re
import sys
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from urllib.parse import quote

if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from badkit.web_peer import PASSWORDS, SCAN, SECRET_NAMES, Answer, Console, PlantedRig, Who  # noqa: E402
from badkit.web_surface import Endpoint, surface  # noqa: E402

CLASS = "web"
SCRIPTS = ['<script>alert("vts-xss")</script>', '"><img src=x onerror=alert(1)>']
RAW_SCRIPT = ('<script>alert("vts-xss")', "<img src=x onerror")
NUMBERS = ["1e309", "nan", "inf", "-inf", str(2**64), "-1", "9" * 23]
#: how a bad number shows up once taken (in an answer or the action log's detail, as JSON writes it)
TAKEN = {
    "1e309": ["Infinity", "inf", "1e+309"],
    "nan": ["NaN", "nan"],
    "inf": ["Infinity", "inf"],
    "-inf": ["-Infinity", "-inf"],
    str(2**64): [str(2**64), "1.8446744073709552e+19"],
    "-1": [": -1"],
    "9" * 23: ["9" * 23, "1e+23"],
}
JSON_NUMBER = {"nan": "NaN", "inf": "Infinity", "-inf": "-Infinity"}
TRAVERSAL = [
    "..",
    "%2e%2e",
    "../../sim.env",
    "..%2f..%2fsim.env",
    "%2e%2e%2f%2e%2e%2fid_rsa",
    "/etc/passwd",
    "..\\..\\sim.env",
    "....//....//sim.env",
    "%00",
    "link.env",
    *SECRET_NAMES,
]
HOSTS = ["evil.example", "evil.example:{port}", "127.0.0.1.evil.example:{port}", "localhost.evil.example"]
ORIGINS = [
    {"Origin": "http://evil.example"},
    {"Origin": "null"},
    {"Origin": None, "Referer": "http://evil.example/page"},
    {"Origin": None, "Sec-Fetch-Site": "cross-site"},
    {"Origin": "http://127.0.0.1:{port}.evil.example"},
]
BODIES = [
    ("{", "application/json"),
    ("[]", "application/json"),
    ('"on"', "application/json"),
    ("null", "application/json"),
    ("1", "application/json"),
    ("[" * 100_000 + "]" * 100_000, "application/json"),
    ("{" + '"k":1,' * 300_000 + '"z":1}', "application/json"),
    ("\xff\xfe\x00junk", "application/json"),
    ('{"on": true, "frames": 5, "confirm": true}', "text/plain"),
    ('{"on": true, "frames": 5}', "application/x-www-form-urlencoded"),
    ('--b\r\nContent-Disposition: form-data; name="on"\r\n\r\ntrue\r\n--b--\r\n', "multipart/form-data; boundary=b"),
]
REPEAT_CANDIDATES = [
    "1",
    "2",
    "OK",
    "ACTION",
    "TOLERANCE",
    "cam1",
    "cam2",
    "2026-01-01",
    "2026-01-02",
    "30d",
    "60d",
    "/",
    "/history",
    "daily",
    "ann",
    "phil",
    "0",
]
OPEN = ("/login", "/static/")
CLIENTS = 50
SECURITY_HEADERS = ("content-security-policy", "x-content-type-options", "referrer-policy")


@dataclass
class Verdict:
    what: str
    traceback: bool = False
    hang: bool = False
    false_ok: bool = False
    damaged: bool = False
    other: bool = False
    security: bool = False
    why: str = ""

    def flag(self, kind: str, why: str) -> None:
        setattr(self, kind, True)
        self.why = f"{self.why}; {why}" if self.why else why

    @property
    def passed(self) -> bool:
        return not (self.traceback or self.hang or self.false_ok or self.damaged or self.other or self.security)


@dataclass
class Case:
    family: str
    ep: Endpoint
    who: Who
    path: str
    headers: dict | None = None
    body: bytes | None = None
    ctype: str | None = None
    script: bool = False
    foreign: bool = False  # from elsewhere: host, origin, token, anonymous
    must_refuse: bool = False  # a 2xx is a false OK (or, foreign, a security finding), as is any change
    taken: str = ""  # a bad number in a body: a false OK if it shows up taken (answer, action log)
    note: str = ""

    @property
    def what(self) -> str:
        return f"[{self.family}] {self.ep.method} {self.path[:120]} as {self.who.name}" + (
            f" ({self.note})" if self.note else ""
        )


# -- building requests ---------------------------------------------------------------------------


def _static_file() -> str:
    from vts_hw.console import app

    files = sorted(p.name for p in (Path(app.__file__).parent / "static").iterdir() if p.is_file())
    return files[0] if files else "x"


def default(ep: Endpoint, slot: str, kind: str) -> str:
    """A harmless good value for a path slot (an id of the store's run, a camera of the rig)."""
    if kind == "int" or slot in ("run", "artifact", "n", "id"):
        return "1"
    if slot == "camera":
        return "cam1"
    if slot == "scan":
        return SCAN
    if kind == "path":
        return "manifest.json" if ep.path.startswith("/scan/files") else _static_file()
    return "1" if slot == "alert" else "index.html"


def build(
    ep: Endpoint, path_values: dict | None = None, query: list[tuple[str, str]] | None = None, raw: bool = False
) -> str:
    """The request path of ``ep`` with its path slots filled (``path_values`` as given when ``raw``,
    else percent-encoded) and the query."""
    out = ep.path
    for slot, kind in ep.params.items():
        v = (path_values or {}).get(slot)
        v = default(ep, slot, kind) if v is None else (v if raw else quote(v, safe=""))
        out = out.replace("{" + slot + (":" + kind if kind in ("int", "path") else "") + "}", v)
    if query:
        out += "?" + "&".join(f"{quote(k)}={quote(v, safe='')}" for k, v in query)
    return out


def json_body(key: str, value: str, number: bool) -> bytes:
    if number:
        return ("{" + json.dumps(key) + ": " + JSON_NUMBER.get(value, value) + "}").encode()
    return json.dumps({key: value}).encode()


def form_body(ep: Endpoint, key: str, value: str) -> bytes:
    fields = {k: "x" for k in ep.form}
    fields[key] = value
    return "&".join(f"{quote(k)}={quote(v, safe='')}" for k, v in fields.items()).encode()


#: make test's share of the families (without --full): each console the families that need it, so that
#: every family meets every endpoint once (the Host, Origin and token checks on the console without
#: users, which DNS rebinding and other sites aim at; the rest as each role and as nobody)
SUBSET = {
    False: {"host", "origin", "token", "bodies"},
    True: {"anonymous", "script", "numbers", "traversal", "repeated", "headers", "many clients"},
}
REPEATED_SUBSET = 3  # endpoints with query slots given a repeated one (their first slot), without --full


def families(ep: Endpoint, who: Who, users: bool, full: bool, port: int):
    """The cases of one endpoint as ``who`` (without ``full``: SUBSET's families, first values)."""
    for case in _families(ep, who, users, full, port):
        if full or case.family in SUBSET[users]:
            yield case


def _families(ep: Endpoint, who: Who, users: bool, full: bool, port: int):
    pick = (lambda xs: xs) if full else (lambda xs: xs[:1])
    post = ep.method != "GET"
    anon = users and not who.cookie
    if anon:
        closed = not ep.path.startswith(OPEN)
        yield Case("anonymous", ep, who, build(ep), foreign=closed, must_refuse=closed)
        if not full:
            return
    for h in pick(HOSTS):
        yield Case(
            "host",
            ep,
            who,
            build(ep),
            headers={"Host": h.format(port=port)},
            foreign=True,
            must_refuse=True,
            note=f"Host {h.format(port=port)}",
        )
    if post:
        for o in pick(ORIGINS):
            hs = {k: (v.format(port=port) if v else v) for k, v in o.items()}
            yield Case(
                "origin",
                ep,
                who,
                build(ep),
                headers=hs,
                foreign=True,
                must_refuse=True,
                note=", ".join(f"{k}: {v}" for k, v in hs.items()),
            )
        for what, tok in pick(
            [
                ("no token", None),
                ("a wrong token", "not-the-token"),
                ("a token of bytes beyond ASCII", "\xe9t\xe9\xff"),  # (a TypeError, a 500, once)
                ("another session's token", who.extra.get("other_token")),
            ]
        ):
            if what.startswith("another") and not tok:
                continue
            yield Case(
                "token", ep, who, build(ep), headers={"X-Console-Token": tok}, foreign=True, must_refuse=True, note=what
            )
    slots = (
        [("path", s, k) for s, k in ep.params.items()]
        + [("query", q, "str") for q in ep.query]
        + ([("body", b, "str") for b in ep.body] + [("form", f, "str") for f in ep.form] if post else [])
    )
    for where, slot, kind in slots:
        for s in pick(SCRIPTS):
            yield _slot_case("script", ep, who, where, slot, s, script=True)
        for n in pick(NUMBERS):
            yield _slot_case("numbers", ep, who, where, slot, n, number=True)
        if where == "path" and kind != "int":
            for t in TRAVERSAL if full else TRAVERSAL[:3] + ["sim.env"]:
                yield Case("traversal", ep, who, build(ep, {slot: t}, raw=True), note=f"{slot}={t}")
    if post and (ep.reads_body or full):
        for b, ct in pick(BODIES) if full else BODIES[:1] + BODIES[5:6]:
            yield Case(
                "bodies",
                ep,
                who,
                build(ep),
                body=b.encode("utf-8", "surrogateescape"),
                ctype=ct,
                must_refuse=ep.reads_body,
                note=f"{ct}: {b[:24]!r}{'...' if len(b) > 24 else ''} ({len(b)} B)",
            )


def _slot_case(family, ep, who, where, slot, value, script=False, number=False) -> Case:
    note = f"{where} {slot}={value}"
    if where == "path":
        return Case(family, ep, who, build(ep, {slot: value}), script=script, note=note)
    if where == "query":
        return Case(family, ep, who, build(ep, query=[(slot, value)]), script=script, note=note)
    if where == "form":
        return Case(
            family,
            ep,
            who,
            build(ep),
            body=form_body(ep, slot, value),
            ctype="application/x-www-form-urlencoded",
            script=script,
            note=note,
        )
    return Case(
        family,
        ep,
        who,
        build(ep),
        body=json_body(slot, value, number),
        script=script,
        taken=value if number else "",
        note=note,
    )


# -- judging ---------------------------------------------------------------------------------------


class Judge:
    """Sends cases to one console and judges them (see the module docstring)."""

    def __init__(
        self, room: PlantedRig, console: Console, who_all: list[Who], settle_as: Who, reader: Who | None = None
    ):
        self.room, self.console, self.all, self.settle_as = room, console, who_all, settle_as
        #: who reads the state: a session no case sends with (a case may end the others')
        self.reader = reader or settle_as
        self.cams = list(room.cameras)
        self.scans_dir = console.scans_dir

    def state(self) -> dict:
        c, w = self.console, self.reader
        if w.cookie and (c.send("GET", "/session", who=w) or Answer(0, {}, b"")).status != 200:
            login(c, w)
        out = {"led": {n: self.room.led(n) for n in self.cams}}
        for key, path, fields in (
            ("scan", "/scan/state", ("phase", "folder")),
            ("qa", "/qa/state", ("state", "version", "pushing")),
        ):
            a = c.send("GET", path, who=w)
            try:
                d = json.loads(a.body) if a is not None and a.status == 200 else {}
            except ValueError:
                d = {}
            out[key] = {f: d.get(f) for f in fields}
        for n in self.cams:
            a = c.send("GET", f"/aim/{n}", who=w)
            try:
                out[f"aim {n}"] = json.loads(a.body).get("on") if a is not None and a.status == 200 else None
            except ValueError:
                out[f"aim {n}"] = None
        out["scans"] = sorted(p.name for p in self.scans_dir.iterdir() if p.name.startswith("scan-"))
        rows = self.room.store_rows()
        out["actions"] = rows.pop("actions")
        out["store"] = rows
        out["sessions"] = {
            x.name: (c.send("GET", "/session", who=x) or Answer(0, {}, b"")).status for x in self.all if x.cookie
        }
        return out

    def judge(self, case: Case, ans: Answer | None, errs: str, before: dict | None, after: dict | None) -> Verdict:
        v = Verdict(case.what)
        if ans is None:
            v.flag("hang", f"no answer within {60:.0f} s")
            return v
        if ans.status == 0 and not (b"reset" in ans.body and self.console.proc.poll() is None):
            v.flag("other", ans.body.decode(errors="replace")[:160])  # (reset: refused before the body was read)
        if ans.status == 500 or "Traceback (most recent call last)" in errs or b"Traceback (most recent" in ans.body:
            last = [ln for ln in errs.strip().splitlines() if ln.strip()][-1:] or [""]
            v.flag("traceback", f"HTTP {ans.status}; {last[0][:160]}")
        blob = ans.body + "".join(f"{k}: {val}\n" for k, val in ans.headers.items()).encode()
        for name, secret in self.room.secrets.items():
            if secret and secret in blob:
                v.flag("security", f"the answer holds {name}")
        for x in self.all:
            if x.cookie and x.cookie.encode() in ans.body:
                v.flag("security", f"the answer holds {x.name}'s session key")
        loc = ans.header("location")
        off_site = "://" in loc and not loc.split("://", 1)[1].startswith(self.console.host)
        if loc and (loc.startswith("//") or off_site):
            v.flag("security", f"redirected off the console: {loc}")
        if case.script and any(r.encode() in ans.body for r in RAW_SCRIPT):
            ctype = ans.header("content-type")
            sniff = "nosniff" not in ans.header("x-content-type-options").lower()
            if "html" in ctype or sniff:
                v.flag(
                    "security",
                    f"the script came back unescaped ({ctype or 'no content type'}, "
                    f"{'no nosniff' if sniff else 'nosniff'})",
                )
        ok = 200 <= ans.status < 300 or (300 <= ans.status < 400 and "/login" not in loc)
        if case.must_refuse and ok:
            kind = "security" if case.foreign else "false_ok"
            v.flag(kind, f"answered {ans.status}: {ans.body[:100].decode(errors='replace')!r}")
        if before is not None and after is not None:
            changed = [k for k in before if k not in ("actions", "sessions") and before[k] != after[k]]
            lost = [w for w, s in before["sessions"].items() if s == 200 and after["sessions"].get(w) != 200]
            if lost and not (case.ep.path == "/logout" and not case.foreign and case.who.name in lost):
                changed.append(f"{', '.join(lost)}'s session ended")
            new = [a for a in after["actions"] if a not in before["actions"]]
            claims = [a for a in new if not any(w in a[2].lower() for w in ("refused", "login", "logged"))]
            strict = case.must_refuse or case.foreign
            if changed and strict:
                what = "; ".join(f"{k}: {before.get(k)} -> {after.get(k)}" if k in before else k for k in changed)
                v.flag("security" if case.foreign else "false_ok", f"changed {what[:300]}")
            if claims and strict:
                v.flag(
                    "security" if case.foreign else "false_ok",
                    f"the action log says {', '.join(repr(a[2]) for a in claims)} (HTTP {ans.status})",
                )
            if case.taken and 200 <= ans.status < 300:
                seen = ans.body.decode(errors="replace") + " ".join(a[3] or "" for a in new)
                if any(t in seen for t in TAKEN.get(case.taken, [case.taken])):
                    v.flag(
                        "false_ok",
                        f"{case.note} taken (HTTP {ans.status}): "
                        f"{[a[2] + ' ' + (a[3] or '') for a in new][:2] or ans.body[:100]}",
                    )
        return v

    def run(self, case: Case) -> Verdict:
        post = case.ep.method != "GET"
        before = self.state() if post else None
        self.console.new_errors()
        ans = self.console.send(
            case.ep.method,
            case.path,
            who=case.who,
            headers=case.headers,
            body=case.body,
            ctype=case.ctype,
            stream=case.ep.stream,
        )
        time.sleep(0.05 if post else 0)  # (an answer's log line written before it: a margin only)
        errs = self.console.new_errors()
        after = self.state() if post else None
        v = self.judge(case, ans, errs, before, after)
        if post:
            self.settle(before, after)
        return v

    def settle(self, before: dict, after: dict) -> None:
        """Undo what a case changed (so the next is judged on the same room): a scan stopped, a QA
        job waited for, LEDs and aim checks switched back, sessions logged in again."""
        c, w = self.console, self.settle_as
        for x in self.all:
            if x.cookie and after["sessions"].get(x.name) != 200:
                login(c, x)
        if after["scan"].get("phase") not in (None, "idle", "stopped", before["scan"].get("phase")):
            c.send("POST", "/scan/stop", who=w)
            _until(lambda: self.state()["scan"].get("phase") in ("idle", "stopped", None), 120)
        if after["qa"].get("state") == "running" or after["qa"].get("pushing"):
            _until(lambda: self.state()["qa"].get("state") != "running", 300)
        for n in self.cams:
            if before["led"][n] is not None and after["led"][n] != before["led"][n]:
                c.send("POST", f"/camera/{n}/led", who=w, body=json.dumps({"on": before["led"][n]}).encode())
            if after.get(f"aim {n}") and not before.get(f"aim {n}"):
                c.send("POST", f"/aim/{n}", who=w, body=b'{"on": false}')


def _until(check, timeout: float) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if check():
            return True
        time.sleep(0.5)
    return False


def login(console: Console, who: Who) -> None:
    """Log ``who`` in through the form, as a browser does; its cookie and its pages' token."""
    shown = console.send("GET", "/login")  # the form first, as a browser: its token and its cookie
    m = re.search(rb'name="csrf_token" value="([^"]+)"', shown.body if shown is not None else b"")
    if not m:
        raise RuntimeError(f"no login form for {who.name}: {None if shown is None else shown.status}")
    form_cookie = shown.header("set-cookie").split(";", 1)[0]
    a = console.send(
        "POST",
        "/login",
        body=f"name={who.name}&password={quote(who.password)}&next=/&csrf_token={m.group(1).decode()}".encode(),
        ctype="application/x-www-form-urlencoded",
        headers={"Cookie": form_cookie},
    )
    if a is None or a.status != 303 or f"{console.cookie_name}=" not in a.header("set-cookie"):
        raise RuntimeError(f"{who.name} could not log in: {None if a is None else (a.status, a.body[:200])}")
    who.cookie = a.header("set-cookie").split(f"{console.cookie_name}=", 1)[1].split(";", 1)[0]
    who.token = page_token(console, who)


def page_token(console: Console, who: Who) -> str:
    a = console.send("GET", "/", who=who)
    m = re.search(rb'name="console-token" content="([^"]+)"', a.body if a is not None else b"")
    if not m:
        raise RuntimeError(f"no page token on the Room page for {who.name}: {None if a is None else a.status}")
    return m.group(1).decode()


# -- the families that are not one request ---------------------------------------------------------


def repeated(judge: Judge, eps: list[Endpoint], who_of, full: bool) -> list[Verdict]:
    """Each query slot of each GET endpoint given twice, with two values it accepts alone."""
    out = []
    c = judge.console
    todo = [e for e in eps if e.method == "GET" and e.query and not e.stream]
    for i, ep in enumerate(todo if full else todo[:REPEATED_SUBSET]):
        who = who_of(i)
        for slot in ep.query if full else ep.query[:1]:
            good = []
            for cand in REPEAT_CANDIDATES if full else REPEAT_CANDIDATES[:12]:
                a = c.send("GET", build(ep, query=[(slot, cand)]), who=who)
                if a is not None and a.status == 200:
                    good.append((cand, a.body))
                    if len(good) == 2:
                        break
            v = Verdict(f"[repeated] GET {ep.path}?{slot}=..&{slot}=.. as {who.name}")
            if len(good) < 2:
                v.why = f"fewer than two values of {slot} accepted alone: nothing to repeat"
                out.append(v)
                continue
            (a1, _), (a2, _) = good
            c.new_errors()
            ans = c.send("GET", build(ep, query=[(slot, a1), (slot, a2)]), who=who)
            v = judge.judge(
                Case("repeated", ep, who, build(ep, query=[(slot, a1), (slot, a2)]), note=f"{slot}={a1}&{slot}={a2}"),
                ans,
                c.new_errors(),
                None,
                None,
            )
            if ans is not None and ans.status == 200:
                v.flag("other", f"?{slot}={a1}&{slot}={a2} answered 200: one of them taken silently")
            out.append(v)
    return out


def header_cases(judge: Judge, eps: list[Endpoint], who: Who) -> list[Verdict]:
    """Every page (an HTML answer to a GET) carries the usual security headers."""
    out = []
    for ep in eps:
        if ep.method != "GET" or ep.stream or ep.params:
            continue
        a = judge.console.send("GET", build(ep), who=who)
        v = Verdict(f"[headers] GET {ep.path} as {who.name}")
        if a is None:
            v.flag("hang", "no answer")
        elif "html" in a.header("content-type"):
            missing = [h for h in SECURITY_HEADERS if not a.header(h)]
            csp = a.header("content-security-policy")
            if csp and "frame-ancestors" not in csp:
                missing.append("frame-ancestors in the CSP")
            if "nosniff" not in a.header("x-content-type-options").lower() and "x-content-type-options" not in missing:
                missing.append("nosniff")
            if missing:
                v.flag("security", f"a page without {', '.join(missing)}")
        out.append(v)
    return out


def many_clients(judge: Judge, eps: list[Endpoint], who: Who) -> Verdict:
    """CLIENTS event streams held open and CLIENTS requests at once: every request answered (< 500),
    and, once the streams are closed, the cameras' streams and the console's sockets let go of."""
    import socket

    c, v = judge.console, Verdict(f"[many clients] {CLIENTS} event streams + {CLIENTS} requests at once as {who.name}")
    streams = [e for e in eps if e.stream]
    base_streams, base_fds = judge.room.streams(), _fds(c.proc.pid)
    held: list[socket.socket] = []
    for i in range(CLIENTS):
        ep = streams[i % len(streams)]
        try:
            s = socket.create_connection(("127.0.0.1", c.port), timeout=60)
            s.sendall(
                (
                    f"GET {build(ep)} HTTP/1.1\r\nHost: {c.host}\r\nAccept: text/event-stream\r\n"
                    + (f"Cookie: {c.cookie_name}={who.cookie}\r\n" if who.cookie else "")
                    + "\r\n"
                ).encode()
            )
            held.append(s)
        except OSError as exc:
            v.flag("other", f"stream {i} not opened: {exc}")
    answers: list = [None] * CLIENTS
    gets = [e for e in eps if e.method == "GET" and not e.stream]

    def ask(i):
        answers[i] = c.send("GET", build(gets[i % len(gets)]), who=who, deadline=120)

    threads = [threading.Thread(target=ask, args=(i,)) for i in range(CLIENTS)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    bad = [
        (gets[i % len(gets)].path, a.status if a else None)
        for i, a in enumerate(answers)
        if a is None or a.status == 500
    ]
    if bad:
        v.flag(
            "hang" if any(s is None for _, s in bad) else "traceback",
            f"{len(bad)} of {CLIENTS} requests unanswered or failed while {len(held)} streams were open: {bad[:3]}",
        )
    opened = [s for s in held if _first_bytes(s)]
    if len(opened) < len(held):
        v.flag("other", f"{len(held) - len(opened)} of {len(held)} event streams never started")
    for s in held:
        s.close()
    if not _until(lambda: judge.room.streams() <= base_streams, 120):
        v.flag(
            "other",
            f"the cameras still serve {judge.room.streams()} streams (before: {base_streams}) "
            "2 min after every page closed",
        )
    if not _until(lambda: _fds(c.proc.pid) <= base_fds + 8, 120):
        v.flag(
            "other",
            f"the console holds {_fds(c.proc.pid)} files/sockets (before: {base_fds}) 2 min after the clients closed",
        )
    a = c.send("GET", "/api/room", who=who)
    if a is None or a.status >= 500:
        v.flag("hang" if a is None else "traceback", "the console no longer answers /api/room after the crowd")
    return v


def _first_bytes(s) -> bool:
    try:
        s.settimeout(60)
        return bool(s.recv(1024))
    except OSError:
        return False


def _fds(pid: int) -> int:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return 0


# -- the sweep ---------------------------------------------------------------------------------------


def sweep(root: Path, full: bool = False, log=print) -> list[Verdict]:
    t0 = time.monotonic()
    room = PlantedRig(root)
    log(f"-- the room set up in {time.monotonic() - t0:.1f} s")
    out: list[Verdict] = []
    eps = surface()
    try:
        # without users: the person at this machine, the console in the rig's folder (scans: '.')
        consoles = [("no users", [], room.sim), ("users", ["--login", "--scans-dir", str(room.scans)], room.sim)]
        for label, args, cwd in consoles:
            try:
                c = Console(room, args, cwd, label)
            except RuntimeError as exc:
                if label == "no users":  # refused to serve its own folder as scans: as told, then
                    out.append(Verdict(f"[start] vts console in a folder of secrets (refused: {str(exc)[:120]})"))
                    c = Console(room, ["--scans-dir", str(room.scans)], cwd, label)
                else:
                    raise
            try:
                out += _one_console(room, c, eps[label], label == "users", full, log)
            finally:
                code, tail = c.stop()
                v = Verdict(f"[stop] vts console ({label}) stopped with Ctrl-C")
                if code != 0:
                    v.flag("hang" if code is None else "other", f"exit {code}: {tail.strip()[-200:]}")
                if "Traceback (most recent call last)" in c.log.read_text(errors="replace")[-20000:] and not any(
                    x.traceback for x in out
                ):
                    v.flag("traceback", "a traceback on the console's stderr no case accounted for")
                out.append(v)
    finally:
        room.close()
    return out


def _one_console(room: PlantedRig, c: Console, eps: list[Endpoint], users: bool, full: bool, log) -> list[Verdict]:
    if users:
        whos = [Who("anon")] + [Who(n, password=PASSWORDS[n][1]) for n in ("ann", "phil")]
        for w in whos[1:]:
            login(c, w)
        whos[1].extra["other_token"], whos[2].extra["other_token"] = whos[2].token, whos[1].token
        settle_as = whos[2]
        carl = Who("carl", password=PASSWORDS["carl"][1])
        login(c, carl)  # the state's reader
    else:
        local = Who("local")
        local.token = page_token(c, local)
        whos, settle_as = [local], local
    judge = Judge(room, c, whos, settle_as, carl if users else None)
    out, spent = [], {}
    for i, ep in enumerate(eps):
        ids = whos if full else [whos[0], whos[1 + i % (len(whos) - 1)]] if users else whos
        for who in ids:
            for case in families(ep, who, users, full, c.port):
                t0 = time.monotonic()
                v = judge.run(case)
                out.append(v)
                dt = time.monotonic() - t0
                spent[case.family + (" POST" if case.ep.method != "GET" else "")] = (
                    spent.get(case.family + (" POST" if case.ep.method != "GET" else ""), 0.0) + dt
                )
                if not v.passed or dt > 2:
                    log(f"  {'FAILED' if not v.passed else 'ok'} ({dt:.1f} s) {v.what}: {v.why}")
    active = [w for w in whos if w.cookie or not users]
    log(
        f"-- {c.label}: {len(out)} cases sent; seconds per family: "
        f"{', '.join(f'{k} {v:.1f}' for k, v in sorted(spent.items(), key=lambda x: -x[1]))}"
    )
    if not full and not users:  # (SUBSET: these on the console with users)
        return out
    t0 = time.monotonic()
    out += repeated(judge, eps, lambda i: active[i % len(active)], full)
    log(f"-- repeated: {time.monotonic() - t0:.1f} s")
    out += header_cases(judge, eps, active[-1])
    if users:
        out += header_cases(judge, [e for e in eps if e.path.startswith("/login")], Who("anon"))
        login(c, Who("carl", password=PASSWORDS["carl"][1]))  # the login form's own user is sound afterwards
    t0 = time.monotonic()
    out.append(many_clients(judge, eps, active[0]))
    log(f"-- many clients: {time.monotonic() - t0:.1f} s")
    return out


def main() -> int:
    import argparse

    ap = argparse.ArgumentParser(description="The class web of bench/bad_inputs.py: prints JSON verdicts")
    ap.add_argument("root")
    ap.add_argument("--full", action="store_true")
    ap.add_argument("--show", action="store_true")
    a = ap.parse_args()
    root = Path(a.root)
    root.mkdir(parents=True, exist_ok=True)
    log = (lambda s: print(s, file=sys.stderr, flush=True)) if a.show else (lambda s: None)
    out = sweep(root, a.full, log)
    print(json.dumps([asdict(v) for v in out]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
