"""Endless and huge inputs (issue 21, second round): every reader of a user's file bounds what it
reads. `/dev/zero`, a pipe, or a huge (sparse) file given where a recording, config, calibration,
mapping, trigger log or JSON import is wanted is refused in one sentence naming it (exit 2 or 3)
within seconds of CPU, instead of growing by a gigabyte a second and ignoring Ctrl-C. (The CPU
time the command took is what is bounded: on a busy machine the wall time of the same refusal
grows with the load -- 39 s was seen under 4 busy processes on 2 cores.)

`vts` runs as a subprocess with its address space capped (4 GiB), so a reader that reads
without a bound fails here fast (MemoryError, a traceback) instead of filling the machine.
"""

import json
import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vts_hw.bounded import TooLarge, read_bytes

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]
CAP = 4 * 2**30


def _capped():
    resource.setrlimit(resource.RLIMIT_AS, (CAP, CAP))


def vts(*args, cwd=None, timeout=60):
    env = dict(os.environ)
    for k in ("VTS_CONFIG", "VTS_STORE"):
        env.pop(k, None)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run(
        [*VTS, *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=cwd, env=env, preexec_fn=_capped
    )
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    p.cpu_seconds = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    return p


def _sparse(path: Path, size: int = 8 * 2**30) -> Path:
    with open(path, "wb") as f:
        f.truncate(size)
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """/dev/zero, a FIFO and huge sparse files, and recordings whose parts are them."""
    d = tmp_path_factory.mktemp("endless")
    fifo = d / "fifo"
    os.mkfifo(fifo)
    _sparse(d / "huge.mjpg")
    _sparse(d / "huge.yaml")
    _sparse(d / "huge.json")
    for name, target in (("zero_manifest", "/dev/zero"), ("huge_manifest", str(d / "huge.json"))):
        rec = d / name
        rec.mkdir()
        (rec / "cam1.mjpeg").write_bytes(b"")
        (rec / "cam1.index.csv").write_text("frame,offset,length,camera_time,host_time\n")
        (rec / "manifest.json").symlink_to(target)
    rec = d / "fifo_mjpeg"
    rec.mkdir()
    (rec / "cam1.index.csv").write_text("frame,offset,length,camera_time,host_time\n")
    (rec / "cam1.mjpeg").symlink_to(fifo)
    rec = d / "zero_index"
    rec.mkdir()
    (rec / "cam1.mjpeg").write_bytes(b"")
    (rec / "cam1.index.csv").symlink_to("/dev/zero")
    (d / "rig.yaml").write_text(
        f"rig: t\ncameras:\n  - name: cam1\n    host: 127.0.0.1\nresults:\n  url: sqlite:///{d / 'results.sqlite'}\n"
    )
    (d / "bad_trigger_log.csv").symlink_to("/dev/zero")
    return d


CASES = {
    "recording info /dev/zero": lambda d: ["recording", "info", "/dev/zero"],
    "recording info FIFO": lambda d: ["recording", "info", d / "fifo"],
    "recording info 8 GiB .mjpg": lambda d: ["recording", "info", d / "huge.mjpg"],
    "motion analyze, manifest /dev/zero": lambda d: [
        "motion",
        "analyze",
        d / "zero_manifest",
        "--calibration",
        d / "huge.json",
        "--config",
        d / "rig.yaml",
    ],
    "recording info, index /dev/zero": lambda d: ["recording", "info", d / "zero_index"],
    "recording reindex, manifest /dev/zero": lambda d: ["recording", "reindex", d / "zero_manifest"],
    "motion analyze, manifest 8 GiB": lambda d: [
        "motion",
        "analyze",
        d / "huge_manifest",
        "--calibration",
        d / "huge.json",
        "--config",
        d / "rig.yaml",
    ],
    "motion analyze --calibration /dev/zero": lambda d: [
        "motion",
        "analyze",
        d / "zero_index",
        "--calibration",
        "/dev/zero",
        "--config",
        d / "rig.yaml",
    ],
    "sync analyze --mapping /dev/zero": lambda d: [
        "sync",
        "analyze",
        d / "zero_index",
        "--mapping",
        "/dev/zero",
        "--config",
        d / "rig.yaml",
    ],
    "--config /dev/zero": lambda d: ["store", "info", "--config", "/dev/zero"],
    "--config 8 GiB": lambda d: ["store", "info", "--config", d / "huge.yaml"],
    "--config FIFO": lambda d: ["store", "info", "--config", d / "fifo"],
    "qa import /dev/zero": lambda d: ["qa", "import", "/dev/zero", "--config", d / "rig.yaml"],
    "qa import 8 GiB": lambda d: ["qa", "import", d / "huge.json", "--config", d / "rig.yaml"],
    "calibrate spect --vts /dev/zero": lambda d: [
        "calibrate",
        "spect",
        "--vts",
        "/dev/zero",
        "--volume",
        d / "huge.json",
        "--config",
        d / "rig.yaml",
        "-o",
        d / "o.json",
    ],
    "trigger status --log /dev/zero": lambda d: [
        "trigger",
        "status",
        "--log",
        d / "bad_trigger_log.csv",
        "--config",
        d / "rig.yaml",
    ],
    # found by bench/bad_inputs.py --classes endless: appending to a FIFO blocked for ever
    "trigger status --log FIFO": lambda d: ["trigger", "status", "--log", d / "fifo", "--config", d / "rig.yaml"],
    # ... and a device as the images folder was a traceback (NotADirectoryError)
    "calibrate cameras /dev/zero": lambda d: ["calibrate", "cameras", "/dev/zero", "--config", d / "rig.yaml"],
    # issue 32 §3: the firmware to flash was read by intelhex without a bound (a FIFO: for ever)
    "trigger flash --hex /dev/zero --dry-run": lambda d: ["trigger", "flash", "--hex", "/dev/zero", "--dry-run"],
    "trigger flash --hex FIFO --dry-run": lambda d: ["trigger", "flash", "--hex", d / "fifo", "--dry-run"],
    # ... and reindex opened a recording's .mjpeg that is a FIFO, and waited for ever
    "recording reindex, .mjpeg FIFO": lambda d: ["recording", "reindex", d / "fifo_mjpeg"],
}


@pytest.mark.parametrize("case", list(CASES))
def test_an_endless_or_huge_input_is_refused_in_one_sentence(files, case):
    args = CASES[case](files)
    p = vts(*args, cwd=files)
    assert "Traceback" not in p.stderr, p.stderr[-2000:]
    assert p.returncode in (2, 3, 4), (p.returncode, p.stderr)
    last = (p.stderr.strip().splitlines() or [""])[-1]
    assert last.startswith(("vts: ", "Error: ")), p.stderr
    assert p.cpu_seconds < 15, f"took {p.cpu_seconds:.0f} s of CPU"  # /dev/zero reads ~1 GB/s
    assert not list(files.glob("*.tmp")) and not (files / "o.json").exists()


def test_a_bounded_read_is_interrupted_by_ctrl_c(tmp_path):
    """A big file within the bound is read a chunk at a time: Ctrl-C stops it at once."""
    big = _sparse(tmp_path / "big.mjpg", 2**30)

    def alarm(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGALRM, alarm)
    t0 = time.monotonic()
    try:
        signal.setitimer(signal.ITIMER_REAL, 0.05)
        with pytest.raises(KeyboardInterrupt):
            read_bytes(big, limit=2**31, what="capture")
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert time.monotonic() - t0 < 5


def test_the_bound_names_the_file(tmp_path):
    f = tmp_path / "x.json"
    f.write_bytes(b"[" + b"0," * 600 + b"0]")
    with pytest.raises(TooLarge, match=r"x\.json: .* more than a calibration can be"):
        read_bytes(f, limit=1000, what="calibration")
    assert read_bytes(f, limit=2000) == f.read_bytes()
    with pytest.raises(TooLarge, match="/dev/zero: not a regular file.*must be a file"):
        read_bytes("/dev/zero")


def test_recording_info_still_reads_a_real_capture(axis_frames):
    p = vts("recording", "info", axis_frames / "t.mjpg", "--json")
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)[0]["frames"] > 0


def test_a_replay_camera_over_a_fifo_mjpeg_is_refused_not_waited_on(files, tmp_path):
    """A recording replayed as a camera (kind replay) whose .mjpeg is a FIFO: refused in one
    sentence (its open blocked for ever)."""
    from vts_hw.drivers.replay import ReplayCamera

    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / "cam1.index.csv").write_text("frame,offset,length,camera_time,host_time\n0,0,10,1.00,1000.000000\n")
    (rec / "cam1.mjpeg").symlink_to(files / "fifo")
    with pytest.raises(TooLarge, match="cam1.mjpeg: not a regular file but a device, pipe or socket"):
        ReplayCamera("cam1", rec)


def test_no_reader_checks_a_name_then_opens_it_again():
    """The class behind the FIFO hangs: a reader that checks a path (bounded.check_file) and then
    opens it by name may open another file, a FIFO swapped in meanwhile blocking it for ever. Every
    reader opens through bounded.open_checked (checked, opened without waiting, checked again)."""
    repo = Path(__file__).resolve().parents[2]
    found = [
        f"{p.relative_to(repo)}:{n}"
        for folder in ("vts_hw", "drivers", "procedures", "sim_devices")
        for p in (repo / folder).rglob("*.py")
        if p.name != "bounded.py"
        for n, line in enumerate(p.read_text().splitlines(), 1)
        if "check_file(" in line
    ]
    assert found == []
