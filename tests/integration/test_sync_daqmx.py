"""A scan made with the NI-DAQmx backend, sync-checked end to end (issue 11, part 4).

The scan session runs in this process against the simulated cameras (HTTP), with rig.yaml's
trigger section naming the ``daqmx`` backend; its hardware is a fake port (no NI-DAQmx driver
here), so nothing is emitted: the simulated SPECT follows the wave from the session's
``trigger.csv`` — the neutral rows the driver wrote (docs/trigger-log-format.md) — exactly as
`vts sync analyze` then reads it. Before the neutral rows this session ended in "no square
wave was started in this trigger log".
"""

from __future__ import annotations

import yaml

from vts_hw.config import load_rig
from vts_hw.drivers import daqmx
from vts_hw.drivers.registry import open_cameras
from vts_hw.drivers.trigger import read_log
from vts_hw.procedures.scan import ScanSession
from vts_hw.procedures.sync import SyncAnalysis
from vts_hw.recording.trigger_wave import wave_from_trigger_log
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scenarios import sync_session as sync_sim
from vts_hw.sim_devices.spect_listmode import SimListModeSpect

EVENT_GOAL_S = 0.020
DELAY_GOAL_S = 0.010
LINES = ["Dev1/port0/line0", "Dev1/port0/line1"]


class RealTimePort:
    """A DaqmxPort with no hardware behind it: it records the calls and runs from start to stop."""

    def __init__(self):
        self.calls: list[tuple] = []
        self.running = False

    def configure_pulse_train(self, counter, frequency_hz, duty, start_trigger=None):
        self.calls.append(("configure", counter, frequency_hz, duty, start_trigger))
        return frequency_hz, duty

    def start_pulse_train(self):
        self.calls.append(("start",))
        self.running = True

    def stop_pulse_train(self):
        self.calls.append(("stop",))
        self.running = False

    def pulse_train_running(self):
        return self.running

    def write_lines(self, lines, values):
        self.calls.append(("lines", lines, tuple(values)))

    def close(self):
        self.calls.append(("close",))


def test_a_daqmx_scan_is_sync_checked_end_to_end(tmp_path, monkeypatch):
    port = RealTimePort()
    monkeypatch.setattr(daqmx, "NidaqmxPort", lambda: port)
    duration = 12.0
    rig = SimRig(n_cameras=2, seed=3, trigger="none").start()
    try:
        rig_yaml, _ = rig.write(tmp_path / "rig")
        data = yaml.safe_load(rig_yaml.read_text())
        data["trigger"] = {
            "backend": "daqmx",
            "address": "Dev1/ctr0",
            "lines": LINES,
            "fire_trigger": "/Dev1/PFI0",
            "frequency_hz": 1.0,
            "duty": 0.5,
        }
        rig_yaml.write_text(yaml.safe_dump(data))
        marker = sync_sim.prepare(rig)
        with rig.env():
            cfg = load_rig(rig_yaml)
            s = ScanSession(cfg, tmp_path / "scan", open_cameras(cfg.cameras), duration=duration)
            s.start()
            fire = s.trigger.info["fire_time"]
            src = sync_sim.start_moves(
                rig, marker, fire, duration, times_rel=[2.5, 6.0, 9.5], steps=[16.0, -14.0, 12.0]
            )
            manifest = s.stop(s.wait())
    finally:
        rig.stop()
    session = tmp_path / "scan"
    assert manifest["status"] == "complete" and manifest["trigger"]["fired"], manifest["trigger"]
    assert manifest["trigger"]["mode"] == "start pulses and square wave"
    # the counter was armed on the PFI line, then both start-pulse lines rose in one write
    names = [c[0] for c in port.calls]
    assert ("configure", "Dev1/ctr0", 1.0, 0.5, "/Dev1/PFI0") in port.calls
    assert names.index("start") < port.calls.index(("lines", ",".join(LINES), (True, True)))
    kinds = [r["kind"] for r in read_log(session / "trigger.csv")]
    assert kinds.count("wave_start") == 1 and kinds.count("wave_stop") == 1

    wave = wave_from_trigger_log(session / "trigger.csv")
    assert (wave.device, wave.period_s, wave.duty, wave.start_pulse) == ("daqmx", 1.0, 0.5, True)
    assert wave.time_source == "host_write" and 0 <= wave.uncertainty_s < 0.05
    assert abs(wave.start_host - fire) < 0.05 and wave.stop_host - wave.start_host > duration - 0.5

    lm = tmp_path / "scan.vtslm"
    truth = SimListModeSpect(rig.scene, [src], seed=4).follow_trigger_log(session / "trigger.csv", lm, duration - 0.6)
    assert truth.start_pulse_host == wave.start_host
    a = SyncAnalysis(session, lm, cfg.calibration.cameras, cfg.calibration.mapping, workers=2).analyze()
    data = a.results_data()
    assert data["trigger"]["device"] == "daqmx" and data["trigger"]["time_source"] == "host_write"
    assert len(data["events"]) == len(src.moves)
    for mv, ev in zip(src.moves, data["events"]):
        assert ev["seen_by"] == "both", data["events"]
        errs = (ev["t_vts"] - mv.t_mid, ev["t_spect"] - mv.t_mid, ev["dt_s"])
        assert max(abs(e) for e in errs) < EVENT_GOAL_S, errs
    assert abs(data["summary"]["start_delay_s"] - truth.start_delay_s) < DELAY_GOAL_S
    assert data["summary"]["state"] == "OK", data["problems"]
