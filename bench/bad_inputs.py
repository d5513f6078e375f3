#!/usr/bin/env python3
"""Every `vts` command fed bad inputs, as a new user (or an adversarial tester) would give them:
no traceback, no hang, no false OK, no foreign file touched.

The command tree is walked from the CLI itself, so a new command is swept without being
listed here. The classes of bad input, each command one case at a time:

* ``paths``: every file or folder parameter replaced by a path that does not exist, an empty
  file, a binary file, a JSON ``[]``, an empty folder, a folder where a file is wanted (and a
  file where a folder is wanted), a file in a read-only place (outputs);
* ``numbers``: every integer replaced by ``nan``, ``inf``, ``-1``, ``1e309`` and ``abc``;
* ``floats``: every float option (``sim up`` and ``demo`` too) given ``nan``, ``inf``,
  ``-inf``, ``1e309`` and, where it has limits, a value beyond them (``-1``, ``0`` where it must
  be positive): refused as bad input naming the option (exit 2), else a false OK (exit 0) or not
  refused;
* ``configs``: ``--config`` naming a missing, empty, binary or ``[]`` rig.yaml, one with an
  unknown key, and a good one whose cameras, trigger and QATrack+ do not answer; the bad ones
  also as ``vts --config FILE qa daily``, and ``vts --config`` before ``sim up`` (which reads no
  rig.yaml: refused), a calibration entry under both its names and a calibration file named that
  is not there (decision 0099), ``--only vts`` for these alone;
* ``foreign stores``: ``--store`` naming an SQLite database of another program, a file that is
  not SQLite and an empty SQLite database, for every command; ``store migrate --from/--to``,
  ``store init``, ``qa drift --set-baseline``, ``qa import`` of a good run file and a
  calibration of the simulated rig (which stores its result after its work) likewise. Each
  case has its own copy; it must be byte-identical afterwards with nothing beside it, and a
  command that opened it must refuse it (exit 3): exit 0 is a false OK.
* ``full disk``: every command that writes, its output on a real full disk (bench/badkit/full_disk.py:
  a small tmpfs per case; needs root or password-less sudo): exit 3 naming the file, no half file
  left that looks whole, nothing acquired lost.

Round 2 (issue 21), each a module of ``badkit/``, swept with ``--classes all`` (or by name):
``slow peers`` (cameras that trickle, answer 503, stall or drop; QATrack+, the function
generator and PostgreSQL that trickle or say nothing: bounded, exit non-zero naming the peer) and
``endless files`` (``/dev/zero``, a FIFO, an 8 GiB sparse file for every file the commands read).

Round 3 (issue 32), each a module of ``badkit/``, in the default sweep as a share that meets every
command, route or action once (``--classes all``: every value, moment and identity):
``root writes`` (badkit/root_writes.py: every output of every command onto a device node, a
FIFO, a link to a file elsewhere, a folder: refused in one sentence, the node unchanged);
``killed`` (badkit/signals.py: SIGINT, SIGTERM and SIGKILL of every long command and of the
console during a Scan-page scan or a Daily QA, at several moments: what is left on disk, running,
and switched on in the trigger box and the LEDs); ``console full disk`` (badkit/console_disk.py:
each console action with its store or scans folder on a full disk: an honest answer and action
log, nothing empty left); ``web`` (badkit/web.py: every console route and method as each role and
none, with foreign Host, Origin and token, script, traversal, numbers, malformed bodies, repeated
parameters and many clients, against `vts console` on a simulated rig with secrets planted).
A ``security`` finding is a secret served, a request from elsewhere obeyed, a script sent back
unescaped, a page without its security headers.

Each case runs in a forked child of this process (the CLI is imported once) with a time
limit, in a folder of its own; the child notes every store it opens. A case passes when the
command ends with a documented exit code (0, 2, 3, 4, 5, 10, 20), no Python traceback, and
its class's own rule. Printed per class: cases, tracebacks, hangs, false OKs, data damaged
and other failures (goal 0 each), and each failure.

    .venv/bin/python bench/bad_inputs.py            # every command, every class
    .venv/bin/python bench/bad_inputs.py --only camera --show
    .venv/bin/python bench/bad_inputs.py --classes floats,foreign
    .venv/bin/python bench/bad_inputs.py --classes slow,endless,SIGINT   # round 2
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import socket
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import click

sys.path.insert(0, str(Path(__file__).resolve().parent))
from badkit import (  # noqa: E402  (issue 21 round 2)  # noqa: E402  (issue 32)
    console_disk,
    endless_files,
    full_disk,  # noqa: E402
    root_writes,
    session_files,  # noqa: E402
    signals,
    slow_peers,
)
from badkit.classes import (  # noqa: E402
    Case,
    Verdict,
    common,
    float_cases,
    foreign_cases,
    number_judge,
    plain,
    probe_stores,
    sha,
    store_command_cases,
)
from badkit.forked import FORK_LOCK, fork_vts  # noqa: E402

WEB = "web"  # badkit/web.py, run in a process of its own (it uses threads; this one forks)

SKIP = {
    ("sim", "up"): "starts servers in the foreground",
    ("demo",): "runs the whole demo",
    ("console",): "serves the room console in the foreground (a dead rig's cameras are shown NOT ANSWERING)",
    ("discover",): "searches the network: swept on loopback only, never from every interface",
}
#: what a skipped command runs with in the floats class (a bad float is refused before anything starts)
SKIPPED_BASE = {
    ("sim", "up"): lambda wd: ["--detach", "--dir", str(wd / "sim")],
    ("demo",): lambda wd: ["-o", str(wd / "demo"), "--days", "1"],
    ("console",): lambda wd: ["--port", "0"],
    ("discover",): lambda wd: ["--interface", "127.0.0.1", "--timeout", "1", "-o", str(wd / "found.yaml")],
}


def skipped_cases(cmd_path: tuple[str, ...], fx: Fixtures) -> list[Case]:
    """The bad inputs a command of SKIP refuses before it starts anything."""
    if cmd_path == ("sim", "up"):
        return [Case("configs", "no --dir", plain([*cmd_path, "--detach"]))]
    if cmd_path == ("console",):  # every bad config (not the dead rig: it serves it), a bad port
        return [
            *(
                Case("configs", what, plain([*cmd_path, "--port", "0", "--config", cfg]))
                for what, cfg in fx.configs.items()
            ),
            Case("numbers", "bad port", plain([*cmd_path, "--port", "-1"]), number_judge("-1")),
        ]
    if cmd_path == ("discover",):  # a bad timeout, refused before anything is searched
        return [
            Case(
                "numbers",
                "bad timeout",
                plain([*cmd_path, "--interface", "127.0.0.1", "--timeout", "-3"]),
                number_judge("-3"),
            )
        ]
    return [Case("numbers", "bad days", plain([*cmd_path, "--days", "-3"]), number_judge("-3"))]


#: options given to every case of a command only to shorten a fixed wait each case would sit through
#: before it meets its bad input: `vts commission` listens --listen s (3 s by default) for cameras
#: announcing themselves before it reaches the rig; with the dead rig nothing announces itself, so
#: the cases end as they did, 3 s sooner each (a --listen case of its own still replaces the value)
QUICK = {("commission",): ["--listen", "0.2"]}
NUMBERS = ["nan", "inf", "-1", "1e309", "abc"]
CLASSES = (
    "paths",
    "numbers",
    "floats",
    "configs",
    "foreign stores",
    full_disk.CLASS,
    root_writes.CLASS,
    signals.CLASS,
    console_disk.CLASS,
    WEB,
    slow_peers.CLASS,
    endless_files.CLASS,
    session_files.CLASS,
)
#: the classes that need the peers of badkit.slow_peers running
NEED_PEERS = (slow_peers.CLASS,)
#: swept unless --classes says otherwise (the two of round 2 take minutes of peers: --classes all;
#: the four of round 3 as a share meeting every command once, whole with --classes all)
DEFAULT_CLASSES = CLASSES[:10]
COUNTS = ("tracebacks", "hangs", "false_oks", "damaged", "security", "other")
QATRACK_TOKEN_ENV = "VTS_BAD_INPUTS_QATRACK_TOKEN"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Fixtures:
    """The bad things, made once in a temporary folder."""

    def __init__(self, root: Path):
        self.root = root
        (root / "empty.txt").write_bytes(b"")
        (root / "binary.bin").write_bytes(os.urandom(4096) + b"\xff\xd8\x00")
        (root / "list.json").write_text("[]")
        (root / "emptydir").mkdir()
        ro = root / "readonly"
        ro.mkdir()
        self.readonly_out = ro / "out.file"
        port = free_port()
        dead = {
            "rig": "dead",
            "cameras": [
                {"name": "cam1", "host": "127.0.0.1", "port": port, "timeout_s": 1},
                {"name": "cam2", "host": "127.0.0.1", "port": free_port(), "timeout_s": 1},
            ],
            "trigger": {"backend": "visa", "address": f"TCPIP::127.0.0.1::{free_port()}::SOCKET"},
            "results": {"url": f"sqlite:///{root / 'store' / 'results.sqlite'}"},
            "qatrack": {
                "url": f"http://127.0.0.1:{free_port()}/",
                "unit": "SPECT 1",
                "time_zone": "UTC",
                "token_env": QATRACK_TOKEN_ENV,
                "timeout_s": 2,
                "lists": {"daily": {"test_list": "VTS daily", "macros": {"cam1/drift_x_px": "dx"}, "ignore": ["*"]}},
            },
        }
        import yaml

        (root / "dead.yaml").write_text(yaml.safe_dump(dead))
        (root / "unknown_key.yaml").write_text(yaml.safe_dump({**dead, "camerass": []}))
        # camera entries that do not fit their kind (its settings model, its roles): refused
        for name, cam in (
            ("hostless", {"name": "cam1"}),
            ("axis_options", {"name": "cam1", "host": "127.0.0.1", "port": port, "options": {"speed": 2}}),
            ("replay", {"name": "cam1", "kind": "replay", "options": {"folder": str(root / "emptydir")}}),
            # a value that goes into the camera's URLs and would make another host the one asked
            ("host_with_user", {"name": "cam1", "host": "127.0.0.1@evil.example", "port": port}),
            (
                "mjpeg_path_off_host",
                {
                    "name": "cam1",
                    "kind": "mjpeg",
                    "host": "127.0.0.1",
                    "port": port,
                    "options": {"stream_path": ".evil.example/x"},
                },
            ),
        ):
            (root / f"{name}.yaml").write_text(yaml.safe_dump({"rig": name, "cameras": [cam]}))
        # rig.yaml's calibration entries (decision 0099): one under its new and its old name; a
        # calibration file named that is not there (the room says so before any camera is opened)
        for name, section in (
            ("both_names", {"cameras": "a.json", "stereo": "b.json"}),
            ("no_calibration_file", {"cameras": str(root / "gone.json")}),
        ):
            (root / f"{name}.yaml").write_text(yaml.safe_dump({**dead, "calibration": section}))
        self.configs = {
            "missing config": str(root / "nope.yaml"),
            "empty config": str(root / "empty.txt"),
            "binary config": str(root / "binary.bin"),
            "[] config": str(root / "list.json"),
            "unknown key": str(root / "unknown_key.yaml"),
        }
        self.dead_config = str(root / "dead.yaml")
        self.paths = {
            "missing path": str(root / "does-not-exist"),
            "empty file": str(root / "empty.txt"),
            "binary file": str(root / "binary.bin"),
            "[] json": str(root / "list.json"),
            "empty folder": str(root / "emptydir"),
        }


def is_path(p: click.Parameter) -> bool:
    return isinstance(p.type, (click.Path, click.File))


def is_number(p: click.Parameter) -> bool:
    return isinstance(
        p.type, (click.types.FloatParamType, click.types.IntParamType, click.FloatRange, click.IntRange)
    ) or getattr(p.type, "name", "") in ("seconds",)


def is_float(p: click.Parameter) -> bool:
    return isinstance(p.type, click.types.FloatParamType)


def base_args(cmd: click.Command, fx: Fixtures) -> list[str]:
    """A plausible command line: required arguments filled with harmless values."""
    args = []
    for p in cmd.params:
        if isinstance(p, click.Argument) and p.required:
            if is_path(p):
                args.append(fx.paths["empty folder"])
            elif isinstance(p.type, click.Choice):
                args.append(p.type.choices[0])
            elif is_number(p):
                args.append("1")
            else:
                args.append("cam1")
        elif isinstance(p, click.Option) and p.required:
            opt = p.opts[-1] if p.opts[-1].startswith("--") else p.opts[0]
            if is_path(p):
                args += [opt, str(fx.root / f"out-{p.name}")]
            elif is_number(p):
                args += [opt, "1"]
            else:
                args += [opt, "x"]
    return args


def _refused(wd: Path, code: int | None, out: str, err: str) -> Verdict:
    """A bad input that must be refused: exit 0 is a false OK."""
    v = common(code, err)
    if code == 0:
        return Verdict(false_ok=True, why="accepted")
    return v


def global_config_cases(fx: Fixtures) -> list[Case]:
    """`vts --config FILE COMMAND` (the room's file before the command's name): every bad config,
    and a command that reads no rig.yaml, which refuses it (issue 34 §4)."""
    out = [
        Case("configs", f"vts --config: {what}", plain(["--config", cfg, "qa", "daily"]), _refused)
        for what, cfg in fx.configs.items()
    ]
    out.append(
        Case(
            "configs",
            "vts --config before a command that reads no rig.yaml",
            lambda wd: ["--config", fx.dead_config, "sim", "up", "--detach", "--dir", str(wd / "sim")],
            _refused,
        )
    )
    return out


def camera_kind_cases(fx: Fixtures) -> list[Case]:
    """A camera entry that does not fit its kind's settings model, `camera setup` of a kind
    without the parameters role, and a value that goes into a camera's URLs and makes another host
    the one asked (its host, an MJPEG path): refused in one sentence (docs/decisions/0100-camera-roles.md)."""

    def config(name: str) -> str:
        return str(fx.root / f"{name}.yaml")

    return [
        Case(
            "configs",
            "camera kind: an Axis camera without a host",
            lambda wd: ["camera", "snapshot", "cam1", "-o", str(wd / "a.jpg"), "--config", config("hostless")],
            _refused,
        ),
        Case(
            "configs",
            "camera kind: options on an Axis camera",
            plain(["camera", "info", "cam1", "--config", config("axis_options")]),
            _refused,
        ),
        Case(
            "configs",
            "camera kind: setup of a kind without parameters",
            plain(["camera", "setup", "cam1", "--config", config("replay")]),
            _refused,
        ),
        Case(
            "configs",
            "camera URL: a host with a user part (another host asked, with the credentials)",
            plain(["camera", "info", "cam1", "--config", config("host_with_user")]),
            _refused,
        ),
        Case(
            "configs",
            "camera URL: an mjpeg stream path not from / (joined onto the host: another host)",
            plain(["camera", "stream", "cam1", "--seconds", "1", "--config", config("mjpeg_path_off_host")]),
            _refused,
        ),
    ]


def calibration_key_cases(fx: Fixtures) -> list[Case]:
    """rig.yaml's calibration entries: one under both its names, and a calibration file named that
    is not there (`calibrate spect --from-cameras` opens the room's calibration): refused, exit 2."""
    both, gone = str(fx.root / "both_names.yaml"), str(fx.root / "no_calibration_file.yaml")
    return [
        Case(
            "configs",
            "calibration: cameras and stereo (its old name) both given",
            plain(["trigger", "status", "--config", both]),
            _refused,
        ),
        Case(
            "configs",
            "calibration.cameras names no file",
            lambda wd: [
                "calibrate",
                "spect",
                "--from-cameras",
                "--volume",
                fx.paths["binary file"],
                "-o",
                str(wd / "m.json"),
                "--config",
                gone,
            ],
            _refused,
        ),
    ]


def cases(cmd_path: tuple[str, ...], cmd: click.Command, fx: Fixtures, classes=CLASSES, full: bool = False):
    """The cases of the classes paths, numbers, configs, floats and foreign stores of one command."""
    base = base_args(cmd, fx) + QUICK.get(cmd_path, [])
    has_config = any(p.name == "config_path" for p in cmd.params)
    if has_config:
        for what, cfg in fx.configs.items():
            yield Case("configs", what, plain([*cmd_path, *base, "--config", cfg]))
        yield Case("configs", "dead rig", plain([*cmd_path, *base, "--config", fx.dead_config]))
    cfg = ["--config", fx.dead_config] if has_config else []
    for p in cmd.params:
        if p.name == "config_path":
            continue
        opt = None if isinstance(p, click.Argument) else (p.opts[-1] if p.opts[-1].startswith("--") else p.opts[0])
        if is_path(p):
            values = dict(fx.paths)
            if getattr(p.type, "file_okay", True) and not getattr(p.type, "dir_okay", True):
                values["folder for a file"] = fx.paths["empty folder"]
            if getattr(p.type, "dir_okay", True) and not getattr(p.type, "file_okay", True):
                values["file for a folder"] = fx.paths["empty file"]
            values["read-only place"] = str(fx.readonly_out)
            for what, v in values.items():
                yield _path_case(cmd_path, base, cfg, p, opt, what, v)
        elif is_number(p) and not is_float(p):
            for v in NUMBERS:
                yield Case(
                    "numbers", f"{p.name}: {v}", plain([*cmd_path, *_replace(base, p, opt, v), *cfg]), number_judge(v)
                )
    yield from float_cases(cmd_path, cmd, lambda wd: [*base, *cfg])
    yield from foreign_cases(cmd_path, lambda wd: base, cfg)
    if root_writes.CLASS in classes:
        yield from root_writes.cases(cmd_path, cmd, base + cfg, good_command(cmd_path, fx), _replace, full)
    if getattr(fx, "endless", None):
        yield from endless_files.cases(cmd_path, cmd, base, cfg, fx.endless, _replace)


def _path_case(cmd_path, base, cfg, p: click.Parameter, opt, what: str, value: str) -> Case:
    """A bad path for ``p``; a bad file is the case's own copy, which must come out as it went in
    unless it was empty (nothing to lose) or ``p`` names an output the command writes whole (``-o``
    over an existing file replaces it; a log is appended to, so a --log is no output here)."""
    src = Path(value)
    if not src.is_file():
        return Case("paths", f"{p.name}: {what}", plain([*cmd_path, *_replace(base, p, opt, value), *cfg]))

    def make(wd: Path) -> list[str]:
        copy = wd / src.name
        copy.write_bytes(src.read_bytes())
        (wd / ".input.sha256").write_text(sha(copy))
        return [*cmd_path, *_replace(base, p, opt, str(copy)), *cfg]

    def judge(wd: Path, code, out, err) -> Verdict:
        v = common(code, err)
        if src.stat().st_size and sha(wd / src.name) != (wd / ".input.sha256").read_text() and not is_output(p):
            v.damaged, v.why = True, f"{src.name}, given as {p.name}, was changed"
        return v

    return Case("paths", f"{p.name}: {what}", make, judge)


#: the parameters that name what a command writes
OUTPUTS = {"out", "output", "export_dir", "plot_path", "folder", "out_dir"}


def is_output(p: click.Parameter) -> bool:
    return p.name in OUTPUTS


def _replace(base: list[str], p: click.Parameter, opt: str | None, value: str) -> list[str]:
    out = list(base)
    if opt is None:  # an argument: the first base value of that position, else appended
        for i, a in enumerate(out):
            if not a.startswith("-") and (i == 0 or not out[i - 1].startswith("-")):
                out[i] = value
                return out
        return out + [value]
    if opt in out:
        out[out.index(opt) + 1] = value
        return out
    if getattr(p, "is_flag", False):
        return out
    return out + [opt, value]


def run_case(argv: list[str], timeout: float, workdir: Path) -> tuple[int | None, str, str]:
    """Run `vts ARGV` in a forked child in ``workdir`` (so that default outputs of cases run at
    once do not meet; every store it opens is noted there); (exit code or None on a hang, stdout,
    stderr)."""
    return fork_vts(argv, timeout, workdir, before=probe_stores)


def preload() -> int:
    """Import every module of the package once, before the cases fork: a child then starts with
    them (copy-on-write) instead of importing numpy, OpenCV, matplotlib, SQLAlchemy ... again,
    which is most of a case's time. Nothing is run: the commands import lazily, as they do for a
    user, only the import cost moves. A module that cannot be imported is left for its cases to
    find. Returns how many were imported."""
    import importlib
    import pkgutil
    import threading

    import matplotlib

    matplotlib.use("Agg")
    import vts_hw

    n = 0
    for m in pkgutil.walk_packages(vts_hw.__path__, "vts_hw."):
        if m.name.endswith("__main__"):
            continue
        try:
            importlib.import_module(m.name)
            n += 1
        except Exception:  # noqa: BLE001 -- its cases report it, with the user's view of it
            pass
    assert threading.active_count() == 1, "an import started a thread: forking after it is unsafe"
    return n


def good_command(cmd_path: tuple[str, ...], fx: Fixtures):
    """``argv(wd, D)``: a command line of badkit/full_disk's table for this command (good inputs on
    the simulated rig, its outputs in D), or None (the root writes class then uses the sweep's base)."""
    if getattr(fx, "writers", None) is None:
        return None
    words = " ".join(cmd_path)
    for what, argv, *_ in fx.writers:
        if what == words or what.startswith((words + " ", words + ",")):
            return argv
    if cmd_path in SKIPPED_BASE:
        return lambda wd, D: [*cmd_path, *SKIPPED_BASE[cmd_path](wd)]
    return None


def plan(only: str | None, classes, fx: Fixtures, cli, peers=None, full: bool = False) -> list[Case]:
    """Every case of the chosen classes, command by command (the tree walked from the CLI);
    ``full``: the round 3 classes whole (every value, moment and identity), else their share."""
    if {root_writes.CLASS, signals.CLASS, console_disk.CLASS} & set(classes):
        inp = full_disk.inputs(fx.root)
        fx.writers = full_disk.table(inp)
    from vts_hw.cli import command_tree

    planned: list[Case] = []
    for cmd_path, cmd in command_tree(cli):
        if isinstance(cmd, click.Group):
            continue
        if only and not " ".join(cmd_path).startswith(only):
            continue
        if cmd_path in SKIP:  # their float options only (refused before anything starts), and the old two
            todo = list(float_cases(cmd_path, cmd, SKIPPED_BASE[cmd_path])) + skipped_cases(cmd_path, fx)
            if root_writes.CLASS in classes:
                todo += root_writes.cases(cmd_path, cmd, [], good_command(cmd_path, fx), _replace, full)
        else:
            todo = list(cases(cmd_path, cmd, fx, classes, full))
        planned += todo
    planned += [c for c in store_command_cases(fx) if not only or c.what.startswith(only)]
    planned += [c for c in global_config_cases(fx) if not only or only == "vts"]
    planned += [c for c in camera_kind_cases(fx) if not only or only in ("vts", "camera")]
    planned += [c for c in calibration_key_cases(fx) if not only or only in ("vts", "trigger", "calibrate")]
    if full_disk.CLASS in classes:
        planned += full_disk.cases(fx.root, only)
    if signals.CLASS in classes:
        planned += signals.cases(full_disk.inputs(fx.root), only, full)
    if console_disk.CLASS in classes:
        planned += console_disk.cases(fx.root, only, full)
    if session_files.CLASS in classes:
        planned += session_files.cases(full_disk.inputs(fx.root), only)
    if peers is not None:
        planned += slow_peers.cases(fx, only, peers)
    return [c for c in planned if c.cls in classes]


def command_of(argv: list[str]) -> str:
    """The command words of a case's argv (``--store URL`` before them skipped)."""
    words = argv[2:] if argv[:1] == ["--store"] else argv
    out = []
    for w in words:
        if w.startswith("-") or "/" in w or len(out) == 2:
            break
        out.append(w)
    return " ".join(out)


def _stop_sims(root: Path) -> None:
    """A detached simulated rig a case started (a float not refused would start one): stopped."""
    from vts_hw.sim_devices.rig_detached import stop_detached

    for pid_file in root.glob("cases/*/**/sim.pid"):  # (a root writes case may start one in its target)
        stop_detached(pid_file.parent)


def sweep(
    only: str | None, timeout: float, show: bool, root: Path, jobs: int = 1, classes=CLASSES, full: bool = False
) -> dict:
    from vts_hw.cli import _register, cli

    _register()
    preload()
    fx = Fixtures(root)
    # the read-only place: a folder whose writes fail even for root is not available without a
    # mount, so make it a path under a regular FILE (ENOTDIR) -- an output that cannot be written
    fx.readonly_out = root / "empty.txt" / "out.file"
    fixtures = {p: sha(p) for p in root.iterdir() if p.is_file()}
    per = {c: {"cases": 0, **{k: 0 for k in COUNTS}, "opened": 0, "seconds": 0.0} for c in classes}
    results = {
        "cases": 0,
        "passed": 0,
        "classes": per,
        "failures": [],
        "opened_by": [],
        "tracebacks": [],
        "hangs": [],
        "bad_exit": [],
    }
    env_backup, cwd = dict(os.environ), os.getcwd()
    os.chdir(root)  # default outputs (trigger.csv, drift-report.html) land in the sandbox
    os.environ["XDG_DATA_HOME"] = str(root / "xdg")
    os.environ[QATRACK_TOKEN_ENV] = "bad-inputs-token"
    for name in ("VTS_CONFIG", "VTS_STORE", "VTS_STORE_PASSWORD_ENV"):
        os.environ.pop(name, None)
    stack = contextlib.ExitStack()
    web = None
    try:
        if endless_files.CLASS in classes:
            fx.endless = endless_files.make_inputs(root)
        peers = stack.enter_context(slow_peers.Peers(root)) if set(NEED_PEERS) & set(classes) else None
        # the class web runs in a process of its own from now, beside the forked cases
        web = web_start(root, full) if WEB in classes and not only else None
        t_plan = time.monotonic()
        planned = plan(only, classes, fx, cli, peers, full)
        setup_s = time.monotonic() - t_plan
        argvs = []
        for k, case in enumerate(planned):  # every case's files, made here before any fork
            wd = root / "cases" / str(k)
            wd.mkdir(parents=True)
            argvs.append(case.make(wd))

        # cases run `jobs` at a time (each a forked child in a folder of its own); the parent's
        # threads only fork, read pipes and wait
        def timed(k):
            t0 = time.monotonic()
            got = planned[k].extra.get("run", run_case)(argvs[k], timeout, root / "cases" / str(k))
            return got, time.monotonic() - t0

        with ThreadPoolExecutor(max(1, jobs)) as pool:
            done = pool.map(timed, range(len(planned)))
            for k, (case, argv, ((code, out, err), dt)) in enumerate(zip(planned, argvs, done)):
                wd = root / "cases" / str(k)
                with FORK_LOCK:  # a judge reads stores (SQLite): never while a case is forked
                    v: Verdict = case.judge(wd, code, out, err) if case.judge else common(code, err)
                label = f"vts {' '.join(argv)}  [{case.cls}: {case.what}]"
                c = per[case.cls]
                c["cases"] += 1
                c["seconds"] += dt
                results["cases"] += 1
                for key, flag in (
                    ("tracebacks", v.traceback),
                    ("hangs", v.hang),
                    ("false_oks", v.false_ok),
                    ("damaged", v.damaged),
                    ("other", v.other),
                    ("opened", v.opened),
                    ("security", v.security),
                ):
                    c[key] += bool(flag)
                if v.opened:
                    results["opened_by"].append(command_of(argv))
                if v.passed:
                    results["passed"] += 1
                else:
                    results["failures"].append(f"{label}\n      {v.why}")
                    kind = "hangs" if v.hang else "tracebacks" if v.traceback else "bad_exit"
                    results[kind].append(f"{label}: {v.why}")
                if show:
                    last = (err.strip().splitlines() or [""])[-1][:160]
                    print(f"  exit {code}: {label}\n      {last}")
        if web is not None:
            web_sweep(web, results, per[WEB], show)
            web = None
        results["setup_s"] = round(setup_s, 1)
    finally:
        if web is not None:
            web[0].kill()
            web[0].wait()
        stack.close()
        for fd in signals._HELD:
            os.close(fd)
        signals._HELD.clear()
        _stop_sims(root)
        full_disk.cleanup(root)
        os.chdir(cwd)
        os.environ.clear()
        os.environ.update(env_backup)
    changed = [str(p.name) for p, h in fixtures.items() if sha(p) != h]
    if changed and "configs" in per:  # the configs every case shares: never written
        per["configs"]["damaged"] += len(changed)
        results["failures"].append(f"fixture(s) changed by some case: {', '.join(changed)}")
    results["opened_by"] = sorted(set(results["opened_by"]))
    return results


def web_start(root: Path, full: bool):
    """The class web started: badkit/web.py in a process of its own (it uses threads; this one forks),
    its output in files; (the process, its stdout file, its stderr file, when it started)."""
    import subprocess

    (root / "web").mkdir(parents=True, exist_ok=True)
    out, err = open(root / "web.json", "w+"), open(root / "web.err", "w+")
    proc = subprocess.Popen(
        [
            sys.executable,
            str(Path(__file__).resolve().parent / "badkit" / "web.py"),
            str(root / "web"),
            *(["--full"] if full else []),
        ],
        stdout=out,
        stderr=err,
        stdin=subprocess.DEVNULL,
    )
    return proc, out, err, time.monotonic()


def web_sweep(web, results: dict, c: dict, show: bool) -> None:
    """The class web's verdicts (its process waited for), counted here."""
    proc, out, err, t0 = web
    try:
        proc.wait(3600)
    except Exception:  # noqa: BLE001 -- a sweep that does not end is one failure, said below
        proc.kill()
        proc.wait()
    c["seconds"] = time.monotonic() - t0
    out.seek(0)
    err.seek(0)
    stdout, stderr = out.read(), err.read()
    out.close()
    err.close()
    try:
        verdicts = json.loads(stdout)
    except ValueError:
        c["cases"] += 1
        c["other"] += 1
        results["cases"] += 1
        results["failures"].append(
            f"[web] the web sweep did not finish (exit {proc.returncode}): {stderr.strip()[-400:]}"
        )
        return
    fams = c.setdefault("families", {})
    for v in verdicts:
        c["cases"] += 1
        results["cases"] += 1
        fam = v["what"].split("]", 1)[0].lstrip("[")
        fams[fam] = fams.get(fam, 0) + 1
        for key, flag in (
            ("tracebacks", "traceback"),
            ("hangs", "hang"),
            ("false_oks", "false_ok"),
            ("damaged", "damaged"),
            ("other", "other"),
            ("security", "security"),
        ):
            c[key] += bool(v[flag])
        if any(v[f] for f in ("traceback", "hang", "false_ok", "damaged", "other", "security")):
            results["failures"].append(f"{v['what']}\n      {v['why']}")
            if v["security"]:
                results.setdefault("security", []).append(f"{v['what']}: {v['why']}")
        else:
            results["passed"] += 1
        if show:
            print(f"  {v['what']}  {v['why']}")


def table(r: dict) -> str:
    head = (
        f"{'class':<18} {'cases':>6} {'tracebacks':>10} {'hangs':>6} {'false OKs':>9} {'data damaged':>12} "
        f"{'security':>8} {'other':>6} {'seconds':>8}"
    )
    lines = [head]
    for cls, c in r["classes"].items():
        lines.append(
            f"{cls:<18} {c['cases']:>6} {c['tracebacks']:>10} {c['hangs']:>6} {c['false_oks']:>9} "
            f"{c['damaged']:>12} {c['security']:>8} {c['other']:>6} {c['seconds']:>8.0f}"
        )
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="only commands starting with this (e.g. 'camera' or 'qa daily')")
    ap.add_argument(
        "--classes",
        default=",".join(DEFAULT_CLASSES),
        help=f"classes to sweep, comma-separated, or 'all' (default: {', '.join(DEFAULT_CLASSES)}; "
        f"also: {', '.join(CLASSES[10:])}; 'foreign' for foreign stores); 'all' sweeps the "
        "classes of round 3 whole (every value, moment and identity), else a share meeting "
        "every command, route and action once",
    )
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per case before it counts as a hang")
    ap.add_argument("--show", action="store_true", help="print every case and its last line")
    ap.add_argument("--json", action="store_true", help="the figures as JSON")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="cases run at once (default: one per core)")
    a = ap.parse_args()
    wanted = [c.strip() for c in a.classes.split(",") if c.strip()]
    full = wanted == ["all"]
    wanted = list(CLASSES) if full else wanted
    classes = [c for c in CLASSES if any(c.startswith(w) for w in wanted)]
    if not classes:
        ap.error(f"--classes: none of {', '.join(CLASSES)}")
    with tempfile.TemporaryDirectory(prefix="vts-bad-inputs-") as tmp:
        t0 = time.monotonic()
        r = sweep(a.only, a.timeout, a.show, Path(tmp), a.jobs, classes, full)
        dt = time.monotonic() - t0
    if a.json:
        print(json.dumps(r, indent=1))
    else:
        print(
            f"bad inputs: {r['cases']} cases over every command in {dt:.0f} s: {r['passed']} passed "
            f"(one sentence, a documented exit code, refused where the class says so)"
        )
        print(table(r))
        fs = r["classes"].get("foreign stores")
        if fs:
            print(
                f"foreign stores: {fs['opened']} case(s) reached the store ({', '.join(r['opened_by'])}); "
                "every other command never opens one"
            )
        for x in r["failures"]:
            print(f"  FAILED {x}")
    return 0 if not r["failures"] else 1


if __name__ == "__main__":
    sys.exit(main())
