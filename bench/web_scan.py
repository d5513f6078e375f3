#!/usr/bin/env python3
"""A web scanner written by others against the room console (issue 32 §6): Debian's ``wapiti``
(``apt install wapiti``; bookworm main) against `vts console` on a simulated rig, with the secrets
planted where a careless server would serve them (bench/badkit/web_peer.py's PlantedRig: the rig's
passwords and QATrack+ token in ``sim.env``, the users' hashes in ``results.sqlite``, marker files
in the scans folder, a scan folder and the store's folder).

The console is scanned three times: as the person at the machine (no users: the console a page in
the operator's browser can reach, and DNS rebinding aims at); with users, logged in as a
physicist (its session cookie and page token given to wapiti, the logout left out so the scan
keeps its session); and the same over HTTPS (a self-signed certificate), as it serves a LAN:
there its HSTS and its Secure, __Host- cookie are seen (on plain HTTP on 127.0.0.1 neither can
be: a browser ignores HSTS over HTTP, and the cookie must come back over it). Wapiti crawls the pages and forms it finds and starts from every GET route of
the console (read from its code, bench/badkit/web_surface.py: the routes the pages' scripts call
are no links a crawler finds); its modules that need nothing from outside this machine run (not
``ssrf``: it calls an endpoint on the internet; not ``nikto``/``wapp``: they download databases;
not ``brute_login_form``: it would lock the users out).

Printed: per scan, the findings of each module (vulnerabilities and anomalies, each with its
path and parameter; a module that does not end in its time is one), and the count; the exit
status is 0 when there are none. Wapiti crawls once; each module then runs on what was crawled. Takes minutes:
not in make test (tests/integration/test_bad_inputs.py sweeps the same surface in seconds).

    .venv/bin/python bench/web_scan.py                 # the three scans
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
from badkit.web_peer import PASSWORDS, Console, PlantedRig, Who  # noqa: E402
from badkit.web_surface import surface  # noqa: E402
from vts_hw.sim_devices.tls import self_signed  # noqa: E402

#: wapiti 3.0.4 (bookworm) compiles each -x pattern as 'PATTERN\Z(?ms)', which Python 3.11 refuses (global
#: flags not at the start): run it with that one function mended, flags first (same meaning), through
#: the system's Python, whose package it is
WAPITI = [
    "/usr/bin/python3",
    "-c",
    """
import re, sys
import wapitiCore.net.crawler as crawler
def wildcard_translate(pattern):
    return re.compile("(?ms)" + "".join(".*" if c == "*" else re.escape(c) for c in pattern) + r"\\Z")
crawler.wildcard_translate = wildcard_translate
from wapitiCore.main.wapiti import wapiti_main
sys.argv[0] = "wapiti"
sys.exit(wapiti_main())
""",
]
MODULES = [
    "backup",
    "blindsql",
    "buster",
    "cookieflags",
    "crlf",
    "csp",
    "csrf",
    "exec",
    "file",
    "htaccess",
    "http_headers",
    "methods",
    "permanentxss",
    "redirect",
    "shellshock",
    "sql",
    "xss",
    "xxe",
]


def scan(console: Console, who: Who | None, work: Path, minutes: float, label: str) -> dict:
    """Wapiti against ``console`` (as ``who``, when it has a session): one crawl, then each module in a
    run of its own on what was crawled (``--skip-crawl``), so that a module that does not end in its
    time is one finding and the others still report. {module: its JSON report, or None}."""
    base = f"{console.scheme}://{console.host}/"
    starts = sorted(
        {
            build(e)
            for e in surface()["users" if who and who.cookie else "no users"]
            if e.method == "GET" and not e.stream
        }
    )
    attack_s = int(max(20, minutes * 60 / len(MODULES)))  # each module's share (wapiti's own limit)
    common = [
        *WAPITI,
        "-u",
        base,
        "--scope",
        "folder",
        "--store-session",
        str(work / f"session-{label}"),
        "--store-config",
        str(work / f"config-{label}"),
        "-f",
        "json",
        "--no-bugreport",
        "-t",
        "30",
        "--verify-ssl",
        "0",
        "-v",
        "1",
        # never the logout (the session is the scan's), never an event stream (it has no end)
        "-x",
        f"{base}logout*",
        "-x",
        f"{base}events*",
        "-x",
        f"{base}*/events*",
    ]
    if who is not None and who.token:
        common += ["-H", f"X-Console-Token: {who.token}"]
    if who is not None and who.cookie:
        cookies = work / f"cookies-{label}.json"
        cookies.write_text(
            json.dumps(
                {
                    "127.0.0.1": {
                        "/": {
                            console.cookie_name: {
                                "value": who.cookie,
                                "version": 0,
                                "expires": None,
                                "secure": console.scheme == "https",
                                "port": None,
                            }
                        }
                    }
                }
            )
        )
        common += ["-c", str(cookies)]
    out: dict = {"label": label, "modules": {}, "seconds": 0}
    t0 = time.monotonic()
    for i, mod in enumerate(MODULES):
        report = work / f"wapiti-{label}-{mod}.json"
        cmd = [*common, "-m", mod, "-o", str(report), "--max-attack-time", str(attack_s)]
        if i == 0:  # the crawl, once: from the console's page and every GET route
            cmd += ["--flush-session", "--max-scan-time", str(int(minutes * 60))]
            for st in starts:
                cmd += ["-s", base + st.lstrip("/")]
        else:
            cmd += ["--skip-crawl", "--flush-attacks"]
        log = open(work / f"wapiti-{label}-{mod}.log", "w")
        try:
            p = subprocess.run(
                cmd,
                stdout=log,
                stderr=subprocess.STDOUT,
                text=True,
                cwd=work,
                timeout=(minutes * 60 if i == 0 else 0) + 4 * attack_s + 120,
            )
            out["modules"][mod] = (
                json.loads(report.read_text()) if report.exists() else {"error": f"no report (exit {p.returncode})"}
            )
        except subprocess.TimeoutExpired:
            limit = (minutes * 60 if i == 0 else 0) + 4 * attack_s + 120
            out["modules"][mod] = {"error": f"did not end within {limit} s"}
        finally:
            log.close()
    out["seconds"] = round(time.monotonic() - t0)
    return out


def findings(r: dict) -> dict[str, list[str]]:
    """Each category of one module's report with its findings (vulnerabilities and anomalies); a
    module that did not end, or wrote no report, is one finding."""
    out: dict[str, list[str]] = {}
    if "error" in r:  # the scanner's own trouble (a module past its time), said apart from the console's
        return {"scanner": [r["error"]]}
    for kind in ("vulnerabilities", "anomalies"):
        for cat, items in (r.get(kind) or {}).items():
            for it in items or []:
                where = f"{it.get('method', '')} {it.get('path', '')}"
                out.setdefault(f"{'vulnerability' if kind == 'vulnerabilities' else 'anomaly'}: {cat}", []).append(
                    f"{where} {it.get('parameter', '')}: {it.get('info', '')}".strip()
                )
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
    room = PlantedRig(work / "room")
    try:
        cert, key = self_signed(work)  # the console over HTTPS, as on a LAN (its HSTS, its Secure cookie)
        for label, args in (
            ("no users", []),
            ("users", ["--login", "--scans-dir", str(room.scans)]),
            # (a scans folder of its own: the scans before planted secrets in theirs, refused now)
            (
                "users over HTTPS",
                [
                    "--login",
                    "--scans-dir",
                    str(room.root / "scans-https"),
                    "--certfile",
                    str(cert),
                    "--keyfile",
                    str(key),
                ],
            ),
        ):
            c = Console(room, args, room.sim, label)
            res: dict = {"label": label, "seconds": 0, "modules": {}}
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
                res["console"] = {
                    "exit": code,
                    "traceback": "Traceback (most recent call last)" in c.log.read_text(errors="replace"),
                }
                results.append(res)
    finally:
        room.close()
    total = 0
    out = []
    for res in results:
        per = {mod: findings(r) for mod, r in res.get("modules", {}).items()}
        n = sum(len(v) for f in per.values() for k, v in f.items() if k != "scanner")
        total += n
        out.append(
            {"scan": res["label"], "seconds": res["seconds"], "modules": per, "count": n, "console": res.get("console")}
        )
    if a.json:
        print(json.dumps(out, indent=1))
    else:
        for o in out:
            unfinished = [m for m, f in o["modules"].items() if "scanner" in f]
            print(
                f"wapiti against vts console ({o['scan']}): {o['count']} finding(s) in {o['seconds']} s"
                + (f" (modules that did not end in their time: {', '.join(unfinished)})" if unfinished else "")
                + "; "
                f"the console after it: exit {o['console']['exit']} on Ctrl-C, "
                f"{'a traceback' if o['console']['traceback'] else 'no traceback'} on its stderr"
            )
            for mod, f in o["modules"].items():
                print(f"  {mod:<14} {sum(len(v) for v in f.values())}")
                for k, v in sorted(f.items()):
                    for x in v:
                        print(f"    {k}: {x}")
        print(f"total: {total} finding(s)")
    if a.keep:
        print(f"(reports in {work})", file=sys.stderr)
    else:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if total == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
