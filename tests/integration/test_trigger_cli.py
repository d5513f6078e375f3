"""`vts trigger` as a user runs it (a subprocess per command; in-process where only the exit and
the words are looked at): against the simulated rig's
Keysight 33522B on a TCP socket (through pyvisa-py, as a real one on the LAN), against the
trigger box firmware in the emulator, and with the pyvisa-sim model (`simulated: true`)."""

import subprocess
import sys

import pytest
import serial
import yaml

from inprocess_cli import vts as vts_in_process
from vts_hw.drivers.function_generator import SIM_RESOURCE
from vts_hw.drivers.trigger import read_log
from vts_hw.recording.trigger_wave import wave_from_trigger_log
from vts_hw.sim_devices.scpi_server import SimFunctionGenerator
from vts_hw.sim_devices.trigger_box import F_CPU, SimTriggerBox

VTS = [sys.executable, "-m", "vts_hw.cli.__main__"]


def _rig(tmp_path, **trigger):
    cfg = {"rig": "t", "cameras": [{"name": "cam1", "host": "127.0.0.1"}], "trigger": trigger}
    p = tmp_path / "rig.yaml"
    p.write_text(yaml.safe_dump(cfg))
    return p


def vts(*args):
    return subprocess.run([*VTS, *args], capture_output=True, text=True, timeout=60)


@pytest.fixture()
def fgen():
    with SimFunctionGenerator() as srv:
        yield srv


def _fgen_rig(tmp_path, srv, **trigger):
    return _rig(tmp_path, backend="visa", address=srv.resource, **trigger)


# ---- the function generator on its socket -----------------------------------------------------------


def test_the_state_lasts_between_commands(tmp_path, fgen):
    rig = _fgen_rig(tmp_path, fgen, frequency_hz=1.0, duty=0.25, high_v=2.5, low_v=0.0)
    log = tmp_path / "trigger.csv"
    p = vts("trigger", "start", "--config", str(rig), "--log", str(log))
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "fgen: output ON, 1 Hz, duty 25 %, 0..2.5 V"

    p = vts("trigger", "status", "--config", str(rig), "--log", str(log))  # a new process, a new connection
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "fgen: output ON, 1 Hz, duty 25 %, 0..2.5 V"
    (run,) = fgen.instrument.runs(1)  # and the instrument agrees
    assert run.stop is None and (run.function, run.frequency_hz, run.duty_percent) == ("SQU", 1.0, 25.0)

    p = vts("trigger", "stop", "--config", str(rig), "--log", str(log))
    assert p.returncode == 0 and p.stdout.strip() == "fgen: output OFF, 1 Hz, duty 25 %, 0..2.5 V"
    assert fgen.instrument.runs(1)[0].stop is not None
    sent = [r["text"] for r in read_log(log) if r["kind"] == "cmd"]
    assert sent.count("*IDN?") == 3 and "OUTP 1" in sent and "OUTP 0" in sent
    assert all(r["host_time"] for r in read_log(log))
    # the wave the three processes made, from their neutral rows: started by the first, stopped by the third
    wave = wave_from_trigger_log(log)
    rows = read_log(log)
    assert wave.start_host == float(next(r["host_time"] for r in rows if r["text"] == "OUTP 1"))
    assert wave.stop_host == float(next(r["host_time"] for r in rows if r["text"] == "OUTP 0"))
    assert (wave.period_s, wave.duty, wave.high_v, wave.low_v, wave.converted) == (1.0, 0.25, 2.5, 0.0, False)


def test_fire_says_no_start_pulses_went_out_and_changes_nothing(tmp_path, fgen):
    rig = _fgen_rig(tmp_path, fgen, frequency_hz=5.0, high_v=2.5, low_v=0.0)
    log = tmp_path / "trigger.csv"
    p = vts("trigger", "fire", "--config", str(rig), "--log", str(log))
    assert p.returncode == 4 and "Traceback" not in p.stderr
    assert p.stderr.strip() == (
        "vts: fgen cannot start the square wave and the start pulses together: a Keysight 33500 has no "
        "contact-closure outputs; send the start pulses from the trigger box or an NI-DAQmx digital line "
        "(backend daqmx); nothing was sent, so no start pulses went out and the square wave was not "
        "started (the square wave alone: vts trigger start)"
    )
    ch = fgen.instrument.channels[1]
    assert (ch.function, ch.frequency_hz, ch.output) == ("SIN", 1000.0, False)  # as it was
    assert [r["text"] for r in read_log(log) if r["kind"] == "cmd"] == ["*IDN?", "SYST:ERR?"]


def test_pulse_is_one_clear_sentence(tmp_path, fgen):
    rig = _fgen_rig(tmp_path, fgen)
    p = vts("trigger", "pulse", "1", "100", "--config", str(rig), "--log", str(tmp_path / "t.csv"))
    assert p.returncode == 4 and p.stderr.startswith("vts: fgen cannot send a start pulse: ")
    assert "Traceback" not in p.stderr and fgen.instrument.events == []


def test_a_generator_that_is_off_is_one_sentence_naming_it(tmp_path, fgen):
    rig = _fgen_rig(tmp_path, fgen)
    fgen.stop()
    p = vts("trigger", "status", "--config", str(rig), "--log", str(tmp_path / "t.csv"))
    assert p.returncode == 4, p.stderr
    assert p.stderr == (
        f"vts: fgen: the instrument at {fgen.resource} refused the connection (nothing "
        f"listens there: is it switched on, and are the address and port right?)\n"
    )


def test_a_generator_that_hangs_is_a_timeout_naming_it(tmp_path, fgen):
    rig = _fgen_rig(tmp_path, fgen)
    fgen.go_silent()
    p = vts("trigger", "status", "--config", str(rig), "--log", str(tmp_path / "t.csv"))
    assert p.returncode == 4, p.stderr
    assert p.stderr == f"vts: fgen: the instrument at {fgen.resource} did not answer '*IDN?' within 2 s\n"
    rows = read_log(tmp_path / "t.csv")
    assert rows[-1]["kind"] == "event" and "did not answer" in rows[-1]["text"]  # kept in trigger.csv


def test_the_pyvisa_sim_model_still_works_from_the_config(tmp_path):
    rig = _rig(tmp_path, backend="visa", address=SIM_RESOURCE, simulated=True, frequency_hz=1.0, high_v=2.5, low_v=0.0)
    p = vts("trigger", "start", "--config", str(rig), "--log", str(tmp_path / "t.csv"))
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "fgen: output ON, 1 Hz, duty 50 %, 0..2.5 V"


# ---- the trigger box ------------------------------------------------------------------------------


def test_fire_on_the_trigger_box_says_what_went_out(tmp_path):
    with SimTriggerBox() as box:
        rig = _rig(tmp_path, backend="triggerbox", address=box.port, frequency_hz=2.0, duty=0.5, pulse_ms=50)
        p = vts("trigger", "fire", "--config", str(rig), "--log", str(tmp_path / "t.csv"))
        assert p.returncode == 0, p.stderr
        lines = p.stdout.strip().splitlines()
        assert lines[0].startswith("triggerbox: output ON, 2 Hz, duty 50 %, ") and "rising edge(s)" in lines[0]
        assert lines[1:] == [
            "  watchdog off: the box keeps its output as it is whatever happens to its host (vts trigger stop "
            "switches it off)",  # the wave outlives `vts trigger fire` by design
            "  square wave at the device's fixed TTL levels",
            "start pulses: channel 1 (VTS start) and channel 2 (SPECT start), 50 ms each, sent with the square "
            "wave's first rising edge (triggerbox accepted the fire; the device confirms 50 ms)",
        ]
        p = vts("trigger", "stop", "--config", str(rig), "--log", str(tmp_path / "t.csv"))
        assert p.returncode == 0, p.stderr
        # what the firmware really put on its pins: both contacts closed 50 ms, with the first edge
        up = [e.cycle for e in box.edges("OC1A") if e.value == 1]
        for pin in ("CH1", "CH2"):
            closed, opened = box.edges(pin)
            assert (closed.value, opened.value) == (1, 0)
            assert abs(closed.cycle - up[0]) <= 16 * 10
            assert abs((opened.cycle - closed.cycle) / F_CPU - 0.050) < 0.001


def test_a_level_the_generator_cannot_make_is_refused_before_anything_is_sent(tmp_path, fgen):
    rig = _fgen_rig(tmp_path, fgen, high_v=8.0, low_v=0.0)  # rig.yaml allows ±10 V; a 33500 into 50 ohm ±5 V
    p = vts("trigger", "start", "--config", str(rig), "--log", str(tmp_path / "t.csv"))
    assert p.returncode == 4, p.stderr
    assert p.stderr == ("vts: fgen: high level 8.0 V is outside the instrument's range -5 to 5 V; nothing was sent\n")
    assert fgen.instrument.channels[1].high_v == 0.05 and fgen.instrument.events == []


def test_a_trigger_log_that_cannot_be_written(tmp_path, fgen, small_disk):
    rig = _fgen_rig(tmp_path, fgen)
    (tmp_path / "afile").write_text("x")
    p = vts("trigger", "status", "--config", str(rig), "--log", str(tmp_path / "afile" / "trigger.csv"))
    assert p.returncode == 3 and "could not be written" in p.stderr and "nothing was sent" in p.stderr
    assert "Traceback" not in p.stderr
    # the disk fills while the device works: the device does what it was told, the log is short, exit 3
    disk = small_disk(64)
    log = disk.path / "trigger.csv"
    head = "host_time,device_us,device,kind,text\n"
    row = "1.000000,,fgen,event,earlier\n"
    log.write_text(head + row * ((4096 - len(head)) // len(row)) + "#" * ((4096 - len(head)) % len(row) - 1) + "\n")
    assert log.stat().st_size == 4096  # its page is full
    disk.fill(leave=0)
    p = vts("trigger", "start", "--config", str(rig), "--log", str(log))
    assert p.returncode == 3 and str(log) in p.stderr and "no space left on device" in p.stderr
    assert p.stdout.strip().startswith("fgen: output ON")  # said what the device did
    assert fgen.instrument.runs(1)[0].stop is None  # and it did it
    assert "Traceback" not in p.stderr


def test_a_log_that_is_not_a_trigger_log_is_never_appended_to(tmp_path, fgen):
    """`--log rig.yaml` by mistake (issue 21: no foreign file touched): refused before anything
    is sent, the file as it was; an empty file becomes the log."""
    rig = _fgen_rig(tmp_path, fgen, frequency_hz=1.0, high_v=2.5, low_v=0.0)
    for name, data in (("rig-copy.yaml", rig.read_bytes()), ("notes.bin", bytes(range(256)) * 4)):
        other = tmp_path / name
        other.write_bytes(data)
        p = vts("trigger", "start", "--config", str(rig), "--log", str(other))
        assert p.returncode == 2 and "is not a trigger log" in p.stderr and str(other) in p.stderr, p.stderr
        assert other.read_bytes() == data
    assert fgen.instrument.runs(1) == []  # nothing was sent
    empty = tmp_path / "empty.csv"
    empty.write_bytes(b"")
    p = vts("trigger", "start", "--config", str(rig), "--log", str(empty))
    assert p.returncode == 0 and read_log(empty)


def test_a_box_that_reports_an_error_is_exit_4_in_one_sentence_never_a_fine_status(tmp_path, capsys):
    """An error in the box's queue (a command someone sent it that it did not know) was printed as
    `device error: ...` under exit 0 (issue 32 §4); `trigger status` is exit 4 now, once: the
    queue is read off."""
    with SimTriggerBox() as box:
        rig = _rig(tmp_path, backend="triggerbox", address=box.port)
        with serial.Serial(box.port, 115200, timeout=10) as line:
            line.write(b"BOGUS\n")
            assert line.readline() == b"ERR -113 Undefined header\n"
        status = ["trigger", "status", "--config", rig, "--log", tmp_path / "t.csv"]
        code, out, err = vts_in_process(capsys, *status)
        assert code == 4 and '  device error: -113,"Undefined header"' in out.splitlines(), out
        assert err == 'vts: triggerbox reports 1 error(s) in its queue (read off it now): -113,"Undefined header"\n'
        code, out, err = vts_in_process(capsys, *status)
        assert code == 0 and "device error" not in out, err
