"""The trigger box's host watchdog with a host that dies: a real process drives the firmware in
the emulator (over its pty) through the real driver, fires, keeps the wave on with its heartbeat
thread, and is killed with SIGKILL. The emulator's pin record, in its own cycles, shows the wave
kept on while the host lived and cut within the stated bound of the last command the box heard
(firmware/trigger_box/watchdog.h: T - 1 tick .. T after it took that line); a new connection,
`vts trigger status` as a user runs it, says so (docs/decisions/0083)."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest
import yaml

from firmware_kit import US, Link, falls, rises
from inprocess_cli import vts
from vts_hw.sim_devices.trigger_box import F_CPU, SimTriggerBox

pytestmark = pytest.mark.timeout(300)

T_S = 1.0  # the watchdog time the host asks for (its heartbeat: every 0.25 s)
TICK = 125 * US
ISR_LATE = 16 * US
FREQ_HZ = 20.0

HOST = r"""
import sys, time
from vts_hw.drivers.trigger_box import TriggerBox
box = TriggerBox(sys.argv[1], watchdog_s=float(sys.argv[2]))
box.configure(float(sys.argv[3]), 0.5)
box.fire(pulse_ms=10)
print("fired", flush=True)
time.sleep(600)            # the heartbeat thread keeps the box fed until this process dies
"""


def test_a_killed_host_leaves_no_wave_behind(tmp_path, capsys):
    with SimTriggerBox(speed=1) as box:
        host = subprocess.Popen(
            [sys.executable, "-c", HOST, box.port, str(T_S), str(FREQ_HZ)],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        try:
            assert host.stdout.readline() == "fired\n", host.stderr.read()
            first = rises(box.edges("OC1A"))[0]
            box.wait_until(first + int(2.5 * T_S * F_CPU))  # the host alive for 2.5 T
            alive = box.edges("OC1A")
        finally:
            host.send_signal(signal.SIGKILL)
            host.wait()
        # while it lived: one unbroken wave, no cut, though its main thread only slept
        r = rises(alive)
        period = round(F_CPU / FREQ_HZ)
        assert len(r) >= 2.5 * T_S * FREQ_HZ
        assert all(abs(b - a - period) <= 5 for a, b in zip(r, r[1:])), "the wave broke while the host lived"
        ends = [u.cycle for u in box.uart() if u.direction == "RX" and u.value == 0x0A]
        beats = [c for c in ends if first < c < r[-1]]
        gaps = [(b - a) / F_CPU for a, b in zip(beats, beats[1:])]
        alive_said = (
            f"host alive {(r[-1] - first) / F_CPU:.2f} s: {len(beats)} command lines, longest gap "
            f"{max(gaps):.3f} s (T = {T_S:g} s)"
        )

        box.wait_cycles(int(1.25 * T_S * F_CPU))  # dead for longer than T
        # a new connection: what a user runs next, in this process
        rig = tmp_path / "rig.yaml"
        rig.write_text(
            yaml.safe_dump(
                {
                    "rig": "t",
                    "cameras": [{"name": "cam1", "host": "127.0.0.1"}],
                    "trigger": {"backend": "triggerbox", "address": box.port},
                }
            )
        )
        code, out, err = vts(capsys, "trigger", "status", "--config", rig, "--log", tmp_path / "t.csv")
        lines = out.splitlines()
        assert lines[0].startswith("triggerbox: output OFF, 20 Hz, duty 50 %, "), out
        assert lines[1].startswith(
            "  watchdog TRIPPED: the box heard nothing from its host for 1 s and cut the "
            "square wave (output off) at device time "
        ), out
        assert '  device error: -310,"Watchdog: host silent, output off"' in lines, out
        assert code == 4 and err == (
            "vts: triggerbox reports 1 error(s) in its queue (read off it now): "
            '-310,"Watchdog: host silent, output off"\n'
        ), err
        link = Link(box)
        assert link.ask("OUTP?") == "OFF"
        state, cut_us = link.ask("WDOG?").split(",")[1:]  # still says so, after the queue was read
        assert state == "TRIPPED"
        link.close()

        # the pins, by the emulator's clock: the cut within T - 1 tick .. T of the last command the box
        # took (between its line's end reaching the UART and its reply's first byte), nothing after it
        cut = int(cut_us) * US
        uart = box.uart()
        rx = [u.cycle for u in uart if u.direction == "RX" and u.value == 0x0A and u.cycle < cut][-1]
        tx = [u.cycle for u in uart if u.direction == "TX" and u.cycle > rx][0]
        t = int(T_S * F_CPU)
        assert rx + t - TICK < cut <= tx + t + ISR_LATE, ((cut - rx) / US, (tx - rx) / US)
        edges = box.edges("OC1A")
        assert edges[-1].value == 0 and falls(edges)[-1] <= cut + ISR_LATE
        assert rises(edges)[-1] + period > cut - ISR_LATE  # no rising edge after the cut
        print(alive_said)
        print(
            f"cut {(cut - rx) / US / 1e6 - T_S:+.6f} s after T from the end of the last command line "
            f"(its reply left {(tx - rx) / US:.0f} us after it)"
        )


def test_a_scan_whose_host_stalled_past_the_watchdog_is_not_complete(tmp_path):
    """The scan's trigger (what `vts scan start` and the console run): its host goes silent for
    longer than T mid-scan; at the stop the box's -310 becomes one of the scan's problems, and
    trigger.csv ends the wave at the cut, through the clock mapping."""
    from vts_hw.config import load_rig
    from vts_hw.drivers.trigger import read_log
    from vts_hw.procedures.scan_trigger import ScanTrigger

    with SimTriggerBox(speed=1) as box:
        path = tmp_path / "rig.yaml"
        path.write_text(
            yaml.safe_dump(
                {
                    "rig": "t",
                    "cameras": [{"name": "cam1", "host": "127.0.0.1"}],
                    "trigger": {
                        "backend": "triggerbox",
                        "address": box.port,
                        "frequency_hz": FREQ_HZ,
                        "watchdog_s": 0.5,
                    },
                }
            )
        )
        trig = ScanTrigger(load_rig(path))
        trig.check()
        trig.attach_log(tmp_path / "trigger.csv")
        trig.fire()
        assert trig.info["fire_status"]["extra"]["watchdog"]["state"] == "armed"
        trig.gen.heartbeat.stop()  # the host stalls: nothing reaches the box
        box.wait_cycles(int(0.8 * F_CPU))
        trig.stop()
        trig.close()
    assert trig.info["errors"] == ['stop: triggerbox reports -310,"Watchdog: host silent, output off"']
    rows = read_log(tmp_path / "trigger.csv")
    assert sum(r["kind"] == "event" and "watchdog cut" in r["text"] for r in rows) == 1
    (stop,) = [r for r in rows if r["kind"] == "wave_stop"]
    assert "time=device_clock_mapped" in stop["text"] and int(stop["device_time_us"]) > 0
