#!/usr/bin/env python3
"""Every `vts` command fed bad inputs, as a new user would give them: no traceback, ever.

The command tree is walked from the CLI itself, so a new command is swept without being
listed here. Each command gets, one at a time:

* every file or folder parameter replaced by: a path that does not exist, an empty file, a
  binary file, a JSON ``[]``, an empty folder, a folder where a file is wanted (and a file
  where a folder is wanted), a file in a read-only place (outputs);
* every number replaced by ``nan``, ``inf``, ``-1``, ``1e309`` and ``abc``;
* ``--config`` naming a missing, empty, binary or ``[]`` rig.yaml, one with an unknown key,
  and a good one whose cameras and trigger do not answer (ports nobody listens on).

Each case runs in a forked child of this process (the CLI is imported once) with a time
limit. A case passes when the command ends with a documented exit code (0, 2, 3, 4, 5, 10,
20) and no Python traceback. Printed: cases, passed, tracebacks, hangs, and each failure.

    .venv/bin/python bench/bad_inputs.py            # every command
    .venv/bin/python bench/bad_inputs.py --only camera --show
"""

from __future__ import annotations

import argparse
import io
import json
import os
import select
import signal
import socket
import sys
import tempfile
import time
import traceback
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import click

EXIT_OK = {0, 2, 3, 4, 5, 10, 20}
SKIP = {("sim", "up"): "starts servers in the foreground", ("demo",): "runs the whole demo"}
NUMBERS = ["nan", "inf", "-1", "1e309", "abc"]


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
        dead = {"rig": "dead", "cameras": [{"name": "cam1", "host": "127.0.0.1", "port": port, "timeout_s": 1},
                                           {"name": "cam2", "host": "127.0.0.1", "port": free_port(),
                                            "timeout_s": 1}],
                "trigger": {"backend": "visa", "address": f"TCPIP::127.0.0.1::{free_port()}::SOCKET"},
                "results": {"url": f"sqlite:///{root / 'store' / 'results.sqlite'}"}}
        import yaml
        (root / "dead.yaml").write_text(yaml.safe_dump(dead))
        (root / "unknown_key.yaml").write_text(yaml.safe_dump({**dead, "camerass": []}))
        self.configs = {"missing config": str(root / "nope.yaml"), "empty config": str(root / "empty.txt"),
                        "binary config": str(root / "binary.bin"), "[] config": str(root / "list.json"),
                        "unknown key": str(root / "unknown_key.yaml")}
        self.dead_config = str(root / "dead.yaml")
        self.paths = {"missing path": str(root / "does-not-exist"), "empty file": str(root / "empty.txt"),
                      "binary file": str(root / "binary.bin"), "[] json": str(root / "list.json"),
                      "empty folder": str(root / "emptydir")}


def is_path(p: click.Parameter) -> bool:
    return isinstance(p.type, (click.Path, click.File))


def is_number(p: click.Parameter) -> bool:
    return isinstance(p.type, (click.types.FloatParamType, click.types.IntParamType, click.FloatRange,
                               click.IntRange)) or getattr(p.type, "name", "") in ("seconds",)


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


def cases(cmd_path: tuple[str, ...], cmd: click.Command, fx: Fixtures):
    base = base_args(cmd, fx)
    has_config = any(p.name == "config_path" for p in cmd.params)
    if has_config:
        for what, cfg in fx.configs.items():
            yield what, [*cmd_path, *base, "--config", cfg]
        yield "dead rig", [*cmd_path, *base, "--config", fx.dead_config]
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
                yield f"{p.name}: {what}", [*cmd_path, *_replace(base, p, opt, v), *cfg]
        elif is_number(p):
            for v in NUMBERS:
                yield f"{p.name}: {v}", [*cmd_path, *_replace(base, p, opt, v), *cfg]


def _replace(base: list[str], p: click.Parameter, opt: str | None, value: str) -> list[str]:
    out = list(base)
    if opt is None:  # an argument: the first base value of that position, else appended
        idx = [q for q in p.__class__.__mro__]  # noqa: F841 (kept simple: replace the first path/number)
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


def run_case(argv: list[str], timeout: float, workdir: Path | None = None) -> tuple[int | None, str, str]:
    """Run `vts ARGV` in a forked child (in ``workdir``, so that default outputs of cases run at
    once do not meet); (exit code or None on a hang, stdout, stderr)."""
    out_r, out_w = os.pipe()
    err_r, err_w = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: the CLI's own main(), as the console script runs it
        try:
            if workdir is not None:
                os.makedirs(workdir, exist_ok=True)
                os.chdir(workdir)
            os.dup2(out_w, 1)
            os.dup2(err_w, 2)
            os.setsid()
            sys.stdout = io.TextIOWrapper(os.fdopen(1, "wb", buffering=0), write_through=True)
            sys.stderr = io.TextIOWrapper(os.fdopen(2, "wb", buffering=0), write_through=True)
            sys.stdin = open(os.devnull)
            from vts_hw.cli import main
            code = 0
            try:
                main(argv)
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
            except BaseException:
                traceback.print_exc()
                code = 99
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(code if "code" in locals() else 98)
    os.close(out_w)
    os.close(err_w)
    chunks = {out_r: [], err_r: []}
    deadline = time.monotonic() + timeout
    open_fds = [out_r, err_r]
    hung = False
    while open_fds:
        left = deadline - time.monotonic()
        if left <= 0:
            hung = True
            os.killpg(pid, signal.SIGKILL)
            break
        ready, _, _ = select.select(open_fds, [], [], min(left, 0.5))
        for fd in ready:
            data = os.read(fd, 65536)
            if data:
                chunks[fd].append(data)
            else:
                open_fds.remove(fd)
    _, status = os.waitpid(pid, 0)
    for fd in (out_r, err_r):
        os.close(fd)
    code = None if hung else (os.waitstatus_to_exitcode(status))
    return code, b"".join(chunks[out_r]).decode(errors="replace"), b"".join(chunks[err_r]).decode(errors="replace")


def walk(group: click.Group, path=()):
    for name, c in sorted(group.commands.items()):
        if isinstance(c, click.Group):
            yield from walk(c, path + (name,))
        else:
            yield path + (name,), c


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
        except Exception:   # noqa: BLE001 -- its cases report it, with the user's view of it
            pass
    assert threading.active_count() == 1, "an import started a thread: forking after it is unsafe"
    return n


def sweep(only: str | None, timeout: float, show: bool, root: Path, jobs: int = 1) -> dict:
    from vts_hw.cli import _register, cli
    _register()
    preload()
    fx = Fixtures(root)
    # the read-only place: a folder whose writes fail even for root is not available without a
    # mount, so make it a path under a regular FILE (ENOTDIR) -- an output that cannot be written
    fx.readonly_out = root / "empty.txt" / "out.file"
    results = {"cases": 0, "passed": 0, "tracebacks": [], "hangs": [], "bad_exit": []}
    planned: list[tuple[str, list[str]]] = []
    env_backup, cwd = dict(os.environ), os.getcwd()
    os.chdir(root)   # default outputs (trigger.csv, drift-report.html) land in the sandbox
    os.environ["XDG_DATA_HOME"] = str(root / "xdg")
    os.environ.pop("VTS_CONFIG", None)
    try:
        for cmd_path, cmd in walk(cli):
            if only and not " ".join(cmd_path).startswith(only):
                continue
            if cmd_path in SKIP:
                extra = [("no --dir", [*cmd_path, "--detach"]), ("bad rate", [*cmd_path, "--rate", "nan", "--detach"])] \
                    if cmd_path == ("sim", "up") else [("bad days", [*cmd_path, "--days", "-3"])]
                todo = extra
            else:
                todo = list(cases(cmd_path, cmd, fx))
            for what, argv in todo:
                planned.append((what, argv))
        # cases run `jobs` at a time (each a forked child in a folder of its own); the parent's
        # threads only fork, read pipes and wait
        with ThreadPoolExecutor(max(1, jobs)) as pool:
            done = pool.map(lambda k: run_case(planned[k][1], timeout, root / "cases" / str(k)), range(len(planned)))
            for (what, argv), (code, out, err) in zip(planned, done):
                results["cases"] += 1
                label = f"vts {' '.join(argv)}  [{what}]"
                if code is None:
                    results["hangs"].append(label)
                elif "Traceback (most recent call last)" in err:
                    results["tracebacks"].append(f"{label}\n      {err.strip().splitlines()[-1]}")
                elif code not in EXIT_OK:
                    results["bad_exit"].append(f"{label} -> exit {code}: {err.strip().splitlines()[-1:] or ''}")
                else:
                    results["passed"] += 1
                if show:
                    last = (err.strip().splitlines() or [""])[-1][:160]
                    print(f"  exit {code}: {label}\n      {last}")
    finally:
        os.chdir(cwd)
        os.environ.clear()
        os.environ.update(env_backup)
    return results


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", help="only commands starting with this (e.g. 'camera' or 'qa daily')")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per case before it counts as a hang")
    ap.add_argument("--show", action="store_true", help="print every case and its last line")
    ap.add_argument("--json", action="store_true", help="the figures as JSON")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1,
                    help="cases run at once (default: one per core)")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="vts-bad-inputs-") as tmp:
        t0 = time.monotonic()
        r = sweep(a.only, a.timeout, a.show, Path(tmp), a.jobs)
        dt = time.monotonic() - t0
    if a.json:
        print(json.dumps(r, indent=1))
    else:
        print(f"bad inputs: {r['cases']} cases over every command in {dt:.0f} s: {r['passed']} answered in one "
              f"sentence with a documented exit code; {len(r['tracebacks'])} traceback(s), {len(r['hangs'])} "
              f"hang(s), {len(r['bad_exit'])} undocumented exit code(s)")
        for kind in ("tracebacks", "hangs", "bad_exit"):
            for x in r[kind]:
                print(f"  {kind[:-1] if kind.endswith('s') else kind}: {x}")
    return 0 if not (r["tracebacks"] or r["hangs"] or r["bad_exit"]) else 1


if __name__ == "__main__":
    sys.exit(main())
