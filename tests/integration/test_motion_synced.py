"""`vts motion analyze --listmode` on the simulated rig: a patient on the table (breathing, one
body move), a scan session with the trigger box in the emulator, the simulated SPECT following
it; the motion analysis goes through the sync analysis, so every time is list-mode seconds.
The list-mode is given as the sync page's glob (docs/physics/sync.md) over two scans' files, as
`vts sync analyze` takes it: the session's own is picked (issue 21)."""

import dataclasses
import json
import os
import re
import shutil
import subprocess
import sys

import pytest

from vts_hw.sim_devices.patient import BodyMove, add_patient
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scenarios import sync_session as sync_sim


@pytest.fixture(scope="module")
def synced_scan(tmp_path_factory):
    import time

    tmp = tmp_path_factory.mktemp("motion_synced")
    rig = SimRig(n_cameras=2, seed=3, trigger="triggerbox").start()
    try:
        rig_yaml, _ = rig.write(tmp / "rig")
        marker = sync_sim.prepare(rig)
        t0 = time.time()
        move = BodyMove(t0 + 14.0, t0 + 14.8, (0.3, 0.2, 0.6), (1.5, 2.0, 1.0))
        patient = add_patient(rig.scene, t0, 40.0, 2, moves=[move])
        run = sync_sim.cli_scan(rig, rig_yaml, tmp / "scan", 22.0, marker, n=2, seed=1)
    finally:
        rig.stop()
    spect = tmp / "spect"  # the scan's list-mode and the next scan's (10 minutes later)
    spect.mkdir()
    shutil.copy(run.listmode, spect / "scan-1.vtslm")
    from vts_hw.spect.listmode.vtslm import read_vtslm, write_vtslm

    lm = read_vtslm(run.listmode)
    write_vtslm(spect / "scan-2.vtslm", dataclasses.replace(lm, start_time=lm.start_time + 600.0))
    return run, rig_yaml, patient, move, tmp


def _shell(line: str, rig_yaml):
    vts = f"{sys.executable} -m vts_hw.cli"
    return subprocess.run(
        ["bash", "-c", line.replace("vts ", vts + " ", 1)],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, "VTS_CONFIG": str(rig_yaml)},
    )


def test_another_scans_listmode_alone_is_refused_before_any_work(synced_scan):
    run, rig_yaml, patient, move, tmp = synced_scan
    p = _shell(f"vts motion analyze {run.session} --listmode {tmp}/spect/scan-2.vtslm", rig_yaml)
    assert p.returncode == 3 and "do not belong together" in p.stderr and "Traceback" not in p.stderr, p.stderr


@pytest.mark.timeout(600)
def test_motion_on_the_spect_clock(synced_scan):
    run, rig_yaml, patient, move, tmp = synced_scan
    p = _shell(
        f"vts motion analyze {run.session} --listmode {tmp}/spect/scan-*.vtslm --export {tmp / 'export'} --json",
        rig_yaml,
    )
    assert p.returncode in (0, 10, 20), p.stderr
    data = json.loads(p.stdout)
    assert data["listmode"] == str(tmp / "spect" / "scan-1.vtslm")  # the session's own of the glob's two
    assert "SPECT list-mode" in data["clock"] and data["time_origin"] == 0.0 and data["frame"]["name"] == "SPECT frame"
    # the move's true start, on the list-mode clock: host time minus the fire, plus nothing
    # more than the SPECT's start delay (< 0.5 s): within a second of the true start
    # (a busy machine's cameras may skip frames: a start that fell in a gap is bounded by it)
    true_list = move.t_start - run.fire_host
    starts = [(e["t_start"], e["start_bounds_s"]) for e in data["events"]]
    assert any(abs(s - true_list) < 1.0 if b is None else b[0] - 0.5 <= true_list <= b[1] for s, b in starts), (
        starts,
        true_list,
        data["summary"]["time"],
        data["problems"],
    )
    dyn = (tmp / "export" / "castor_motion.dyn").read_text()
    stamps = [ln for ln in dyn.splitlines() if ln.startswith("timestamp_motion_triggers:")]
    assert len(stamps) == 1 and re.fullmatch(r"timestamp_motion_triggers: 0(,\d+)+", stamps[0])  # whole seconds
    triggers = [int(n) for n in stamps[0].split(": ")[1].split(",")]
    assert len(triggers) == len(data["states"]) and data["export_notes"] == []
    assert all(abs(n - st["t_start"]) <= 0.5 for n, st in zip(triggers[1:], data["states"][1:]))
    six = json.loads((tmp / "export" / "motion_6dof.json").read_text())
    assert "SPECT list-mode" in six["clock"]
    # YRT-PET's LOR motion file through the command: a line per frame time from list-mode 0 ms
    lor = (tmp / "export" / "yrtpet_lor_motion.csv").read_text().splitlines()
    assert six["yrtpet"]["written"] and len(lor) == six["yrtpet"]["lines"] and lor[0].startswith("0,")
    assert all(len(ln.split(",")) == 14 for ln in lor)
