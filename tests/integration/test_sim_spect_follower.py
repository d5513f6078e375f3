"""The simulated SPECT beside a running rig (`vts sim up --trigger triggerbox --spect`), run
the way the documentation's "The sync check (scan time)" page says (docs/physics/sync.md):
`vts sim up --detach`, `vts scan start` twice, then
`vts sync analyze scan1 --listmode sim/spect/scan-*.vtslm` through a real shell (the glob then
matches both scans' list-modes), and `vts sim down`. It notices the start pulse the emulated
trigger box sends, moves its source marker, writes each scan's list-mode when the
square wave stops; the analysis takes the list-mode of its own session, refuses another scan's,
and says so when the SPECT could not record a scan (a real full disk under sim/spect)."""

from __future__ import annotations

import json
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from vts_hw.config import load_rig
from vts_hw.procedures.sync import SyncAnalysis
from vts_hw.sim_devices.rig import load_env_file
from vts_hw.sim_devices.spect_follower import WAVE_ENDED_S
from vts_hw.sim_devices.spect_listmode import ListModeTruth

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]
SHELL_VTS = " ".join(shlex.quote(a) for a in VTS)


def _vts(cwd, env, *args, timeout=180):
    return subprocess.run([*VTS, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def _shell(cwd, env, line, timeout=180):
    """``line`` as a user types it (``vts`` …) in bash: globs are the shell's."""
    return subprocess.run(
        ["bash", "-c", line.replace("vts ", SHELL_VTS + " ", 1)],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _sim_up(cwd) -> dict:
    """`vts sim up --trigger triggerbox --spect --detach --dir sim`; the environment the sync page's
    `set -a; . sim/sim.env; export VTS_CONFIG=sim/rig.yaml` gives."""
    r = _vts(cwd, dict(os.environ), "sim", "up", "--trigger", "triggerbox", "--spect", "--detach", "--dir", "sim")
    assert r.returncode == 0, r.stderr
    return {**os.environ, **load_env_file(cwd / "sim" / "sim.env"), "VTS_CONFIG": str(cwd / "sim" / "rig.yaml")}


def _wait_for(folder: Path, pattern: str, n: int, timeout: float = 90.0) -> list[Path]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = sorted(folder.glob(pattern))
        if len(found) >= n:
            return found
        failed = sorted(folder.glob("*.failed.json"))
        assert not failed or pattern.endswith(".failed.json"), failed[0].read_text()
        time.sleep(0.2)
    raise AssertionError(f"no {n} {pattern} in {folder} within {timeout:g} s")


@pytest.fixture(scope="module")
def two_scans(tmp_path_factory):
    """The sync page's session (docs/physics/sync.md): a detached simulated rig with its SPECT,
    a 20 s and a 12 s scan, each recorded by the SPECT, then `vts sim down`. Returns (folder, env,
    [list-mode 1, 2], the output of `vts sim down`)."""
    cwd = tmp_path_factory.mktemp("readme")
    env = _sim_up(cwd)
    try:
        lms = []
        for k, seconds in ((1, 20), (2, 12)):
            r = _vts(cwd, env, "scan", "start", "--duration", str(seconds), "--no-live", "-o", f"scan{k}")
            assert r.returncode == 0, r.stderr
            lms = _wait_for(cwd / "sim" / "spect", "scan-*.vtslm", k, WAVE_ENDED_S + 60)
    finally:
        down = _vts(cwd, env, "sim", "down", "--dir", "sim")
    assert down.returncode == 0 and "stopped" in down.stdout, down.stderr
    return cwd, env, lms, down.stdout


def test_a_scan_is_recorded_by_the_simulated_spect_and_lines_up(two_scans):
    cwd, env, (lm, _), down = two_scans
    assert "failed" not in down  # `vts sim down` lists failures: there were none
    cfg = load_rig(cwd / "sim" / "rig.yaml")
    truth = ListModeTruth.load(str(lm) + ".truth.json")
    t0, t1 = truth.acquisition_start_host, truth.acquisition_start_host + truth.duration_s
    moves = [m["t_mid"] for m in truth.sources[0]["moves"] if t0 + 0.5 < m["t_start"] and m["t_end"] < t1 - 0.5]
    a = SyncAnalysis(cwd / "scan1", lm, cfg.calibration.cameras, cfg.calibration.mapping, workers=1).analyze()
    assert a.gating.start_delay_s == pytest.approx(truth.start_delay_s, abs=0.010)
    both = [e for e in a.events if e.seen_by == "both"]
    assert len(moves) >= 1 and len(both) == len(moves)  # a move every ~15 s: one or two in 20 s
    for e, t_mid in zip(both, moves):
        assert abs(e.t - t_mid) <= 0.020 and abs(e.dt_s) <= 0.020
    assert not list((cwd / "sim" / "spect").glob(".*.part"))  # nothing half-written left behind


def test_the_readme_glob_takes_each_sessions_own_listmode(two_scans):
    """After two scans the sync page's glob gives two files: each session takes its own."""
    cwd, env, lms, _ = two_scans
    for k, lm in enumerate(lms, 1):
        r = _shell(cwd, env, f"vts sync analyze scan{k} --listmode sim/spect/scan-*.vtslm --json --workers 1")
        assert r.returncode in (0, 10, 20) and "Traceback" not in r.stderr, r.stderr
        data = json.loads(r.stdout)
        assert (cwd / data["listmode"]).resolve() == lm.resolve()
        assert len(data["listmode_given"]) == 2
        assert any(p.startswith(f"list-mode {lm.name} chosen of 2 given") for p in data["problems"])
        if k == 1:
            assert r.returncode == 0 and data["summary"]["state"] == "OK"


def test_another_scans_listmode_is_refused(two_scans):
    """scan1 with scan2's list-mode: the files do not belong together (exit 3), named with both
    time spans; before, this was an ACTION "no motion event seen by both"."""
    cwd, env, (lm1, lm2), _ = two_scans
    r = _shell(cwd, env, f"vts sync analyze scan1 --listmode sim/spect/{lm2.name}")
    assert r.returncode == 3 and r.stdout == "", (r.stdout, r.stderr)
    msg = r.stderr.strip()
    assert len(msg.splitlines()) == 1 and "Traceback" not in msg
    assert (
        msg.startswith(f"vts: sim/spect/{lm2.name} and scan1 do not belong together: the list-mode was acquired ")
        and "(SPECT clock), the session recorded " in msg
        and ", its start pulse at " in msg
    )
    assert "no motion event" not in msg


def test_several_listmodes_for_one_session_ask_to_name_one(two_scans, tmp_path):
    """Two files whose acquisitions both fit the session (one a copy of the other): name one."""
    cwd, env, (lm1, _), _ = two_scans
    shutil.copy(lm1, tmp_path / "copy.vtslm")
    r = _shell(cwd, env, f"vts sync analyze scan1 --listmode sim/spect/{lm1.name} {tmp_path}/copy.vtslm")
    assert r.returncode == 3 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith("vts: 2 list-mode files fit scan1 (recorded ")
    assert lm1.name in r.stderr and "copy.vtslm acquired" in r.stderr
    assert r.stderr.strip().endswith("name the one of this scan with --listmode")


def test_a_glob_that_matches_nothing_and_a_truncated_listmode(two_scans, tmp_path):
    cwd, env, (lm1, _), _ = two_scans
    (tmp_path / "elsewhere").mkdir()
    r = _shell(cwd, env, f"vts sync analyze scan1 --listmode {tmp_path}/elsewhere/scan-*.vtslm")
    assert r.returncode == 3 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith(
        f"vts: {tmp_path}/elsewhere/scan-*.vtslm: no list-mode file matches, and no "
        f"failure record there covers scan1 (recorded "
    )
    cut = tmp_path / "cut.vtslm"
    data = lm1.read_bytes()
    cut.write_bytes(data[: len(data) // 2])  # a copy cut short: its header is whole
    r = _shell(cwd, env, f"vts sync analyze scan1 --listmode {cut}")
    assert r.returncode == 3 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith(f"vts: {cut}: ") and "truncated" in r.stderr


def test_a_failure_record_beside_other_scans_listmodes_is_the_answer(two_scans, tmp_path):
    """The glob matches only another scan's list-mode, and a failure record covers this session
    (its start is this session's start pulse): the record is the answer, not "do not belong"."""
    cwd, env, (lm1, lm2), _ = two_scans
    from vts_hw.spect.listmode.failures import write_failure_record

    shutil.copy(lm2, tmp_path / lm2.name)
    fire = json.loads((cwd / "scan1" / "manifest.json").read_text())["trigger"]["fire_time"]
    write_failure_record(
        tmp_path,
        lm1.name,
        "could not write it (read-only file system)",
        by="the simulated SPECT",
        start=fire,
        end=fire + 20.0,
    )
    (tmp_path / "junk.failed.json").write_text("{not json")  # not a record: ignored
    r = _shell(cwd, env, f"vts sync analyze scan1 --listmode {tmp_path}/scan-*.vtslm")
    assert r.returncode == 3 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stderr.startswith("vts: the simulated SPECT failed to record this scan (")
    assert r.stderr.strip().endswith(
        f"could not write it (read-only file system) (record {tmp_path}/{lm1.name.removesuffix('.vtslm')}.failed.json)"
    )


def test_a_spect_that_cannot_record_says_so_where_the_user_looks(tmp_path, small_disk):
    """The sync page's commands with sim/spect on a 256 kB disk: the 8 s list-mode does not fit.
    The simulated SPECT leaves a failure record (and nothing half-written); `vts sync analyze`
    with the sync page's glob, which then matches nothing, says the SPECT failed to record this
    scan and why; `vts sim down` lists it."""
    (tmp_path / "sim").mkdir()
    disk = small_disk(256, name="sim/spect")
    env = _sim_up(tmp_path)
    try:
        r = _vts(tmp_path, env, "scan", "start", "--duration", "8", "--no-live", "-o", "scan1")
        assert r.returncode == 0, r.stderr
        (record,) = _wait_for(disk.path, "*.failed.json", 1, WAVE_ENDED_S + 60)
    finally:
        down = _vts(tmp_path, env, "sim", "down", "--dir", "sim")
    assert list(disk.files()) == [record.name]  # no list-mode, no partial file
    rec = json.loads(record.read_text())
    assert rec["format"] == "vts-listmode-failure/1" and "no space left on device" in rec["reason"]
    manifest = json.loads((tmp_path / "scan1" / "manifest.json").read_text())
    assert abs(rec["start"] - manifest["trigger"]["fire_time"]) < 0.05

    r = _shell(tmp_path, env, "vts sync analyze scan1 --listmode sim/spect/scan-*.vtslm -o sync.html")
    assert r.returncode == 3 and r.stdout == "" and len(r.stderr.strip().splitlines()) == 1, r.stderr
    msg = r.stderr.strip()
    assert msg.startswith("vts: the simulated SPECT failed to record this scan (") and "Traceback" not in msg
    assert f"could not write {rec['listmode']} (no space left on device)" in msg
    assert f"(record sim/spect/{record.name}, log {tmp_path / 'sim' / 'sim.log'})" in msg
    print(msg)
    assert not (tmp_path / "sync.html").exists()

    assert down.returncode == 0, down.stderr
    assert "the simulated SPECT failed to record the scan (" in down.stdout
    assert f"(no space left on device) (sim/spect/{record.name})" in down.stdout
    assert "FAILED to record" in (tmp_path / "sim" / "sim.log").read_text()


def test_the_simulated_spect_needs_the_trigger_box_and_a_folder(tmp_path):
    r = subprocess.run(
        [*VTS, "sim", "up", "--spect", "--dir", str(tmp_path)], capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 2 and "--spect needs --trigger triggerbox" in r.stderr
