"""The classes of bad input of bench/bad_inputs.py beyond bad paths, numbers and configs
(issue 21): numbers that are not finite (or out of range) for every float option, and
databases that are not a vts-hw results store for every command that opens the store.

A :class:`Case` makes its own files in its own folder (``make(workdir) -> argv``) and judges
its outcome (``judge(workdir, code, out, err) -> Verdict``); the sweep runs it in a forked
child that notes every store it opens in ``workdir/.store-opened`` (:func:`probe_stores`).
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import click

EXIT_OK = {0, 2, 3, 4, 5, 10, 20}
OPENED = ".store-opened"
#: values every float option must refuse (exit 2, naming the option)
NOT_FINITE = ["nan", "inf", "-inf", "1e309", "NaN"]
#: bad numbers: accepting one of these (exit 0) is a false OK
NONSENSE = {"nan", "inf", "-inf", "1e309", "abc", "NaN"}


@dataclass
class Verdict:
    traceback: bool = False
    hang: bool = False
    false_ok: bool = False
    damaged: bool = False
    other: bool = False  # an undocumented exit code, or bad input not refused as such
    opened: bool = False  # the command opened the store it was given
    security: bool = False  # a secret served, a foreign request obeyed, a script sent back unescaped
    why: str = ""

    @property
    def passed(self) -> bool:
        return not (self.traceback or self.hang or self.false_ok or self.damaged or self.other or self.security)


@dataclass
class Case:
    cls: str
    what: str
    make: Callable[[Path], list[str]]
    judge: Callable[[Path, int | None, str, str], Verdict] | None = None
    extra: dict = field(default_factory=dict)


def common(code: int | None, err: str) -> Verdict:
    """Hang, traceback, undocumented exit code: what every case is judged by first."""
    if code is None:
        return Verdict(hang=True, why="no answer within the time limit")
    if "Traceback (most recent call last)" in err:
        return Verdict(traceback=True, why=(err.strip().splitlines() or [""])[-1])
    if code not in EXIT_OK:
        return Verdict(other=True, why=f"exit {code}: {(err.strip().splitlines() or [''])[-1]}")
    return Verdict()


def plain(argv: list[str]) -> Callable[[Path], list[str]]:
    return lambda wd: list(argv)


# --- numbers that are not finite, or out of range -------------------------------------------


def float_values(p: click.Parameter) -> list[str]:
    """The values a float option must refuse: not finite, and below its minimum where it has one."""
    values = list(NOT_FINITE)
    lo = getattr(p.type, "min", None)
    if lo is not None:
        values.append(f"{lo - 1:g}")
        if getattr(p.type, "min_open", False):
            values.append(f"{lo:g}")
    hi = getattr(p.type, "max", None)
    if hi is not None:
        values.append(f"{hi * 10 + 1:g}")
    return values


def without(args: list[str], opts) -> list[str]:
    """``args`` without the options ``opts`` and their values."""
    out, skip = [], False
    for a in args:
        if skip:
            skip = False
        elif a in opts:
            skip = True
        else:
            out.append(a)
    return out


def float_cases(cmd_path: tuple[str, ...], cmd: click.Command, base: Callable[[Path], list[str]]):
    """Every float option of the command with every value of :func:`float_values`, given first on
    the command line (click parses it before anything else; the base's own value of it left out);
    refused means exit 2 naming it."""
    for p in cmd.params:
        if isinstance(p, click.Argument) or not isinstance(p.type, click.types.FloatParamType):
            continue
        opt = p.opts[-1] if p.opts[-1].startswith("--") else p.opts[0]
        for v in float_values(p):
            yield Case(
                "floats",
                f"{opt} {v}",
                lambda wd, opt=opt, v=v, opts=tuple(p.opts): [*cmd_path, f"{opt}={v}", *without(base(wd), opts)],
                lambda wd, code, out, err, opt=opt: _refused(code, err, opt),
            )


def _refused(code, err, opt) -> Verdict:
    v = common(code, err)
    if not v.passed:
        return v
    if code == 0:
        return Verdict(false_ok=True, why="accepted")
    if code != 2 or opt not in err:
        return Verdict(
            other=True,
            why=f"not refused as bad input naming {opt} (exit {code}): {(err.strip().splitlines() or [''])[-1]}",
        )
    return Verdict()


def number_judge(value: str):
    def judge(wd, code, out, err) -> Verdict:
        v = common(code, err)
        if v.passed and code == 0 and value in NONSENSE:
            return Verdict(false_ok=True, why=f"{value} accepted")
        return v

    return judge


# --- databases that are not a vts-hw results store -----------------------------------------


def _foreign_sqlite(p: Path) -> None:
    con = sqlite3.connect(p)
    con.executescript(
        "CREATE TABLE patients (id INTEGER PRIMARY KEY, name TEXT, dob TEXT);"
        "INSERT INTO patients (name, dob) VALUES ('A B', '1950-01-01'), ('C D', '1961-02-03');"
        "CREATE TABLE visits (id INTEGER PRIMARY KEY, patient INTEGER, at REAL);"
    )
    con.commit()
    con.close()


def _not_sqlite(p: Path) -> None:
    p.write_text("a lab notebook, not a database\n" * 100)


def _empty_sqlite(p: Path) -> None:
    con = sqlite3.connect(p)
    con.execute("VACUUM")
    con.close()


FOREIGN_KINDS = {"foreign SQLite": _foreign_sqlite, "not SQLite": _not_sqlite, "empty SQLite": _empty_sqlite}
FOREIGN_NAME = "their.db"


def sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "missing"


def _foreign_file(wd: Path, kind: str) -> Path:
    p = wd / FOREIGN_NAME
    FOREIGN_KINDS[kind](p)
    (wd / ".foreign.sha256").write_text(sha(p))
    return p


def foreign_judge(wd: Path, code, out, err) -> Verdict:
    """The database is byte-identical with nothing beside it; a command that opened it refused it
    in one sentence (exit 3)."""
    p = wd / FOREIGN_NAME
    v = common(code, err)
    beside = [q.name for q in wd.iterdir() if q.name.startswith(FOREIGN_NAME) and q.name != FOREIGN_NAME]
    if sha(p) != (wd / ".foreign.sha256").read_text() or beside:
        v.damaged, v.why = True, f"the database changed ({', '.join(beside) or 'its bytes'})"
    opened = wd / OPENED
    v.opened = opened.exists() and str(p) in opened.read_text()
    if v.opened and not (v.hang or v.traceback):
        if code == 0:
            v.false_ok, v.why = True, "it used a database that is not a vts-hw results store"
        elif code != 3 or not any(w in err for w in ("not a vts-hw results store", "empty database")):
            v.other, v.why = True, f"exit {code} without saying the store is not one: {err.strip()[-160:]}"
    return v


def foreign_cases(cmd_path: tuple[str, ...], base: Callable[[Path], list[str]], extra: list[str]):
    """The command with ``--store`` naming each kind of database that is not a store."""
    for kind in FOREIGN_KINDS:
        yield Case(
            "foreign stores",
            f"--store {kind}",
            lambda wd, kind=kind: ["--store", str(_foreign_file(wd, kind)), *cmd_path, *base(wd), *extra],
            foreign_judge,
        )


def store_command_cases(fx) -> list[Case]:
    """The store's own commands and the ones that reach the store only with good inputs."""
    out = []
    for kind in FOREIGN_KINDS:

        def good(wd):
            from vts_hw.store import ResultsStore

            with ResultsStore(wd / "ours.sqlite") as s, s.begin_run("daily", rig="dead") as h:
                h.measure("cam1", "drift_x_px", 0.1, "px")
            return str(wd / "ours.sqlite")

        out += [
            Case(
                "foreign stores",
                f"store migrate --from {kind}",
                lambda wd, kind=kind: [
                    "store",
                    "migrate",
                    "--from",
                    str(_foreign_file(wd, kind)),
                    "--to",
                    str(wd / "new.sqlite"),
                ],
                foreign_judge,
            ),
            Case(
                "foreign stores",
                f"store migrate --to {kind}",
                lambda wd, kind=kind, good=good: [
                    "store",
                    "migrate",
                    "--from",
                    good(wd),
                    "--to",
                    str(_foreign_file(wd, kind)),
                ],
                foreign_judge,
            ),
            Case(
                "foreign stores",
                f"qa drift --set-baseline, {kind}",
                lambda wd, kind=kind: [
                    "--store",
                    str(_foreign_file(wd, kind)),
                    "qa",
                    "drift",
                    "--set-baseline",
                    "--config",
                    fx.dead_config,
                ],
                foreign_judge,
            ),
            Case(
                "foreign stores",
                f"qa import (a good run file), {kind}",
                lambda wd, kind=kind: [
                    "--store",
                    str(_foreign_file(wd, kind)),
                    "qa",
                    "import",
                    _unsaved(wd),
                    "--config",
                    fx.dead_config,
                ],
                foreign_judge,
            ),
        ]
        if kind != "empty SQLite":  # `store init` makes an empty one a store: that is its job
            out.append(
                Case(
                    "foreign stores",
                    f"store init {kind}",
                    lambda wd, kind=kind: ["store", "init", str(_foreign_file(wd, kind))],
                    foreign_judge,
                )
            )
    # a command that stores its result only after its work: a calibration from the real
    # checkerboard pairs (../shared/data, as the tests find them)
    boards = shared_data() / "stereo-checkerboard"
    if boards.is_dir():
        out.append(
            Case(
                "foreign stores",
                "calibrate stereo (the real pairs), foreign SQLite",
                lambda wd: [
                    "--store",
                    str(_foreign_file(wd, "foreign SQLite")),
                    "calibrate",
                    "stereo",
                    str(boards),
                    "--square",
                    "30",
                    "-o",
                    str(wd / "cal.json"),
                ],
                foreign_judge,
            )
        )
    return out


def shared_data() -> Path:
    """The real data the tests read: $VTS_SHARED_DATA, else ../shared/data beside the checkout."""
    import os

    env = os.environ.get("VTS_SHARED_DATA")
    return Path(env) if env else Path(__file__).resolve().parents[3] / "shared" / "data"


def _unsaved(wd: Path) -> str:
    from vts_hw.store.unsaved import FORMAT

    p = wd / "unsaved-run.json"
    p.write_text(
        json.dumps(
            {
                "format": FORMAT,
                "procedure": "daily",
                "rig": "dead",
                "started": 1.8e9,
                "finished": 1.8e9 + 5,
                "state": "OK",
                "measurements": [
                    {"subject": "cam1", "metric": "drift_x_px", "value": 0.1, "unit": "px", "state": "OK"}
                ],
            }
        )
    )
    return str(p)


def probe_stores() -> None:
    """In a case's child: note each store a command opens (its URL) in ./.store-opened."""
    from vts_hw.store import store as module

    original = module.ResultsStore.__init__

    def init(self, url=None, *args, **kwargs):
        with open(OPENED, "a") as f:
            f.write(f"{getattr(url, 'url', url)}\n")
        return original(self, url, *args, **kwargs)

    module.ResultsStore.__init__ = init


__all__ = [
    "Case",
    "Verdict",
    "common",
    "plain",
    "float_cases",
    "number_judge",
    "foreign_cases",
    "store_command_cases",
    "probe_stores",
    "EXIT_OK",
    "NONSENSE",
]
