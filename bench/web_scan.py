#!/usr/bin/env python3
"""A web scanner written by others against the room console (issue 32 §6): Debian's ``wapiti``
(``apt install wapiti``; bookworm main) against `vts console` on a simulated rig, with the secrets
planted where a careless server would serve them (bench/badkit/web_peer.py's Room: the rig's
passwords and QATrack+ token in ``sim.env``, the users' hashes in ``results.sqlite``, marker files
in the scans folder, a scan folder and the store's folder).

The console is scanned twice: as the person at the machine (no users: the console a page in the
operator's browser can reach, and DNS rebinding aims at), and with users, logged in as a
physicist (its session cookie and page token given to wapiti, the logout left out so the scan
keeps its session). Wapiti crawls the pages and forms it finds and starts from every GET route of
the console (read from its code, bench/badkit/web_surface.py: the routes the pages' scripts call
are no links a crawler finds); its modules that need nothing from outside this machine run (not
``ssrf``: it calls an endpoint on the internet; not ``nikto``/``wapp``: they download databases;
not ``brute_login_form``: it would lock the users out).

Printed: per scan, the findings of each module (vulnerabilities and anomalies, each with its
path and parameter), and the count; the exit status is 0 when there are none. Takes minutes:
not in make test (tests/test_bad_inputs.py sweeps the same surface in seconds).

    .venv/bin/python bench/web_scan.py                 # both scans
    .venv/bin/python bench/web_scan.py --minutes 3     # each scan's time limit
    .venv/bin/python bench/web_scan.py --json          # the figures as JSON
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from badkit.web import build, login, page_token  # noqa: E402
from badkit.web_peer import PASSWORDS, Console, Room, Who  # noqa: E402
from badkit.web_surface import surface  # noqa: E402

#: wapiti 3.0.4 (bookworm) compiles each -x pattern as 'PATTERN\Z(?ms)', which Python 3.11 refuses (global
#: flags not at the start): run it with that one function mended, flags first (same meaning), through
#: the system's Python, whose package it is
WAPITI = ["/usr/bin/python3", "-c", """
import re, sys
import wapitiCore.net.crawler as crawler
def wildcard_translate(pattern):
    return re.compile("(?ms)" + "".join(".*" if c == "*" else re.escape(c) for c in pattern) + r"\\Z")
crawler.wildcard_translate = wildcard_translate
from wapitiCore.main.wapiti import wapiti_main
sys.argv[0] = "wapiti"
sys.exit(wapiti_main())
"""]
MODULES = ["backup", "blindsql", "buster", "cookieflags", "crlf", "csp", "csrf", "exec", "file", "htaccess",
           "http_headers", "methods", "permanentxss", "redirect", "shellshock", "sql", "xss", "xxe"]


def scan(console: Console, who: Who | None, work: Path, minutes: float, label: str) -> dict:
    """One wapiti run against ``console`` (as ``who``, when it has a session); its JSON report."""
    base = f"http://{console.host}/"
    report = work / f"wapiti-{label}.json"
    attack_s = int(max(20, minutes * 60 / len(MODULES)))      # each module's share (wapiti's own limit)
    starts = sorted({build(e) for e in surface()["users" if who and who.cookie else "no users"]
                     if e.method == "GET" and not e.stream})
    cmd = [*WAPITI, "-u", base, "--scope", "folder", "-m", ",".join(MODULES), "--flush-session",
           "--store-session", str(work / f"session-{label}"), "--store-config", str(work / f"config-{label}"),
           "-f", "json", "-o", str(report), "--max-scan-time", str(int(minutes * 60)),
           "--max-attack-time", str(attack_s), "--no-bugreport", "-t", "30",
           "-x", f"{base}logout", "-x", f"{base}events", "-x", f"{base}qa/events", "-x", f"{base}scan/events",
           "-x", f"{base}aim/events", "--verify-ssl", "0"]
    for s in starts:
        cmd += ["-s", base + s.lstrip("/")]
    if who is not None and who.token:
        cmd += ["-H", f"X-Console-Token: {who.token}"]
    if who is not None and who.cookie:
        cookies = work / f"cookies-{label}.json"
        cookies.write_text(json.dumps({"127.0.0.1": {"/": {"vts_session": {
            "value": who.cookie, "version": 0, "expires": None, "secure": False, "port": None}}}}))
        cmd += ["-c", str(cookies)]
    t0 = time.monotonic()
    # (wapiti's limits are its crawl's and each module's: its report comes at the end, so wait them out)
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=minutes * 60 + 2 * attack_s * len(MODULES) + 300,
                       cwd=work)
    took = time.monotonic() - t0
    (work / f"wapiti-{label}.log").write_text(p.stdout + p.stderr)
    if not report.exists():
        raise RuntimeError(f"wapiti wrote no report (exit {p.returncode}; its output: {work}/wapiti-{label}.log): "
                           f"{(p.stderr or p.stdout)[-300:]}")
    r = json.loads(report.read_text())
    return {"label": label, "seconds": round(took), "report": r, "exit": p.returncode}


def findings(r: dict) -> dict[str, list[str]]:
    """Each category of wapiti's report with its findings (vulnerabilities and anomalies)."""
    out: dict[str, list[str]] = {}
    for kind in ("vulnerabilities", "anomalies"):
        for cat, items in (r.get(kind) or {}).items():
            for it in items or []:
                where = f"{it.get('method', '')} {it.get('path', '')}"
                out.setdefault(f"{kind[:-3] if kind == 'vulnerabilities' else 'anomaly'}: {cat}", []).append(
                    f"{where} {it.get('parameter', '')}: {it.get('info', '')}".strip())
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, default=5.0, help="each scan's time limit (default 5)")
    ap.add_argument("--json", action="store_true", help="the figures as JSON")
    ap.add_argument("--keep", action="store_true", help="keep the work folder (the reports) and say where")
    a = ap.parse_args()
    if not shutil.which("wapiti"):
        print("web_scan: wapiti is not installed (apt install wapiti)", file=sys.stderr)
        return 2
    work = Path(tempfile.mkdtemp(prefix="vts-web-scan-"))
    results = []
    room = Room(work / "room")
    try:
        for label, args in (("no users", []), ("users", ["--login", "--scans-dir", str(room.scans)])):
            c = Console(room, args, room.sim, label)
            res: dict = {"label": label, "seconds": 0, "report": {}}
            try:
                if args:
                    who = Who("phil", password=PASSWORDS["phil"][1])
                    login(c, who)
                else:
                    who = Who("local")
                    who.token = page_token(c, who)
                res = scan(c, who, work, a.minutes, label.replace(" ", "-"))
            finally:
                code, _ = c.stop()
                res["console"] = {"exit": code,
                                  "traceback": "Traceback (most recent call last)" in c.log.read_text(errors="replace")}
                results.append(res)
    finally:
        room.close()
    total = 0
    out = []
    for res in results:
        f = findings(res["report"])
        n = sum(len(v) for v in f.values())
        total += n
        out.append({"scan": res["label"], "seconds": res["seconds"], "findings": f, "count": n,
                    "console": res.get("console")})
    if a.json:
        print(json.dumps(out, indent=1))
    else:
        for o in out:
            print(f"wapiti against vts console ({o['scan']}): {o['count']} finding(s) in {o['seconds']} s; "
                  f"the console after it: exit {o['console']['exit']} on Ctrl-C, "
                  f"{'a traceback' if o['console']['traceback'] else 'no traceback'} on its stderr")
            print(f"  modules run: {', '.join(MODULES)}")
            for k, v in sorted(o["findings"].items()):      # a category: what one module reports
                print(f"  {k}: {len(v)}")
                for x in v:
                    print(f"    {x}")
        print(f"total: {total} finding(s)")
    if a.keep:
        print(f"(reports in {work})", file=sys.stderr)
    else:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if total == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
