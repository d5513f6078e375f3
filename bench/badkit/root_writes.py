"""The class "root writes" of bench/bad_inputs.py (issue 32 §2 and §5): every file and folder a
command writes (its output parameters, read from the command tree as the ``paths`` class reads
them), given a target that is not a regular file it may replace:

* ``device``: a character device made with mknod in the case's folder (the twin of /dev/null:
  anything written "succeeds"; never the real /dev nodes), when the sweep runs as root; a FIFO
  otherwise;
* ``FIFO``: a named pipe nobody reads (whoever opens it to write waits for ever);
* ``symlink``: a link to a regular file elsewhere (outside the case's output place);
* ``directory``: a folder holding a file of its own, where a file is wanted (where a folder is
  wanted, the folder's own file must be left as it is).

Each command runs with good inputs where badkit/full_disk.py's table has a command line for it
(the simulated rig, a recording, a store with runs: it gets as far as writing), else with the
sweep's harmless base (it may stop before writing: then only the node's fate is judged).

Files a command writes *inside* a folder it is given by name (``INSIDE``: `motion analyze --export`'s
YRT-PET and CASToR files, which an export also removes when an earlier one left them) get the same
nodes at their names in that folder (the whole sweep only: a motion analysis each): the command must
leave the node as it is and say so (it has nothing to write there without a list-mode).

A case passes when the command ends (no hang) without a traceback, with a documented exit, and:
the node is what it was (a device with the same numbers, a FIFO, the folder with its file, the
link still a link to the same place); a device, FIFO or folder-for-a-file is refused (not exit 0:
a false OK) in one ``vts:`` sentence; a link is either followed (exit 0, its target written, the
link kept) or refused (its target unchanged): replaced by a file of its own is data damaged.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import click

from badkit.classes import Case, Verdict, common, sha

CLASS = "root writes"
KINDS = ("device", "FIFO", "symlink", "directory")
#: the parameters that name what a command writes (the paths class's OUTPUTS, and the trigger logs)
WRITTEN = {"out", "output", "export_dir", "plot_path", "folder", "out_dir", "log_path"}
#: commands whose parameter of such a name is only read (`sim down --dir` reads the pid file there)
READ_ONLY = {("sim", "down")}
#: folder outputs given an existing folder run their whole job (the demo: minutes; sim up: a rig left
#: running in the background): not that kind
WHOLE_JOB = {("demo",), ("sim", "up")}
#: files a command writes inside a folder output, by name (issue 33 §2): (the folder's parameter, names)
INSIDE = {("motion", "analyze"): ("export_dir", ("yrtpet_lor_motion.csv", "castor_motion.dyn"))}
NULL_DEV = os.makedev(1, 3)  # the numbers of /dev/null: a twin made in the case's folder
TARGET_TEXT = b"the file a link points at: not the command's\n"
KEEP_TEXT = b"a file of the folder's own\n"


def written(p: click.Parameter) -> bool:
    return isinstance(p.type, (click.Path, click.File)) and p.name in WRITTEN


def wants_folder(p: click.Parameter) -> bool:
    return getattr(p.type, "dir_okay", True) and not getattr(p.type, "file_okay", True)


def make_node(wd: Path, kind: str, name: str) -> Path:
    """The target of ``kind`` in the case's folder ``wd`` (the link's target in ``wd/elsewhere``)."""
    node = wd / "target" / name
    node.parent.mkdir(parents=True, exist_ok=True)
    if kind == "device":
        if os.geteuid() == 0:
            os.mknod(node, stat.S_IFCHR | 0o666, NULL_DEV)
        else:
            os.mkfifo(node)
    elif kind == "FIFO":
        os.mkfifo(node)
    elif kind == "symlink":
        target = wd / "elsewhere" / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(TARGET_TEXT)
        node.symlink_to(target)
    else:
        node.mkdir()
        (node / "keep.txt").write_bytes(KEEP_TEXT)
    return node


def node_fate(wd: Path, kind: str, node: Path) -> str:
    """'' when the node is what :func:`make_node` made, else what became of it."""
    try:
        st = os.lstat(node)
    except FileNotFoundError:
        return "it is gone"
    if kind == "device" and os.geteuid() == 0:
        if not stat.S_ISCHR(st.st_mode) or st.st_rdev != NULL_DEV:
            return f"the device node was replaced ({_what(st)})"
    elif kind in ("device", "FIFO"):
        if not stat.S_ISFIFO(st.st_mode):
            return f"the FIFO was replaced ({_what(st)})"
    elif kind == "symlink":
        if not stat.S_ISLNK(st.st_mode):
            return f"the link was replaced ({_what(st)})"
        if os.readlink(node) != str(wd / "elsewhere" / node.name):
            return "the link points elsewhere now"
    else:
        if not stat.S_ISDIR(st.st_mode):
            return f"the folder was replaced ({_what(st)})"
        if (node / "keep.txt").read_bytes() != KEEP_TEXT if (node / "keep.txt").exists() else True:
            return "the folder's own file was changed or removed"
    return ""


def _what(st) -> str:
    return (
        "a regular file"
        if stat.S_ISREG(st.st_mode)
        else "a folder"
        if stat.S_ISDIR(st.st_mode)
        else "a link"
        if stat.S_ISLNK(st.st_mode)
        else "something else"
    )


def _judge(kind: str, folder: bool, opt: str):
    def judge(wd: Path, code, out, err) -> Verdict:
        v = common(code, err)
        node = Path((wd / ".node").read_text())
        fate = node_fate(wd, kind, node)
        if fate:
            v.damaged, v.why = True, f"{fate} ({opt} {node.name})"
            return v
        if not v.passed:
            return v
        last = (err.strip().splitlines() or [""])[-1]
        if kind == "symlink":
            target = wd / "elsewhere" / node.name
            followed = sha(target) != sha_text(TARGET_TEXT)
            if code == 0 and not followed and not folder:
                return Verdict(false_ok=True, why=f"exit 0, yet the link's target was not written ({opt})")
            if code == 0 and folder:
                return Verdict(false_ok=True, why=f"exit 0 with {opt} a link to a file")
            if code != 0 and followed:
                return Verdict(damaged=True, why=f"exit {code}, yet the link's target was changed: {last[:120]}")
            return v
        if kind == "directory" and folder:
            return v  # a folder where a folder is wanted: its own file kept (node_fate)
        if code == 0:
            return Verdict(false_ok=True, why=f"exit 0 with {opt} a {kind}")
        if not last.startswith(("vts: ", "Error: ")):  # (click's usage errors start "Error:")
            return Verdict(other=True, why=f"exit {code} without one sentence: {last[:160]}")
        return v

    return judge


def sha_text(data: bytes) -> str:
    import hashlib

    return hashlib.sha256(data).hexdigest()


def cases(cmd_path: tuple[str, ...], cmd: click.Command, base: list[str], good, replace, full: bool) -> list[Case]:
    """One command's cases: each output parameter onto each kind of node (``full``), or each
    output parameter once, the kinds taken in turn (make test's share). ``good(wd, D)``: the
    command line of full_disk's table for this command (outputs in D; replaced here), else
    ``base`` (the command's own words and harmless values)."""
    out = []
    params = [] if cmd_path in READ_ONLY else [p for p in cmd.params if written(p)]
    for i, p in enumerate(params):
        opt = None if isinstance(p, click.Argument) else (p.opts[-1] if p.opts[-1].startswith("--") else p.opts[0])
        folder = wants_folder(p)
        kinds = [k for k in KINDS if not (folder and k == "directory" and cmd_path in WHOLE_JOB)]
        for j, kind in enumerate(kinds):
            if not full and j != (i + len(cmd_path[0])) % len(kinds):
                continue

            def make(wd: Path, p=p, opt=opt, kind=kind, folder=folder) -> list[str]:
                D = wd / "D"
                D.mkdir(exist_ok=True)
                argv = good(wd, D) if good is not None else [*cmd_path, *base]
                node = make_node(wd, kind, "out.d" if folder else f"out{_suffix(argv, p)}")
                (wd / ".node").write_text(str(node))
                return _put(argv, p, opt, str(node), replace)

            out.append(
                Case(CLASS, f"{' '.join(cmd_path)} {opt or p.name}: {kind}", make, _judge(kind, folder, opt or p.name))
            )
    if full and good is not None and cmd_path in INSIDE:
        out += _inside_cases(cmd_path, cmd, good, replace)
    return out


def _inside_cases(cmd_path, cmd, good, replace) -> list[Case]:
    """The nodes at the names of :data:`INSIDE` in the command's folder output (the good command
    line writes nothing there: no list-mode): each must be left as it is, and said."""
    pname, names = INSIDE[cmd_path]
    p = next(q for q in cmd.params if q.name == pname)
    opt = p.opts[-1]
    out = []
    for name in names:
        for kind in KINDS:

            def make(wd: Path, name=name, kind=kind) -> list[str]:
                D = wd / "D"
                D.mkdir(exist_ok=True)
                node = make_node(wd, kind, name)  # wd/target/<name>: wd/target is the folder
                (wd / ".node").write_text(str(node))
                return _put(good(wd, D), p, opt, str(node.parent), replace)

            out.append(
                Case(CLASS, f"{' '.join(cmd_path)} {opt} holding {name}: {kind}", make, _judge_inside(kind, name))
            )
    return out


def _judge_inside(kind: str, name: str):
    def judge(wd: Path, code, out, err) -> Verdict:
        v = common(code, err)
        node = Path((wd / ".node").read_text())
        fate = node_fate(wd, kind, node)
        if fate:
            return Verdict(damaged=True, why=f"{fate} ({name} in the export folder)")
        if v.passed and code in (0, 10, 20) and f"{name} there is" not in out + err:
            return Verdict(other=True, why=f"exit {code}, {name} in the export folder ({kind}) left unsaid")
        return v

    return judge


def _suffix(argv: list[str], p: click.Parameter) -> str:
    """The suffix the output had in the good command line (a report .html, a plot .png), if any."""
    for opt in getattr(p, "opts", []):
        if opt in argv and argv.index(opt) + 1 < len(argv):
            return Path(argv[argv.index(opt) + 1]).suffix
    return ".out"


def _put(argv: list[str], p: click.Parameter, opt: str | None, value: str, replace) -> list[str]:
    """``argv`` with ``p`` given ``value`` (any of its spellings replaced; an argument: the value
    in its place among the words after the command's, through the sweep's ``replace``)."""
    for o in getattr(p, "opts", []):
        if o in argv:
            out = list(argv)
            out[out.index(o) + 1] = value
            return out
    if isinstance(p, click.Argument):
        n = next((i for i, a in enumerate(argv) if a == "--store"), None)
        head = argv[: n + 2] if n == 0 else []
        rest = argv[len(head) :]
        k = len(_words(rest))
        return [*head, *rest[:k], *replace(rest[k:], p, opt, value)]
    return [*argv, opt, value]


def _words(argv: list[str]) -> list[str]:
    """The command's words at the start of ``argv`` (up to the first option or path)."""
    out = []
    for a in argv:
        if a.startswith("-") or "/" in a or len(out) == 2:
            break
        out.append(a)
    return out


__all__ = ["CLASS", "cases", "written", "KINDS"]
