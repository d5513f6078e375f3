"""The class "SIGINT and SIGKILL to every long command" of bench/bad_inputs.py (issue 21, round 2).

Each long command runs in a forked child as a background job of a script would: with SIGINT
ignored at the start (a non-interactive shell's ``cmd &``). Once it is under way (its first
frames on disk, its workers started, or a few seconds), it gets SIGINT: it must end within
:data:`AFTER_SIGNAL_S` with exit 130 and ``interrupted``; or SIGKILL: then none of its processes
(workers, fork servers) may outlive it. Either way, what is on disk is judged afterwards:
every frame the index lists is whole in the .mjpeg (nothing recorded lost or torn), and a
SIGINT leaves a manifest that says ``interrupted``.

:func:`badkit.forked.fork_vts` is the runner (the sweep's own), with its hook before ``main``
(SIGINT ignored) and its hook while the command runs (the signal).
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from pathlib import Path

from badkit.classes import Case, Verdict, common
from badkit.forked import fork_vts

CLASS = "SIGINT and SIGKILL"
AFTER_SIGNAL_S = 30.0      # how long a command may take to stop after SIGINT
ORPHAN_WAIT_S = 10.0       # how long its processes may take to go after SIGKILL of it
VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def session_members(sid: int) -> list[int]:
    """Live processes of session ``sid`` (the child's own session: its workers, fork servers)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if fields[0] != "Z" and int(fields[3]) == sid:
            out.append(int(d.name))
    return out


def _descendants(pid: int) -> list[int]:
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                kids.setdefault(int((d / "stat").read_text().rsplit(")", 1)[1].split()[1]), []).append(int(d.name))
            except (OSError, IndexError, ValueError):
                pass
    out, todo = [], [pid]
    while todo:
        for k in kids.get(todo.pop(), []):
            out.append(k)
            todo.append(k)
    return out


def _ignore_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # as `cmd &` in a script starts it


class _Signaller:
    """``during``: wait until ``ready(wd, pid)`` (or ``wait_s``), then send ``signum``."""

    def __init__(self, wd: Path, signum: int, ready, wait_s: float):
        self.wd, self.signum, self.ready, self.wait_s = wd, signum, ready, wait_s
        self.sent_after: float | None = None
        self.ended_first = False
        self.left: list[int] = []

    def __call__(self, pid: int) -> None:
        t0 = time.monotonic()
        while time.monotonic() - t0 < self.wait_s:
            if self.ready(self.wd, pid):
                break
            if not Path(f"/proc/{pid}").exists() or _state(pid) == "Z":
                self.ended_first = True
                return
            time.sleep(0.05)
        self.sent_after = time.monotonic() - t0
        try:
            os.kill(pid, self.signum)
        except ProcessLookupError:
            self.ended_first = True
            return
        # what is left of it once it has ended (its pipes may be held open by orphans: look now)
        end = time.monotonic() + AFTER_SIGNAL_S
        while _state(pid) not in ("Z", "X") and time.monotonic() < end:
            time.sleep(0.05)
        end = time.monotonic() + ORPHAN_WAIT_S
        self.left = [p for p in session_members(pid) if p != pid]
        while self.left and time.monotonic() < end:
            time.sleep(0.2)
            self.left = [p for p in session_members(pid) if p != pid]
        for p in self.left:   # never leave them running
            try:
                os.kill(p, signal.SIGKILL)
            except OSError:
                pass


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "X"


def _recording_whole(folder: Path) -> str:
    """'' when every frame each index lists is whole in its .mjpeg, else what is wrong."""
    from vts_hw.recording.folder import read_index
    from vts_hw.recording.mjpeg import split_jpegs
    problems = []
    for idx in folder.glob("*.index.csv"):
        mj = folder / idx.name.replace(".index.csv", ".mjpeg")
        try:
            rows = read_index(idx, lenient=True)
        except Exception as exc:   # noqa: BLE001 -- judged, not raised
            problems.append(f"{idx.name}: {exc}")
            continue
        data = mj.read_bytes() if mj.exists() else b""
        whole = {(s.offset, s.length) for s in split_jpegs(data) if s.complete}
        bad = [r.frame for r in rows if (r.offset, r.length) not in whole]
        if bad:
            problems.append(f"{idx.name}: {len(bad)} indexed frame(s) not whole in {mj.name}")
    return "; ".join(problems)


def _frames_on_disk(wd: Path, pid: int) -> bool:
    return any(p.stat().st_size > 100_000 for p in wd.rglob("*.mjpeg"))


def _workers_up(wd: Path, pid: int) -> bool:
    return len(_descendants(pid)) >= 2


def _after(seconds: float):
    """A readiness test that is true ``seconds`` after it is first asked (a factory: one per case)."""
    def factory():
        t = {}

        def ready(wd, pid):
            t.setdefault("t0", time.monotonic())
            return time.monotonic() - t["t0"] >= seconds
        return ready
    return factory


def _always(test):
    return lambda: test


def _judge(kind: str, signaller: _Signaller, recording: str | None, ends=frozenset({130})):
    def judge(wd: Path, code, out, err) -> Verdict:
        left = signaller.left
        if signaller.ended_first:
            v = common(code, err)
            v.why = v.why or "ended before the signal (nothing to judge)"
            return v
        if kind == "SIGINT":
            v = common(code, err)
            if v.hang or v.traceback:
                pass
            elif code not in ends:
                v.other, v.why = True, (f"exit {code} after SIGINT, not {' or '.join(map(str, sorted(ends)))}: "
                                        f"{(err.strip().splitlines() or [''])[-1]}")
            else:
                v = Verdict()
                if code == 130 and "interrupted" not in err:
                    v.other, v.why = True, "exit 130 without saying 'interrupted'"
        else:
            v = Verdict() if code == -signal.SIGKILL else common(code, err)
        if left:
            v.other, v.why = True, f"{len(left)} process(es) left running after {kind} of the command"
        if recording:
            folder = wd / recording
            wrong = _recording_whole(folder) if folder.is_dir() else ""
            if wrong:
                v.damaged, v.why = True, wrong
            manifest = folder / "manifest.json"
            if kind == "SIGINT" and folder.is_dir() and manifest.exists():
                m = json.loads(manifest.read_text())
                said = {m.get("status"), (m.get("scan") or {}).get("stop_reason"), m.get("stop_reason")}
                if "interrupted" not in said:
                    v.other, v.why = True, f"the manifest says {m.get('status')!r} after SIGINT, not 'interrupted'"
        return v
    return judge


def _case(what: str, argv_of, kind: str, ready, wait_s: float, recording: str | None = None,
          ends=frozenset({130})) -> Case:
    signum = signal.SIGINT if kind == "SIGINT" else signal.SIGKILL
    holder: dict = {}

    def make(wd: Path) -> list[str]:
        holder["signaller"] = _Signaller(wd, signum, ready(), wait_s)
        return argv_of(wd)

    def run(argv, timeout, wd):
        s = holder["signaller"]

        return fork_vts(argv, min(timeout, AFTER_SIGNAL_S), wd, before=_ignore_sigint, during=s)

    def judge(wd, code, out, err):
        if os.environ.get("BAD_INPUTS_DEBUG"):
            Path(os.environ["BAD_INPUTS_DEBUG"], f"{kind}-{what}.err").write_text(err)
        return _judge(kind, holder["signaller"], recording, ends)(wd, code, out, err)
    return Case(CLASS, f"{kind} {what}", make, judge, extra={"run": run})


def cases(fx, only: str | None, peers) -> list[Case]:
    """Every long command, SIGINT and SIGKILL each. ``peers``: the running simulated rig and the
    recordings made for the sweep (slow_peers.Peers)."""
    ok = ["--config", str(peers.ok_rig)]
    rec = str(peers.recording)
    cams = str(peers.recording_cameras)
    # name: (argv, when it is under way, how long to wait for that, its recording folder, the
    # exits a SIGINT may end it with: Ctrl-C is how a scan or a stream without an end is ended)
    long = {
        "camera record": (lambda wd: ["camera", "record", "cam1", "cam2", "--seconds", "60", "-o", str(wd / "rec"), *ok],
                          _always(_frames_on_disk), 40, "rec", {130}),
        "scan start": (lambda wd: ["scan", "start", "--no-live", "--duration", "60", "-o", str(wd / "scan"), *ok],
                       _always(_frames_on_disk), 40, "scan", {0, 130}),
        "camera stream": (lambda wd: ["camera", "stream", "cam1", *ok], _after(3), 20, None, {0, 130}),
        "qa daily": (lambda wd: peers.with_baseline(wd, ["qa", "daily", "--frames", "50", *ok]), _after(3), 20, None,
                     {130}),
        "motion analyze": (lambda wd: ["motion", "analyze", rec, "--calibration", cams, *ok, "--workers", "2",
                                       "-o", str(wd / "r.html")], _always(_workers_up), 60, None, {130}),
        "recording process": (lambda wd: ["recording", "process", rec, "--calibration", cams, *ok, "-o",
                                          str(wd / "tracks")], _always(_workers_up), 60, None, {130}),
        "calibrate stereo": (lambda wd: ["calibrate", "stereo", "--sim", "--sim-poses", "60",
                                         "-o", str(wd / "calib.json")], _after(3), 10, None, {130}),
    }
    out = []
    for name, (argv_of, ready, wait_s, recording, ends) in long.items():
        if only and not name.startswith(only):
            continue
        for kind in ("SIGINT", "SIGKILL"):
            out.append(_case(name, argv_of, kind, ready, wait_s, recording, frozenset(ends)))
    return out


__all__ = ["CLASS", "cases", "fork_vts", "session_members"]
