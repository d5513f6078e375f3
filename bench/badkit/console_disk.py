"""The class "console on a full disk" of bench/bad_inputs.py (issue 32 §1 and §5): each action of
the console's pages (a Scan-page scan, a drift baseline set, a Daily QA, a push to QATrack+, an
LED switched) while what it writes is on a full disk: the scans folder, or the results store (a
small tmpfs of the case's own, badkit/full_disk.py's, filled once the console serves its page, as
a disk fills up while it runs).

The case's command is `vts console` (forked as every case is, on badkit/full_disk's simulated rig,
with SIGINT left as it is: Ctrl-C stops it); while it runs, the person at the console asks for
the action from its page (with the page's token) and waits for it to end (its job's state, read
back), then presses Ctrl-C. Judged afterwards:

* an honest answer: a 2xx only for an action that was done; a job that could not write ends in a
  state that says it failed (its state and error), never ``done``; no 500, no traceback;
* a truthful action log (the History page's "Who did what"): no entry saying it was done (a
  scan that could not start, "baseline set" for a baseline not stored);
* nothing empty left on the disk (no empty scan folder, no empty or temporary file, every file
  there whole: full_disk.half_files);
* the console ends on Ctrl-C (exit 0).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import time
from pathlib import Path

from badkit import full_disk
from badkit.classes import Case, Verdict, common
from badkit.forked import fork_vts
from badkit.signals import _http, listening_port

CLASS = "console full disk"
#: what an entry of the action log says was done
DONE_WORDS = ("baseline set", "scan started", "pushed", "push to qatrack")
FAILED = re.compile(r"no space|disk (is )?full|could not|cannot|failed|error|refused|not (stored|written|saved)", re.I)


def _token(port: int, deadline: float, pid: int) -> str:
    while time.monotonic() < deadline and not _gone(pid):
        try:
            status, body = _http(port, "GET", "/")
            m = re.search(rb'name="console-token" content="([^"]+)"', body)
            if status == 200 and m:
                return m.group(1).decode()
        except OSError:
            pass
        time.sleep(0.3)
    return ""


def _job_end(port: int, path: str, busy, deadline: float) -> dict:
    last: dict = {}
    while time.monotonic() < deadline:
        try:
            status, body = _http(port, "GET", path)
            last = json.loads(body) if status == 200 else {"http": status}
        except (OSError, ValueError):
            last = {"unreadable": True}
        if not busy(last):
            return last
        time.sleep(0.5)
    return {**last, "timed out": True}


ACTIONS = {
    # what: (the request, where the job's state is read, whether it is still busy, what is on the disk)
    "Scan-page scan": (
        "/scan/start",
        b'{"duration_s": 4}',
        "/scan/state",
        lambda s: s.get("phase") in ("starting", "reference", "recording", "stopping", "running"),
        "scans",
    ),
    "drift baseline set": (
        "/qa/baseline",
        b'{"confirm": true, "frames": 3}',
        "/qa/state",
        lambda s: (s.get("job") or s).get("state") == "running",
        "store",
    ),
    "Daily QA": (
        "/qa/run",
        b'{"frames": 3}',
        "/qa/state",
        lambda s: (s.get("job") or s).get("state") == "running",
        "store",
    ),
    "push to QATrack+": ("/qa/push", b"{}", "/qa/state", lambda s: (s.get("job") or s).get("pushing") is True, "store"),
    "LED off": ("/camera/cam1/led", b'{"on": false}', "/api/room", lambda s: False, "store"),
}
SUBSET = ("Scan-page scan", "drift baseline set")
#: bytes left free: SQLite can still open the store to read (its 32 kB -shm) but not keep what it is given
LEAVE = 40_000


def _whats(page: str) -> list[str]:
    """The "What" of each row of the History page's "Who did what" (lower case)."""
    import html

    out = []
    for row in re.findall(r"<tr.*?</tr>", page, re.S):
        cells = [
            html.unescape(re.sub(r"<[^>]+>", " ", c)).strip().lower() for c in re.findall(r"<td.*?</td>", row, re.S)
        ]
        if len(cells) >= 4:
            out.append(" ".join(cells[3].split()))
    return out


def _gone(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] in ("Z", "X")
    except OSError:
        return True


def _during(holder: dict, action: str):
    path, body, state_path, busy, _ = ACTIONS[action]

    def during(pid: int) -> None:
        port = listening_port(pid, time.monotonic() + 120) or 0
        token = _token(port, time.monotonic() + 120, pid) if port else ""
        if not token:
            holder["said"] = "the console never served its page"
            holder["ended"] = _gone(pid)
        else:
            try:
                full_disk._fill(holder["disk"], LEAVE)
                holder["answer"] = _http(port, "POST", path, body, token)
                time.sleep(0.5)
                holder["state"] = _job_end(port, state_path, busy, time.monotonic() + 180)
                status, page = _http(port, "GET", "/history/actions")
                holder["actions"] = page.decode(errors="replace") if status == 200 else f"(HTTP {status})"
            except OSError as exc:
                holder["said"] = f"the console stopped answering: {exc}"
        try:
            os.kill(pid, signal.SIGINT)
        except OSError:
            pass

    return during


def _judge(holder: dict, action: str):
    def judge(wd: Path, code, out, err) -> Verdict:
        if os.environ.get("BAD_INPUTS_DEBUG"):
            Path(os.environ["BAD_INPUTS_DEBUG"], f"console-disk-{action}.json").write_text(
                json.dumps(
                    {
                        **{k: (v if not isinstance(v, (bytes, tuple, Path)) else repr(v)) for k, v in holder.items()},
                        "code": code,
                        "err": err[-3000:],
                    }
                )
            )
        v = common(code, err)
        disk = wd / full_disk.DISK
        if v.hang or v.traceback:
            return v
        if holder.get("ended") and code in (2, 3) and (err.strip().splitlines() or [""])[-1].startswith("vts: "):
            return v  # it refused to serve on a store or folder it cannot write: one sentence
        if "said" in holder:
            return Verdict(other=True, why=holder["said"])
        status, body = holder.get("answer", (0, b""))
        state = holder.get("state", {})
        text = body.decode(errors="replace") + " " + json.dumps(state)
        if status == 500:
            return Verdict(traceback=True, why=f"HTTP 500: {body[:160]!r}")
        if 200 <= status < 300 and not FAILED.search(text):
            v.false_ok, v.why = True, f"HTTP {status} and the job ended {json.dumps(state)[:200]} on a full disk"
        failed = not (200 <= status < 300) or bool(FAILED.search(json.dumps(state)))
        told = [
            w
            for w in _whats(holder.get("actions", ""))
            if any(d in w for d in DONE_WORDS) and not re.search(r"\bnot\b|failed|refused", w)
        ]
        if told and failed:
            v.false_ok, v.why = True, f"the action log says {told} for an action that failed: {json.dumps(state)[:160]}"
        (disk / ".filler").unlink(missing_ok=True)  # (room to read the store: SQLite opens its -shm)
        half = [h for h in full_disk.half_files(disk) if not h.split(":")[0].endswith(("-wal", "-shm", "-journal"))]
        empty = [
            str(p.relative_to(disk))
            for p in disk.rglob("*")
            if p.is_dir() and p.name != "scans" and not any(p.iterdir())
        ]  # (the scans folder: ours)
        if half or empty:
            v.damaged, v.why = True, "; ".join(half + [f"{e}: an empty folder left" for e in empty])
        if code != 0 and v.passed:
            v.other, v.why = True, f"exit {code} on Ctrl-C: {(err.strip().splitlines() or [''])[-1][:160]}"
        return v

    return judge


def cases(root: Path, only: str | None = None, full: bool = False) -> list[Case]:
    """Each console action on a full disk (``full``: every action; else SUBSET); none without a tmpfs."""
    if full_disk.available():
        return []
    inp = full_disk.inputs(root)
    out = []
    for action in ACTIONS if full else SUBSET:
        if only and not ("console".startswith(only) or only.startswith("console")):
            continue
        holder: dict = {}
        where = ACTIONS[action][4]

        def make(wd: Path, holder=holder, where=where) -> list[str]:
            disk = wd / full_disk.DISK
            full_disk._mount(disk, 256 + inp.baseline_store().stat().st_size // 1024)
            scans = disk / "scans" if where == "scans" else wd / "scans"
            scans.mkdir(mode=0o700, parents=True, exist_ok=True)
            store = disk / "results.sqlite" if where == "store" else wd / "results.sqlite"
            shutil.copy(inp.baseline_store(), store)
            holder["disk"] = disk  # filled once the console serves (as a disk fills up in use)
            return [
                "--store",
                f"sqlite:///{store}",
                "console",
                "--config",
                str(inp.config),
                "--port",
                "0",
                "--scans-dir",
                str(scans),
            ]

        def run(argv, timeout, wd, holder=holder, action=action):
            return fork_vts(argv, timeout, wd, during=_during(holder, action))

        out.append(
            Case(
                CLASS,
                f"console: {action}, its {where} on a full disk",
                make,
                _judge(holder, action),
                extra={"run": run},
            )
        )
    return out


__all__ = ["CLASS", "cases"]
