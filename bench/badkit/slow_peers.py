"""The class "slow and trickling peers" of bench/bad_inputs.py (issue 21, round 2), and the
peers the new classes run against.

:class:`Peers` starts one helper process (this file run as a script) that holds real peers on
127.0.0.1 until the sweep ends: a healthy simulated rig of two cameras (for the signals class),
and a sick one: four cameras, each with one fault (``trickle``: a 200 at once then a byte every
0.5 s; ``too_many_viewers``: 503; a stall; a dropped connection), the simulated QATrack+
trickling its answers, the SCPI function generator answering a byte a second, and a TCP
listener that accepts and never says anything (PostgreSQL hung). It also renders a short
recording of the simulated patient (the signals class analyses it). The sweep's own process
stays free of threads (it forks its cases).

A case passes when the command ends within the sweep's time limit with a documented non-zero
exit (exit 0 is a false OK: nothing was delivered), no traceback, and its last line names the
peer (the camera, QATrack+, the generator, the store's host) in a `vts:` sentence.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

if __name__ == "__main__":  # run as the helper process: badkit is beside this file
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from badkit.classes import Case, Verdict, common  # noqa: E402

CLASS = "slow peers"
PASSWORD = "bad-inputs-sim-password"
SICK = {
    "cam1": {"trickle": True, "trickle_s": 0.5},
    "cam2": {"too_many_viewers": True},
    "cam3": {"stall_after_frames": 0, "stall_s": 3600.0},
    "cam4": {"drop_after_frames": 0},
}


class Peers:
    """The helper process and what it made (see the module docstring)."""

    def __init__(self, root: Path):
        self.root = root / "peers"
        self.proc: subprocess.Popen | None = None
        self.info: dict = {}

    def __enter__(self) -> Peers:
        self.root.mkdir(parents=True, exist_ok=True)
        self.proc = subprocess.Popen(
            [sys.executable, __file__, str(self.root)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("the peers process did not start")
        self.info = json.loads(line)
        os.environ.update(self.info["env"])  # the cases' children inherit the passwords and token
        return self

    def __exit__(self, *exc) -> None:
        if self.proc is not None:
            self.proc.stdin.close()
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    ok_rig = property(lambda self: Path(self.info["ok"]))
    sick_rig = property(lambda self: Path(self.info["sick"]))
    pg_port = property(lambda self: self.info["pg_port"])
    recording = property(lambda self: Path(self.info["recording"]))
    recording_cameras = property(lambda self: Path(self.info["cameras"]))

    def with_baseline(self, wd: Path, argv: list[str]) -> list[str]:
        """``argv`` on a store of the case's own that holds a drift baseline of the healthy rig."""
        store = ["--store", f"sqlite:///{wd / 'results.sqlite'}"]
        subprocess.run(
            [
                sys.executable,
                "-m",
                "vts_hw.cli.__main__",
                *store,
                "qa",
                "drift",
                "--set-baseline",
                "--config",
                str(self.ok_rig),
            ],
            capture_output=True,
            timeout=300,
            cwd=wd,
        )
        return [*store, *argv]

    def store_with_a_run(self, wd: Path) -> list[str]:
        """A store of the case's own holding one daily run to push."""
        from vts_hw.store import ResultsStore

        with ResultsStore(wd / "results.sqlite") as s, s.begin_run("daily", rig="sim", started=time.time() - 60) as h:
            for cam in ("cam1", "cam2"):
                h.measure(cam, "drift_x_px", 0.1, "px")
        return ["--store", f"sqlite:///{wd / 'results.sqlite'}"]


def _names(peer: str):
    def judge(wd: Path, code, out, err) -> Verdict:
        v = common(code, err)
        if v.passed and code == 0:
            v.false_ok, v.why = True, f"exit 0 though {peer} delivered nothing"
        # the one sentence on stderr, or the line of the report it points to (qa push lists each run)
        named = [line for line in err.splitlines() if line.startswith("vts: ") and peer in line] or [
            line for line in out.splitlines() if peer in line and err.strip().startswith("vts: ")
        ]
        if v.passed and not named:
            v.other, v.why = True, f"no sentence names {peer}: {err.strip()[-160:]}"
        return v

    return judge


def cases(fx, only: str | None, peers: Peers) -> list[Case]:
    sick = ["--config", str(peers.sick_rig)]
    out = []

    def add(what, argv_of, peer):
        command = what.split(": ", 1)[1]
        if not only or command.startswith(only):
            out.append(Case(CLASS, what, argv_of, _names(peer)))

    for cam, fault in SICK.items():
        name = next(iter(fault))
        add(f"{cam} {name}: camera stream", lambda wd, c=cam: ["camera", "stream", c, "--seconds", "3", *sick], cam)
        add(
            f"{cam} {name}: camera record",
            lambda wd, c=cam: ["camera", "record", c, "--seconds", "3", "-o", str(wd / "rec"), *sick],
            cam,
        )
    for args in (["snapshot", "cam1", "-o", "s.jpg"], ["info", "cam1"], ["led", "cam1", "on"]):
        add(f"cam1 trickle: camera {args[0]}", lambda wd, a=args: ["camera", *a, *sick], "cam1")
    add("QATrack+ trickle: qa push", lambda wd: [*peers.store_with_a_run(wd), "qa", "push", *sick], "QATrack+")
    for verb in ("status", "start", "stop"):
        add(
            f"generator trickle: trigger {verb}",
            lambda wd, v=verb: ["trigger", v, *sick, "--log", str(wd / "t.csv")],
            "fgen",
        )
    pg = f"postgresql://vts@127.0.0.1:{peers.pg_port}/vts"
    for argv in (["store", "info"], ["qa", "drift"], ["report", "drift", "-o", "d.html"]):
        add(f"PostgreSQL silent: {' '.join(argv[:2])}", lambda wd, a=argv: ["--store", pg, *a, *sick], "127.0.0.1")
    add("PostgreSQL silent: store init", lambda wd: ["store", "init", pg], "127.0.0.1")
    return out


# -- the helper process --------------------------------------------------------------------------


def _silent_listener() -> int:
    lst = socket.socket()
    lst.bind(("127.0.0.1", 0))
    lst.listen(64)
    held = []

    def accept():
        while True:
            held.append(lst.accept()[0])

    threading.Thread(target=accept, daemon=True).start()
    return lst.getsockname()[1]


def _recording(folder: Path) -> tuple[Path, Path]:
    import numpy as np

    from vts_hw.sim_devices.recording_sim import simulate_recording

    sim = simulate_recording(folder / "session", duration_s=8.0, seed=1)
    start = min(v[0] for v in sim.exposure.values())
    cams = [
        {"name": n, **{k: np.asarray(getattr(c, k)).tolist() for k in ("K", "dist", "R", "t")}}
        for n, c in ((n, sim.scene.camera_at(n, start)) for n in sim.cameras)
    ]
    (folder / "cameras.json").write_text(json.dumps({"unit": "mm", "cameras": cams}))
    return folder / "session", folder / "cameras.json"


def serve(folder: Path) -> None:
    from vts_hw.sim_devices.rig import SimRig

    rec, cams = _recording(folder)
    with (
        SimRig(n_cameras=2, seed=1, password=PASSWORD) as ok,
        SimRig(n_cameras=4, seed=2, password=PASSWORD, qatrack=True, trigger="visa") as sick,
    ):
        ok.write(folder / "ok")
        sick.write(folder / "sick")
        for cam, fault in SICK.items():
            sick.servers[cam].set_faults(**fault)
        sick.qatrack_site.fault, sick.qatrack_site.trickle_s = "trickle", 0.5
        sick.function_generator.go_trickle(1.0)
        env = {**ok.env_vars(), **sick.env_vars()}
        print(
            json.dumps(
                {
                    "ok": str(folder / "ok" / "rig.yaml"),
                    "sick": str(folder / "sick" / "rig.yaml"),
                    "env": env,
                    "pg_port": _silent_listener(),
                    "recording": str(rec),
                    "cameras": str(cams),
                }
            ),
            flush=True,
        )
        sys.stdin.read()  # until the sweep closes it


if __name__ == "__main__":
    serve(Path(sys.argv[1]))
