"""The simulated SPECT beside a running rig (`vts sim up --trigger triggerbox --spect`): it
notices the start pulse the emulated trigger box sends, moves its source marker, writes the
scan's list-mode when the square wave stops, and the sync analysis finds the moves in it."""

import subprocess
import sys
import time

import pytest

from vts_hw.config import load_rig
from vts_hw.procedures.scan import ScanSession
from vts_hw.procedures.sync import SyncAnalysis
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.spect_follower import WAVE_ENDED_S, SpectFollower
from vts_hw.sim_devices.spect_listmode import ListModeTruth


def test_a_scan_is_recorded_by_the_simulated_spect_and_lines_up(tmp_path):
    rig = SimRig(n_cameras=2, seed=3, trigger="triggerbox")
    follower = SpectFollower(rig, tmp_path / "spect", seed=1, log=lambda m: None)
    with rig, rig.env():
        follower.start()
        rig_yaml, _ = rig.write(tmp_path / "rig")
        cfg = load_rig(rig_yaml)
        ScanSession(cfg, tmp_path / "scan", duration=20.0).run()
        deadline = time.monotonic() + WAVE_ENDED_S + 20
        while not follower.written and time.monotonic() < deadline:
            time.sleep(0.2)
        follower.stop()
    assert len(follower.written) == 1
    lm = follower.written[0]
    truth = ListModeTruth.load(str(lm) + ".truth.json")
    t0, t1 = truth.acquisition_start_host, truth.acquisition_start_host + truth.duration_s
    moves = [m["t_mid"] for m in truth.sources[0]["moves"] if t0 + 0.5 < m["t_start"] and m["t_end"] < t1 - 0.5]
    a = SyncAnalysis(tmp_path / "scan", lm, cfg.calibration.stereo, cfg.calibration.spect, workers=1).analyze()
    assert a.gating.start_delay_s == pytest.approx(truth.start_delay_s, abs=0.010)
    both = [e for e in a.events if e.seen_by == "both"]
    assert len(moves) >= 1 and len(both) == len(moves)     # a move every ~15 s: one or two in 20 s
    for e, t_mid in zip(both, moves):
        assert abs(e.t - t_mid) <= 0.020 and abs(e.dt_s) <= 0.020


def test_the_simulated_spect_needs_the_trigger_box_and_a_folder(tmp_path):
    r = subprocess.run([sys.executable, "-m", "vts_hw.cli.__main__", "sim", "up", "--spect", "--dir",
                        str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--spect needs --trigger triggerbox" in r.stderr
