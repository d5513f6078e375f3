"""No false "commissioned" (issue 32 §3-4, decision 0084), on the simulated rig over HTTP.

* The newest attempt of each step decides: a redo that failed (`--from mapping` without its
  volume, `--from cameras` with cam2 off the network) undoes the pass before it; `--resume` then
  runs that step again and never writes the report from the older runs; the rooms page says
  "incomplete" with what did not pass.
* The rooms page always gives the state with what was skipped ("TOLERANCE, 7 of 9 steps skipped").
* A "Press Enter" step with no terminal: one sentence, exit 2, stored with that reason (not as an
  interrupt); --room-clear answers the drift baseline's question.
* Killed is not finished: SIGTERM of the real `vts commission` in the warm-up is recorded aborted
  "stopped by SIGTERM", exit 130; after `kill -9` the step's running row is marked aborted by the
  next open and the next start says the step did not finish. Real signals to the real command;
  waits are deadlines on what it printed, never sleeps.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from inprocess_cli import vts
from vts_hw.config import dump_rig
from vts_hw.report.rooms import collect_rooms
from vts_hw.report.times import fmt_date
from vts_hw.sim_devices.rig import SimRig
from vts_hw.store import ResultsStore
from vts_hw.store.commission import load_state

pytestmark = pytest.mark.timeout(180)

SKIPPED = ("trigger", "aim", "warmup", "calibration", "mapping", "steps", "sync")
SKIPPED_WORDS = (
    "7 of 9 steps skipped (trigger box, aim and focus, warm-up, calibration, VTS → SPECT mapping, "
    "step test, sync check)"
)
VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


@pytest.fixture(scope="module")
def rig():
    r = SimRig(n_cameras=2, seed=8).start()
    try:
        with r.env():
            yield r
    finally:
        r.stop()


def _room(rig, folder: Path, warmup: str = "{interval_s: 0.2, samples: 3, frames: 1}") -> tuple[Path, str]:
    url = f"sqlite:///{folder / 'r.sqlite'}"
    y = folder / "rig.yaml"
    y.write_text(dump_rig(rig.config(rig_name="room5", results_url=url)) + f"warmup: {warmup}\n")
    return y, url


def _rooms_text(url: str) -> str:
    with ResultsStore(url) as store:
        (room,) = collect_rooms(store).rooms
        return room.commissioned_text()


def test_the_newest_attempt_of_each_step_decides_and_the_rooms_page_says_the_state(rig, tmp_path, capsys):
    y, url = _room(rig, tmp_path)
    base = [
        "commission",
        "--config",
        y,
        "-o",
        tmp_path / "c",
        "--listen",
        "0.2",
        "--interface",
        "127.0.0.1",
        "--frames",
        "1",
    ]
    skips = [a for s in SKIPPED for a in ("--skip", s)] + ["--why", "not part of this test"]

    # the drift baseline asks a person to clear the room: no terminal here (pytest's stdin), so it says so
    code, out, err = vts(capsys, *base, *skips)
    assert code == 2, err
    assert err.strip().splitlines()[-1] == (
        "vts: commissioning asks a person at the table ('Clear the table and the room (phantom and source marker "
        "away), LED rings on. Press Enter.') and stdin is not a terminal: run it at a terminal (`vts commission "
        "--resume`), or for the drift baseline give --room-clear"
    )
    with ResultsStore(url) as store:
        b = load_state(store, "room5").steps["baseline"]
        assert b.aborted and b.why().startswith("commissioning asks a person at the table")
        assert "interrupt" not in b.why() and "Abort" not in b.why()

    # answered beforehand: the report, TOLERANCE for the steps skipped, said on the rooms page with them
    code, out, err = vts(capsys, *base, "--resume", "--room-clear")
    assert code == 10, err
    assert "== discover and set up" not in err and "== drift baseline" in err
    assert f"of room5: TOLERANCE ({SKIPPED_WORDS.replace(' (', ': ', 1)[:-1]}) (not signed off)" in out, out
    with ResultsStore(url) as store:
        report = store.run(load_state(store, "room5").report_run)
    assert _rooms_text(url) == (
        f"commissioned on {fmt_date(report.started)}: TOLERANCE, {SKIPPED_WORDS} (not signed off)"
    )

    # a redo of the mapping that fails: --resume runs the mapping again and writes no report from the old runs
    code, out, err = vts(capsys, *base, "--from", "mapping")
    assert code == 2 and "needs --phantom-volume FILE" in err, err
    code, out, err = vts(capsys, *base, "--resume", "--room-clear")
    assert code == 2, err
    assert "its VTS → SPECT mapping step of " in err and "did not finish (the VTS → SPECT mapping needs" in err
    assert "== VTS → SPECT mapping" in err and "report:" not in out and "TOLERANCE" not in out
    assert _rooms_text(url).startswith("commissioning incomplete, not commissioned: VTS → SPECT mapping aborted; ")

    # cam2 off the network during a redo of the cameras: aborted; --resume starts there again, never "commissioned"
    rig.servers["cam2"].faults.offline = True
    try:
        code, out, err = vts(capsys, *base, "--from", "cameras")
        assert code == 4 and "cam2" in err.strip().splitlines()[-1], err
        code, out, err = vts(capsys, *base, "--resume", "--room-clear")
    finally:
        rig.servers["cam2"].faults.offline = False
    assert code == 4 and "== discover and set up the cameras" in err and "TOLERANCE" not in out, err
    assert "its discover and set up the cameras step of " in err and "did not finish (camera cam2 at " in err, err
    assert _rooms_text(url) == (  # the mapping no longer skipped: aborted
        "commissioning incomplete, not commissioned: discover and set up the cameras aborted; VTS → SPECT mapping "
        "aborted; 6 of 9 steps skipped (trigger box, aim and focus, warm-up, calibration, step test, sync check) "
        f"(its report of {fmt_date(report.started)}, TOLERANCE, no longer stands)"
    )
    with ResultsStore(url) as store:
        cams = [
            r
            for r in store.runs("commission-step")
            if r.notes.startswith("commissioning ") and " step cameras" in r.notes.splitlines()[0]
        ]
        assert [r.status for r in cams][-2:] == ["aborted", "aborted"]  # both attempts kept, each with why


def _start(y: Path, err: Path, *args) -> subprocess.Popen:
    return subprocess.Popen(
        [*VTS, "commission", "--config", str(y), "-o", str(y.parent / "c"), "--from", "warmup", *args],
        stdout=subprocess.DEVNULL,
        stderr=err.open("w"),
        stdin=subprocess.DEVNULL,
    )


def _wait_for(p: subprocess.Popen, err: Path, text: str, deadline_s: float = 90.0) -> None:
    end = time.monotonic() + deadline_s
    while text not in err.read_text():
        assert p.poll() is None, f"ended ({p.returncode}) before {text!r}: {err.read_text()}"
        assert time.monotonic() < end, f"no {text!r} within {deadline_s} s: {err.read_text()}"
        time.sleep(0.05)


def test_sigterm_and_kill_9_in_the_warmup_are_recorded_and_the_next_start_says_so(rig, tmp_path, capsys):
    y, url = _room(rig, tmp_path, "{interval_s: 600, samples: 3, frames: 1}")  # a sample, then a long wait
    err = tmp_path / "err.txt"

    p = _start(y, err)
    try:
        _wait_for(p, err, "sample 1 of 3")
        p.send_signal(signal.SIGTERM)
        assert p.wait(timeout=60) == 130, err.read_text()
    finally:
        p.kill()
    said = err.read_text()
    assert (
        "stopped by SIGTERM: the step under way is recorded as aborted; `vts commission --resume` runs it again" in said
        and said.strip().endswith("vts: interrupted")
        and "Traceback" not in said
    ), said
    with ResultsStore(url) as store:
        w = load_state(store, "room5").steps["warmup"]
        assert w.aborted and w.why() == "stopped by SIGTERM"

    p = _start(y, err)
    try:
        _wait_for(p, err, "sample 1 of 3")
        os.kill(p.pid, signal.SIGKILL)
        assert p.wait(timeout=60) == -signal.SIGKILL
    finally:
        p.kill()
    # the next start (a step that stops at once: the mapping without its volume) opens the store: the row the
    # killed process left running is marked aborted, and the start says the warm-up did not finish
    code, out, said = vts(capsys, "commission", "--config", y, "-o", tmp_path / "c", "--from", "mapping")
    assert code == 2, said
    assert "its warm-up step of " in said and f"did not finish (its process (pid {p.pid} " in said, said
    with ResultsStore(url) as store:
        w = load_state(store, "room5").steps["warmup"]
        assert w.aborted and w.why().startswith(f"its process (pid {p.pid} ") and "ended without finishing" in w.why()
