"""Writers replace nothing that is not theirs (issue 32 §2, decision 0081): every command that
writes a file or into a folder, given a name that is a device node, a FIFO, a symbolic link, or
a folder where a file is meant (a file where a folder is), says so in one sentence naming it,
exits 3, and leaves it exactly as it was, with no temporary file beside it.

In-process (tests/inprocess_cli.py): the refusal comes when the command line is read, before a
camera is opened or a library loaded. The character device is a copy of /dev/null made with
mknod in tmp_path (root only; CI runs as root); the real /dev is never written. Opening a FIFO
to write would block: every case runs under an alarm, so a hang is a failure, not a stuck run.
"""

from __future__ import annotations

import os
import secrets
import signal
import stat
from pathlib import Path

import click
import pytest

from inprocess_cli import vts
from vts_hw.cli import cli
from vts_hw.cli.common import OutputFile, OutputFolder
from vts_hw.errors import DataError
from vts_hw.files import NotReplaced, WriteFailed, open_fd, write_atomic
from vts_hw.recording.writer import Recording
from vts_hw.save_or_keep import save_or_keep

#: commands that write one file: (name, its arguments with the file T)
FILE_WRITERS = {
    "camera snapshot -o": lambda t: ["camera", "snapshot", "cam1", "-o", t],
    "report drift -o": lambda t: ["report", "drift", "-o", t],
    "report rooms -o": lambda t: ["report", "rooms", "-o", t],
    "calibrate stereo -o": lambda t: ["calibrate", "stereo", "--sim", "-o", t],
    "calibrate cameras -o": lambda t: ["calibrate", "cameras", "--sim", "-o", t],
    "calibrate spect -o": lambda t: ["calibrate", "spect", "--sim", "-o", t],
    "discover -o": lambda t: ["discover", "-o", t],
    "motion analyze -o": lambda t: ["motion", "analyze", "session", "-o", t],
    "motion analyze --plot": lambda t: ["motion", "analyze", "session", "--plot", t],
    "sync analyze -o": lambda t: ["sync", "analyze", "session", "-o", t],
    "sync analyze --plot": lambda t: ["sync", "analyze", "session", "--plot", t],
    "trigger status --log": lambda t: ["trigger", "status", "--log", t],
    "store init (the store file)": lambda t: ["store", "init", t],
}
#: commands that write into a folder: (name, its arguments with the folder T)
FOLDER_WRITERS = {
    "camera record -o": lambda t: ["camera", "record", "cam1", "-o", t],
    "camera aim --out": lambda t: ["camera", "aim", "cam1", "--out", t],
    "scan start -o": lambda t: ["scan", "start", "-o", t],
    "qa steps -o": lambda t: ["qa", "steps", "-o", t],
    "demo -o": lambda t: ["demo", "-o", t],
    "sim up --dir": lambda t: ["sim", "up", "--dir", t],
    "motion analyze --export": lambda t: ["motion", "analyze", "session", "--export", t],
    "sync analyze --export": lambda t: ["sync", "analyze", "session", "--export", t],
    "commission -o": lambda t: ["commission", "-o", t],
    "recording process -o": lambda t: ["recording", "process", "session", "-o", t],
}
KINDS = ("char device", "FIFO", "symlink", "wrong kind")  # wrong kind: a folder for a file, a file for a folder
AS_ROOT = os.geteuid() == 0
NULL = os.makedev(1, 3)  # /dev/null's numbers: writing to the copy is harmless


def make_target(root: Path, kind: str, folder: bool) -> tuple[Path, callable]:
    """The bad target ``root/target`` of ``kind``, and a function returning what must not change."""
    t = root / "target"
    elsewhere = root / "elsewhere"
    elsewhere.mkdir()
    if kind == "char device":
        if not AS_ROOT:
            pytest.skip("a device node is made with mknod as root (CI runs as root)")
        os.mknod(t, stat.S_IFCHR | 0o666, NULL)
    elif kind == "FIFO":
        os.mkfifo(t)
    elif kind == "symlink":  # to a file (or folder) another user may care about
        real = elsewhere / ("folder" if folder else "passwd")
        if folder:
            real.mkdir()
            (real / "keep.txt").write_bytes(b"theirs\n")
        else:
            real.write_bytes(b"root:x:0:0:root:/root:/bin/bash\n")
        t.symlink_to(real)
    elif folder:
        t.write_bytes(b"a file where a folder is meant\n")
    else:
        t.mkdir()

    def state():
        st = os.lstat(t)
        inside = sorted(p.relative_to(root).as_posix() for p in root.rglob("*"))  # no temporary file anywhere
        content = {
            p: (root / p).read_bytes()
            for p in inside
            if (root / p).is_file() and not (root / p).is_symlink() and stat.S_ISREG(os.lstat(root / p).st_mode)
        }
        return (stat.S_IFMT(st.st_mode), st.st_rdev, os.readlink(t) if t.is_symlink() else None, inside, content)

    return t, state


@pytest.fixture()
def no_hang():
    """A case that blocks (opening a FIFO to write with no reader) fails instead of hanging."""

    def ring(signum, frame):
        raise TimeoutError("the command blocked: a FIFO opened to write?")

    old = signal.signal(signal.SIGALRM, ring)
    signal.setitimer(signal.ITIMER_REAL, 60)
    yield
    signal.setitimer(signal.ITIMER_REAL, 0)
    signal.signal(signal.SIGALRM, old)


CASES = [(c, k, False) for c in FILE_WRITERS for k in KINDS] + [(c, k, True) for c in FOLDER_WRITERS for k in KINDS]


@pytest.mark.parametrize("command,kind,folder", CASES, ids=[f"{c} onto {k}" for c, k, _ in CASES])
def test_a_writer_refuses_a_target_that_is_not_its_kind_and_leaves_it_as_it_was(
    tmp_path, capsys, monkeypatch, no_hang, command, kind, folder
):
    monkeypatch.chdir(tmp_path)  # no rig.yaml: the refusal comes before one is looked for
    target, state = make_target(tmp_path, kind, folder)
    before = state()
    args = (FOLDER_WRITERS if folder else FILE_WRITERS)[command](str(target))
    code, out, err = vts(capsys, *args)
    lines = err.strip().splitlines()
    assert code == 3, (code, err)
    assert len(lines) == 1 and lines[0].startswith("vts: ") and str(target) in lines[0], err
    assert "Traceback" not in err and out == ""
    assert state() == before  # the node, the link and what it points to, byte for byte


#: the names of the options (and arguments) that name what a command writes
OUTPUT_NAMES = {"-o", "--out", "--output", "--plot", "--log", "--export", "--dir"}
#: a --dir that names what a command reads, not what it writes
READS = {("sim", "down"): "--dir"}


def _commands(cmd, path=()):
    if isinstance(cmd, click.Group):
        ctx = click.Context(cmd)
        for name in cmd.list_commands(ctx):
            yield from _commands(cmd.get_command(ctx, name), (*path, name))
    else:
        yield path, cmd


def test_every_output_of_every_command_is_checked_when_the_command_line_is_read():
    """The class, not the instances above: an option naming what a command writes is an
    OutputFile or an OutputFolder (a new command's -o cannot slip past the check)."""
    seen, plain = 0, []
    for path, cmd in _commands(cli):
        for p in cmd.params:
            if not OUTPUT_NAMES & set(p.opts) or READS.get(path) in p.opts:
                continue
            seen += 1
            if not isinstance(p.type, (OutputFile, OutputFolder)):
                plain.append(f"vts {' '.join(path)} {'/'.join(p.opts)}")
    assert seen >= 25 and plain == [], plain
    named = {c.split(" -")[0] for c in [*FILE_WRITERS, *FOLDER_WRITERS]}
    assert len(named) >= 18, named


# -- the writers themselves: checked again when they write (the target may change meanwhile) --


def test_write_atomic_refuses_a_target_that_became_a_fifo_while_it_wrote(tmp_path, monkeypatch):
    """The race: a regular file when the command started, a FIFO by the time of the rename."""
    target = tmp_path / "report.html"
    target.write_text("old\n")
    real_fsync = os.fsync

    def swap(fd):
        real_fsync(fd)
        target.unlink()
        os.mkfifo(target)

    monkeypatch.setattr(os, "fsync", swap)
    with pytest.raises(NotReplaced) as err:
        write_atomic(target, "new\n")
    assert isinstance(err.value, DataError) and err.value.exit_code == 3
    assert "named pipe (FIFO)" in str(err.value) and str(target) in str(err.value)
    assert stat.S_ISFIFO(os.lstat(target).st_mode)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.html"]  # no temporary file left


def test_a_temporary_name_planted_beforehand_is_never_opened(tmp_path, monkeypatch):
    """Another user who may write into the folder (/tmp) plants a link at the name of the
    temporary file (it was .NAME.PID.tmp, opened with O_TRUNC: root emptied the file it points
    to). The name is random now and created exclusively: a planted one is passed over."""
    victim = tmp_path / "victim"
    victim.write_bytes(b"root's file\n")
    target = tmp_path / "report.html"
    for name in (f".report.html.{os.getpid()}.tmp", ".report.html.planted.tmp"):
        (tmp_path / name).symlink_to(victim)
    names = iter(["planted", "fresh"])
    monkeypatch.setattr(secrets, "token_hex", lambda n=None: next(names))
    write_atomic(target, "the report\n")
    assert target.read_text() == "the report\n" and victim.read_bytes() == b"root's file\n"


def test_an_appending_writer_never_opens_a_fifo_or_writes_through_a_link(tmp_path, no_hang):
    os.mkfifo(tmp_path / "trigger.csv")
    with pytest.raises(NotReplaced, match="named pipe"):
        open_fd(tmp_path / "trigger.csv")
    (tmp_path / "theirs").write_bytes(b"theirs\n")
    (tmp_path / "cam1.mjpeg").symlink_to(tmp_path / "theirs")
    with pytest.raises(NotReplaced, match="symbolic link"):
        open_fd(tmp_path / "cam1.mjpeg")
    assert (tmp_path / "theirs").read_bytes() == b"theirs\n"


def test_a_recording_refuses_a_file_name_in_its_folder_that_is_not_a_regular_file(tmp_path, no_hang):
    """An appended recording whose new camera's .mjpeg is a FIFO (the append blocked on it) or a
    symbolic link (the frames went into the file it points to)."""
    rec = tmp_path / "rec"
    with Recording(rec, ["cam1"]) as r:
        r.write_frame("cam1", b"\xff\xd8frame\xff\xd9", 1.0, 1.0)
    os.mkfifo(rec / "cam2.mjpeg")
    with pytest.raises(WriteFailed, match=r"cam2\.mjpeg: could not be written \(it is a named pipe"):
        Recording(rec, ["cam2"], append=True)
    assert stat.S_ISFIFO(os.lstat(rec / "cam2.mjpeg").st_mode)
    (tmp_path / "theirs").write_bytes(b"theirs\n")
    os.unlink(rec / "cam2.mjpeg")
    (rec / "cam2.mjpeg").symlink_to(tmp_path / "theirs")
    with pytest.raises(WriteFailed, match="symbolic link"):
        Recording(rec, ["cam2"], append=True)
    assert (tmp_path / "theirs").read_bytes() == b"theirs\n"


def test_a_calibration_whose_target_is_refused_at_write_time_goes_to_the_fallback_file(tmp_path, monkeypatch):
    """save_or_keep (calibrations, mappings): the work is not lost to a target that is not a file."""
    monkeypatch.chdir(tmp_path)
    os.mkfifo(tmp_path / "calibration.json")
    saved = save_or_keep(tmp_path / "calibration.json", '{"rms": 0.2}\n', "calibration")
    assert saved.written is None and saved.fallback is not None and saved.fallback.read_text() == '{"rms": 0.2}\n'
    assert "named pipe" in str(saved.error) and f"saved to {saved.fallback} instead" in str(saved.error)
    assert stat.S_ISFIFO(os.lstat(tmp_path / "calibration.json").st_mode)


def test_camera_setup_refuses_a_rig_yaml_it_cannot_replace_before_any_camera_is_set(tmp_path, capsys, monkeypatch):
    """rig.yaml a symbolic link (to the department's copy): said before a camera is touched (the
    camera here is nowhere: reaching it would be exit 4)."""
    real = tmp_path / "department" / "rig.yaml"
    real.parent.mkdir()
    real.write_text("rig: t\ncameras:\n  - name: cam1\n    host: 127.0.0.1\n    port: 9\n    password_env: T_PW\n")
    (tmp_path / "rig.yaml").symlink_to(real)
    monkeypatch.setenv("T_PW", "secret")
    before = real.read_bytes()
    code, out, err = vts(capsys, "camera", "setup", "--all", "--config", tmp_path / "rig.yaml")
    assert code == 3 and "symbolic link" in err and str(tmp_path / "rig.yaml") in err, err
    assert real.read_bytes() == before and (tmp_path / "rig.yaml").is_symlink()
    assert not (tmp_path / "rig.yaml.bak").exists()
