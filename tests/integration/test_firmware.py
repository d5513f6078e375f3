"""Firmware in the loop: the trigger box firmware (firmware/trigger_box) runs in simavr
behind a pty (vts_hw.sim_devices.trigger_box) and is driven over its serial protocol with
pyserial. The output pins are judged from the harness's edge log in emulated cycles (16 per
microsecond), which are exact and deterministic; nothing here depends on how fast the
host is (waits are in emulated cycles, assertions never on wall-clock time).

Two boxes per module: one in real time (the serial tests) and one ten times faster than
real time, for periods of seconds (0.1 Hz is 10 s a period).
"""

from __future__ import annotations

import os

import pytest
import serial

from firmware_kit import ALIGN, JITTER, US, Link, check_whole_periods, falls, ppm_error, rises, run_wave
from vts_hw.sim_devices.trigger_box import F_CPU, SimTriggerBox

# The first test may build the firmware, and on a fresh machine install the AVR toolchain
# and simavr from Debian first (make -C firmware): give it room.
pytestmark = pytest.mark.timeout(600)


# ---------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def box():
    with SimTriggerBox(speed=1) as b:
        yield b


@pytest.fixture(scope="module")
def box10():
    with SimTriggerBox(speed=10) as b:
        yield b


@pytest.fixture
def tb(box):
    link = Link(box)
    link.reset()
    yield link
    link.close()


@pytest.fixture
def tb10(box10):
    link = Link(box10)
    link.reset()
    link.ok("WDOG 0")  # periods of seconds, runs of up to 25 s without a command: the host watchdog off
    yield link
    link.close()


# ---------------------------------------------------------------------------- identity
def test_identity_defaults_and_forms(tb):
    assert tb.ask("*IDN?") == "VTS,TRIGGERBOX,0000,1.1.0"
    assert tb.ask("FREQ?") == "1.000000000"
    assert tb.ask("DUTY?") == "0.500000"
    assert tb.ask("OUTP?") == "OFF"
    assert tb.ask("PULSE:WIDTH?") == "100"
    assert tb.ask("SYST:ERR?") == '0,"No error"'
    assert tb.ask("EDGES?").count(",") == 2
    assert tb.ask("WDOG?") == "10.000000,IDLE,0"  # the host watchdog: on, 10 s
    # lines may end in \r\n; headers are case-insensitive; SCPI long forms
    tb.s.write(b"*idn?\r\n")
    assert tb.line() == "VTS,TRIGGERBOX,0000,1.1.0"
    tb.ok("frequency 2.5")
    assert tb.ask("Freq?") == "2.500000000"
    tb.ok("DUTY 25e-2")
    assert tb.ask("duty?") == "0.250000"
    assert tb.ask("SYSTEM:ERROR:NEXT?") == '0,"No error"'


# ---------------------------------------------------------------------------- frequency
# exactly representable: 16 MHz / f is an integer number of cycles Timer1 can count
@pytest.mark.parametrize("freq", ["1000", "100", "50", "10"])
def test_frequency_exact_real_time(tb, freq):
    period = F_CPU // int(freq)
    assert tb.ask(f"FREQ {freq}") == "OK"
    assert float(tb.ask("FREQ?")) == float(freq)
    edges = run_wave(tb, freq, "0.5", 1.0)
    r, _ = check_whole_periods(edges, period, period // 2)
    assert len(r) >= int(freq) // 2
    err = ppm_error(r, period)
    print(f"{freq} Hz: {len(r)} periods, error {err:+.4f} ppm")
    assert abs(err) <= 1.0


@pytest.mark.parametrize("freq,seconds", [("2", 2.0), ("1", 3.0), ("0.5", 4.5), ("0.1", 11.0)])
def test_frequency_exact_low(tb10, freq, seconds):
    period = round(F_CPU / float(freq))
    edges = run_wave(tb10, freq, "0.5", seconds)
    r, _ = check_whole_periods(edges, period, period // 2)
    assert len(r) >= 2
    err = ppm_error(r, period)
    print(f"{freq} Hz: {len(r)} periods, error {err:+.4f} ppm")
    assert abs(err) <= 1.0


# 16 MHz / f is not a whole number of cycles: the device makes the nearest whole number
# (the best a 16 MHz clock can do) and reports the frequency it really makes
@pytest.mark.parametrize(
    "freq,seconds,bound_ppm,box_name",
    [
        ("333", 1.0, 1.01, "tb"),  # 48048 cycles, fast PWM at clk/1: +1.0 ppm
        ("7", 2.0, 0.13, "tb10"),  # 2285714 cycles in CTC laps: +0.125 ppm
        ("0.13", 8.5, 0.01, "tb10"),  # 123076923 cycles in CTC laps: +0.0006 ppm
    ],
)
def test_frequency_awkward(request, freq, seconds, bound_ppm, box_name):
    link = request.getfixturevalue(box_name)
    link.ok(f"FREQ {freq}")
    actual = float(link.ask("FREQ?"))
    period = F_CPU / actual
    requested_ppm = (actual - float(freq)) / float(freq) * 1e6
    assert abs(requested_ppm) <= bound_ppm
    edges = run_wave(link, freq, "0.5", seconds)
    r = rises(edges)
    err = ppm_error(r, round(period))
    print(
        f"{freq} Hz: makes {actual} Hz ({requested_ppm:+.3f} ppm from the request); "
        f"measured vs reported {err:+.4f} ppm over {len(r)} periods"
    )
    assert abs(err) <= 1.0


# ---------------------------------------------------------------------------- duty
@pytest.mark.parametrize(
    "freq,duty,box_name",
    [
        ("1000", "0.01", "tb"),
        ("1000", "0.99", "tb"),
        ("10", "0.25", "tb"),
        ("7", "0.01", "tb10"),
        ("0.5", "0.7", "tb10"),
        ("0.1", "0.01", "tb10"),
    ],
)
def test_duty(request, freq, duty, box_name):
    link = request.getfixturevalue(box_name)
    seconds = max(0.5, 1.6 / float(freq))  # two rising edges at least (OUTP OFF ends the period)
    edges = run_wave(link, freq, duty, seconds)
    r, f = rises(edges), falls(edges)
    assert len(r) >= 2
    reported = float(link.ask("DUTY?"))
    for a, b, c in zip(r, f, r[1:]):
        measured = (b - a) / (c - a)
        assert abs(measured - float(duty)) <= 0.001, (measured, duty)
        assert abs(measured - reported) <= 1e-6 + JITTER / (c - a)
    print(f"{freq} Hz duty {duty}: measured {(f[0] - r[0]) / (r[1] - r[0]):.6f}, reports {reported}")


# ---------------------------------------------------------------------------- *TRG
@pytest.mark.parametrize(
    "freq,duty,width,box_name",
    [
        ("100", "0.5", 20, "tb"),  # fast PWM, clk/1
        ("0.5", "0.1", 50, "tb10"),  # fast PWM, clk/1024
        ("0.1", "0.01", 30, "tb10"),  # CTC laps
    ],
)
def test_trg_aligns_wave_and_pulses(request, freq, duty, width, box_name):
    link = request.getfixturevalue(box_name)
    box = link.box
    n0 = len(box.edges())
    link.ok(f"FREQ {freq}")
    link.ok(f"DUTY {duty}")
    link.ok(f"PULSE:WIDTH {width}")
    link.ok("*TRG")
    assert link.ask("OUTP?") == "ON"
    box.wait_cycles((width + 10) * 1000 * US)
    link.ok("OUTP OFF")
    link.wait_off()
    new = box.edges()[n0:]
    wave = [e for e in new if e.pin == "OC1A"]
    assert wave[0].value == 1, "the square wave starts with a rising edge"
    t0 = wave[0].cycle
    for ch in ("CH1", "CH2"):
        pulse = [e for e in new if e.pin == ch]
        assert [e.value for e in pulse] == [1, 0]
        delta = pulse[0].cycle - t0
        print(f"{freq} Hz: {ch} rises {delta:+d} cycles from OC1A")
        assert abs(delta) <= ALIGN
        got = pulse[1].cycle - pulse[0].cycle
        assert abs(got - width * 1000 * US) <= 20 * US, (ch, got)  # within 20 us
    check_whole_periods(wave, round(F_CPU / float(freq)), round(F_CPU / float(freq) * float(duty)))
    # EDGES? counts what the pin did, and times it to the microsecond
    n, first, last = map(int, link.ask("EDGES?").split(","))
    assert n == len(rises(wave))
    assert abs(first - wave[0].cycle / US) <= 1
    assert abs(last - rises(wave)[-1] / US) <= 1


def test_trg_refused_while_running(tb):
    tb.ok("FREQ 100")
    tb.ok("OUTP ON")
    assert tb.ask("*TRG") == "ERR -221 Settings conflict"
    tb.ok("OUTP OFF")
    tb.wait_off()


# ---------------------------------------------------------------------------- OUTP OFF
@pytest.mark.parametrize(
    "freq,duty,delays,box_name",
    [
        ("1000", "0.99", (0.2, 0.2003, 0.2007), "tb"),  # 160-cycle low phase
        ("1000", "0.01", (0.2, 0.2005), "tb"),
        ("50", "0.5", (0.21, 0.205), "tb"),
        ("0.5", "0.5", (0.5, 1.5), "tb10"),  # clk/1024: stop decided on TCNT1
        ("7", "0.9", (0.3, 0.4), "tb10"),  # CTC laps, short low phase
        ("0.1", "0.3", (1.0, 5.0), "tb10"),  # CTC laps: OFF in high and low phase
    ],
)
def test_outp_off_ends_on_a_whole_period(request, freq, duty, delays, box_name):
    link = request.getfixturevalue(box_name)
    box = link.box
    period = round(F_CPU / float(freq))
    high = round(period * float(duty))
    for delay in delays:
        edges = run_wave(link, freq, duty, delay)
        check_whole_periods(edges, period, high)
        # and nothing after the stop
        n = len(box.edges("OC1A"))
        box.wait_cycles(min(2 * period, 3 * F_CPU))
        assert len(box.edges("OC1A")) == n, "edges after the wave stopped"


def test_outp_on_while_finishing_keeps_running(tb10):
    box = tb10.box
    n0 = len(box.edges("OC1A"))
    tb10.ok("FREQ 0.5")
    tb10.ok("DUTY 0.9")
    tb10.ok("OUTP ON")
    box.wait_cycles(F_CPU // 2)  # in the high phase
    tb10.ok("OUTP OFF")
    assert tb10.ask("OUTP?") == "ON"  # still finishing its period
    tb10.ok("OUTP ON")  # changed our mind: keep going
    box.wait_cycles(5 * F_CPU)
    assert tb10.ask("OUTP?") == "ON"
    tb10.ok("OUTP OFF")
    tb10.wait_off()
    r, _ = check_whole_periods(box.edges("OC1A")[n0:], 32_000_000, 28_800_000)
    assert len(r) >= 3


# ---------------------------------------------------------------------------- pulses
def test_pulse_widths_and_refusals(tb):
    box = tb.box
    n0 = len(box.edges())
    tb.ok("PULSE 1 5")
    tb.ok("PULSE 2 250")
    assert tb.ask("PULSE 2 10") == "ERR -221 Settings conflict"  # still closed
    box.wait_cycles(300 * 1000 * US)
    tb.ok("PULSE 2 1")
    box.wait_cycles(10 * 1000 * US)
    new = box.edges()[n0:]
    assert not [e for e in new if e.pin == "OC1A"], "pulses must not touch the wave"
    for ch, widths in (("CH1", [5]), ("CH2", [250, 1])):
        e = [x for x in new if x.pin == ch]
        assert [x.value for x in e] == [1, 0] * len(widths)
        got = [(b.cycle - a.cycle) / US for a, b in zip(e[::2], e[1::2])]
        for g, w in zip(got, widths):
            print(f"{ch} {w} ms: {g - w * 1000:+.2f} us")
            assert abs(g - w * 1000) <= 5.0
    for bad, code in (
        ("PULSE 3 10", -222),
        ("PULSE 0 10", -222),
        ("PULSE 1 0", -222),
        ("PULSE 1 10001", -222),
        ("PULSE 1 1.5", -104),
        ("PULSE 1", -109),
        ("PULSE 1 2 3", -108),
        ("PULSE x 10", -104),
        ("PULSE 1,,2", -102),
    ):
        assert tb.ask(bad).startswith(f"ERR {code} "), bad
    tb.ask("*CLS")


# ---------------------------------------------------------------------------- bad input
BAD = [
    ("FROB", "ERR -113 Undefined header"),
    ("FREQ 2000", "ERR -222 Data out of range"),
    ("FREQ 0.09", "ERR -222 Data out of range"),
    ("FREQ -5", "ERR -222 Data out of range"),
    ("FREQ abc", "ERR -104 Data type error"),
    ("FREQ 1e", "ERR -104 Data type error"),
    ("FREQ", "ERR -109 Missing parameter"),
    ("FREQ 10 20", "ERR -108 Parameter not allowed"),
    ("FREQ? 5", "ERR -108 Parameter not allowed"),
    ("DUTY 1.5", "ERR -222 Data out of range"),
    ("DUTY 0.005", "ERR -222 Data out of range"),
    ("OUTP MAYBE", "ERR -224 Illegal parameter value"),
    ("*IDN? x", "ERR -108 Parameter not allowed"),
    ("FREQ 10", "ERR -221 Settings conflict"),  # valid, but not while the wave is on
    ("DUTY 0.5", "ERR -221 Settings conflict"),
    ("*TRG", "ERR -221 Settings conflict"),
]


def test_bad_and_garbled_input_change_nothing(tb):
    box = tb.box
    n0 = len(box.edges("OC1A"))
    tb.ok("FREQ 200")
    tb.ok("DUTY 0.3")
    tb.ok("OUTP ON")
    box.wait_cycles(F_CPU // 10)
    before = (tb.ask("FREQ?"), tb.ask("DUTY?"), tb.ask("OUTP?"))
    for cmd, reply in BAD:
        assert tb.ask(cmd) == reply, cmd
    # binary junk in a line: one error for the line
    tb.s.write(bytes([0x00, 0xFF, 0x80, 0x1B, 0x7F, 0x03]) + b"FREQ 10\n")
    assert tb.line() == "ERR -101 Invalid character"
    # an overlong line: one error, and nothing of it is executed
    tb.s.write(b"FREQ 10 " + b"9" * 200 + b"\n")
    assert tb.line() == "ERR -363 Input buffer overrun"
    # empty lines are not commands: no reply at all
    tb.s.write(b"\n\r\n   \n\t\n")
    assert tb.ask("*IDN?") == "VTS,TRIGGERBOX,0000,1.1.0"
    # random junk with line ends in it: every non-blank line answers ERR, none executes
    junk = bytes(os.urandom(300)).replace(b"\n", b"\r")
    junk = b"\n".join(junk[i : i + 30] for i in range(0, 300, 30))
    tb.s.write(junk + b"\n*IDN?\n")
    while True:
        r = tb.line()
        if r == "VTS,TRIGGERBOX,0000,1.1.0":
            break
        assert r.startswith("ERR "), r
    # the wave never noticed
    assert (tb.ask("FREQ?"), tb.ask("DUTY?"), tb.ask("OUTP?")) == before
    box.wait_cycles(F_CPU // 10)
    tb.ok("OUTP OFF")
    tb.wait_off()
    edges = box.edges("OC1A")[n0:]
    r, f = check_whole_periods(edges, 80_000, 24_000)
    # one unbroken grid of periods from the first edge to the last: no phase jump
    assert all(abs((c - r[0]) - k * 80_000) <= JITTER for k, c in enumerate(r))
    tb.ask("*CLS")


def test_commands_in_a_burst_are_not_lost(tb):
    tb.ok("FREQ 1000")
    tb.ok("OUTP ON")
    tb.s.write(b"FREQ?\n" * 30 + b"EDGES?\n" * 10)
    assert [tb.line() for _ in range(30)] == ["1000.000000000"] * 30
    counts = [int(tb.line().split(",")[0]) for _ in range(10)]
    assert counts == sorted(counts) and counts[0] > 0
    tb.ok("OUTP OFF")
    tb.wait_off()


# ---------------------------------------------------------------------------- errors
def test_error_queue_order_and_overflow(tb):
    for cmd in ("BOGUS", "FREQ 5000", "DUTY x", "OUTP 2"):
        assert tb.ask(cmd).startswith("ERR ")
    assert tb.ask("SYST:ERR?") == '-113,"Undefined header"'
    assert tb.ask("SYST:ERR?") == '-222,"Data out of range"'
    assert tb.ask("SYST:ERR?") == '-104,"Data type error"'
    assert tb.ask("SYST:ERR?") == '-224,"Illegal parameter value"'
    assert tb.ask("SYST:ERR?") == '0,"No error"'
    for _ in range(10):
        tb.ask("BOGUS")
    got = [tb.ask("SYST:ERR?") for _ in range(9)]
    assert got == ['-113,"Undefined header"'] * 7 + ['-350,"Queue overflow"', '0,"No error"']
    tb.ask("BOGUS")
    tb.ok("*CLS")
    assert tb.ask("SYST:ERR?") == '0,"No error"'


# ---------------------------------------------------------------------------- clock
def test_time_is_monotonic_and_the_emulated_clock(tb):
    box = tb.box
    last = -1
    for _ in range(8):
        n0 = len(box.uart())
        t = int(tb.ask("TIME?"))
        ev = box.uart()[n0:]
        sent = [u.cycle for u in ev if u.direction == "RX" and u.value == 0x0A][-1]
        answered = [u.cycle for u in ev if u.direction == "TX"][0]
        # sampled after the command's last byte arrived and before the reply left
        assert sent / US - 1 <= t <= answered / US + 1, (sent / US, t, answered / US)
        assert t > last
        last = t
        box.wait_cycles(F_CPU // 50)


def test_time_and_edges_past_32_bits():
    """The device clock is 64-bit: a build whose clock starts 0.3 ms before 2^32 us."""
    offset_us = 34_359_736 * 125
    with SimTriggerBox(speed=1, firmware="trigger_box_late") as box:
        link = Link(box)
        t = int(link.ask("TIME?"))
        assert t > 2**32
        assert abs(t - offset_us - box.cycles_now() / US) < 0.5e6  # same clock, give or take
        edges = run_wave(link, "1000", "0.5", 0.05)
        n, first, last = map(int, link.ask("EDGES?").split(","))
        r = rises(edges)
        assert n == len(r)
        assert abs(first - offset_us - r[0] / US) <= 1
        assert abs(last - offset_us - r[-1] / US) <= 1
        link.close()


def test_edges_query_while_running(tb):
    box = tb.box
    n0 = len(box.edges("OC1A"))
    tb.ok("FREQ 50")
    tb.ok("OUTP ON")
    box.wait_cycles(F_CPU // 5)
    before = len(rises(box.edges("OC1A")[n0:]))
    n, first, last = map(int, tb.ask("EDGES?").split(","))
    after = len(rises(box.edges("OC1A")[n0:]))
    assert before <= n <= after + 1
    assert last - first == (n - 1) * 20_000
    tb.ok("OUTP OFF")
    tb.wait_off()
    r = rises(box.edges("OC1A")[n0:])
    n, first, last = map(int, tb.ask("EDGES?").split(","))
    assert n == len(r)
    assert abs(first - r[0] / US) <= 1 and abs(last - r[-1] / US) <= 1


# ---------------------------------------------------------------------------- *RST
def test_rst_stops_on_a_whole_period_and_restores_defaults(tb):
    box = tb.box
    n0 = len(box.edges())
    tb.ok("FREQ 20")
    tb.ok("DUTY 0.8")
    tb.ok("PULSE:WIDTH 500")
    tb.ok("*TRG")
    box.wait_cycles(F_CPU // 10)
    tb.ok("*RST")
    tb.wait_off()
    new = box.edges()[n0:]
    check_whole_periods([e for e in new if e.pin == "OC1A"], 800_000, 640_000)
    for ch in ("CH1", "CH2"):  # *RST opens the contacts at once
        e = [x for x in new if x.pin == ch]
        assert [x.value for x in e] == [1, 0]
        assert e[1].cycle - e[0].cycle < 500 * 1000 * US
    assert (tb.ask("FREQ?"), tb.ask("DUTY?"), tb.ask("PULSE:WIDTH?")) == ("1.000000000", "0.500000", "100")


# ---------------------------------------------------------------------------- unplug
def test_unplug_and_replug():
    with SimTriggerBox(speed=1) as box:
        link = Link(box)
        link.ok("FREQ 10")
        box.unplug()
        with pytest.raises(serial.SerialException):
            link.s.write(b"*IDN?\n")
            link.s.readline()
        link.s.close()
        port = box.replug()
        link = Link(box)
        assert port == link.s.port
        assert link.ask("*IDN?").startswith("VTS,TRIGGERBOX,")
        assert link.ask("FREQ?") == "1.000000000"  # a fresh power-up ...
        assert abs(int(link.ask("TIME?")) - box.cycles_now() / US) < 0.5e6  # ... and clock
        link.close()


# ---------------------------------------------------------------------------- host watchdog
TICK = 125 * US  # the tick that counts the host's silence
ISR_LATE = 16 * US  # the cut is made within the tick's interrupt, well inside 16 us


def _heartbeat(box, u0, before, nth=-1):
    """A command line's end (the cycle its '\n' reached the UART) and the cycle its reply's first
    byte left: the box took the line between the two. `nth` line end before `before`."""
    uart = box.uart()[u0:]
    rx = [u.cycle for u in uart if u.direction == "RX" and u.value == 0x0A and u.cycle < before][nth]
    tx = [u.cycle for u in uart if u.direction == "TX" and u.cycle > rx][0]
    return rx, tx


def _check_cut(tb, n0, seconds, heartbeat):
    """The wave was cut T - 1 tick .. T (+ the interrupt's few cycles) after the box took the last
    heartbeat; the pins agree with the cut's device time (WDOG?); returns it in cycles."""
    box = tb.box
    state, us = tb.ask("WDOG?").split(",")[1:]
    assert state == "TRIPPED"
    cut = int(us) * US
    rx, tx = heartbeat
    t = int(seconds * F_CPU)
    assert rx + t - TICK < cut <= tx + t + ISR_LATE, ((cut - rx) / US, (tx - rx) / US)
    edges = box.edges("OC1A")[n0:]
    r, f = rises(edges), falls(edges)
    assert edges[0].value == 1 and edges[-1].value == 0 and len(r) == len(f)
    assert f[-1] <= cut + ISR_LATE  # nothing after the cut ...
    period = round(F_CPU / float(tb.ask("FREQ?")))
    assert r[-1] + period > cut - ISR_LATE  # ... and no rising edge missing before it
    n, first, _ = map(int, tb.ask("EDGES?").split(","))
    assert n == len(r) and abs(first - r[0] / US) <= 1
    return cut


@pytest.mark.parametrize(
    "freq,duty",
    [
        ("1", "0.99"),  # fast PWM clk/256, cut in a high phase
        ("0.13", "0.5"),
    ],
)  # CTC laps, cut in a high phase
# (a cut wherever it falls, at 20 Hz: tests/integration/test_trigger_box_watchdog.py)
def test_watchdog_cuts_the_wave_when_the_host_falls_silent(tb, freq, duty):
    box = tb.box
    n0, u0 = len(box.edges("OC1A")), len(box.uart())
    tb.ok("WDOG 0.5")
    tb.ok(f"FREQ {freq}")
    tb.ok(f"DUTY {duty}")
    tb.ok("OUTP ON")  # the last heartbeat
    box.wait_cycles(int(0.6 * F_CPU))
    assert tb.ask("OUTP?") == "OFF"
    cut = _check_cut(tb, n0, 0.5, _heartbeat(box, u0, box.edges("OC1A")[-1].cycle))
    edges = box.edges("OC1A")[n0:]
    if float(freq) < 10:  # mid-period: the high phase cut short, at the cut
        assert [e.value for e in edges] == [1, 0] and abs(edges[1].cycle - cut) <= ISR_LATE
    print(
        f"{freq} Hz: cut {(cut - _heartbeat(box, u0, cut)[0]) / US - 500_000:+.1f} us after T from the end of "
        f"the last command line"
    )
    assert tb.ask("SYST:ERR?") == '-310,"Watchdog: host silent, output off"'
    assert tb.ask("SYST:ERR?") == '0,"No error"'  # queued once
    assert len(box.edges("OC1A")) == n0 + len(edges), "edges after the cut"
    assert tb.ask("WDOG?").split(",")[1] == "TRIPPED"  # kept until the next start ...
    tb.ok("WDOG 0")
    tb.ok("FREQ 1000")  # (a short last period to finish)
    tb.ok("OUTP ON")
    assert tb.ask("WDOG?") == "0.000000,OFF,0"  # ... which forgets it
    tb.ok("OUTP OFF")
    tb.wait_off()


def test_watchdog_heartbeats_are_command_lines_only(tb):
    """Blank lines, garbage and unknown headers are not the host: the cut comes T after the last
    line that named a command, though junk kept arriving."""
    box = tb.box
    n0, u0 = len(box.edges("OC1A")), len(box.uart())
    tb.ok("WDOG 0.3")
    tb.ok("FREQ 100")
    tb.ok("OUTP ON")
    tb.s.write(b"FROB\n\n  \n\x01X\nOUTP\x7f?\n" * 2)  # each non-blank line: ERR, no heartbeat
    assert [tb.line()[:8] for _ in range(6)] == ["ERR -113", "ERR -101", "ERR -101"] * 2
    box.wait_cycles(int(0.4 * F_CPU))
    assert tb.ask("OUTP?") == "OFF"
    ends = [u.cycle for u in box.uart()[u0:] if u.direction == "RX" and u.value == 0x0A]
    cut = _check_cut(tb, n0, 0.3, _heartbeat(box, u0, ends[3]))  # OUTP ON's line (after WDOG, FREQ)
    assert sum(ends[2] < c < cut for c in ends) == 10  # the junk came in between
    assert tb.ask("SYST:ERR?").startswith("-113,")  # the junk's errors, then the cut's
    while (r := tb.ask("SYST:ERR?")) != '0,"No error"':
        last = r
    assert last == '-310,"Watchdog: host silent, output off"'


def test_watchdog_settings_and_silence_while_off(tb):
    box = tb.box
    n0 = len(box.edges("OC1A"))
    assert tb.ask("WDOG?") == "10.000000,IDLE,0"
    tb.ok("WATCHDOG 2.5")
    assert tb.ask("WATCHDOG?") == "2.500000,IDLE,0"
    tb.ok("WDOG 0")
    assert tb.ask("WDOG?") == "0.000000,OFF,0"
    for bad, code in (
        ("WDOG 0.05", -222),
        ("WDOG 3600.001", -222),
        ("WDOG -1", -222),
        ("WDOG x", -104),
        ("WDOG", -109),
        ("WDOG 1 2", -108),
        ("WDOG? 1", -108),
    ):
        assert tb.ask(bad).startswith(f"ERR {code} "), bad
    assert tb.ask("WDOG?") == "0.000000,OFF,0"  # refusals change nothing
    tb.ok("*CLS")
    tb.ok("WDOG 0.1")
    box.wait_cycles(int(0.3 * F_CPU))  # silent for 3 T with the output off
    assert tb.ask("WDOG?") == "0.100000,IDLE,0"  # nothing to cut, nothing queued
    assert tb.ask("SYST:ERR?") == '0,"No error"'
    assert len(box.edges("OC1A")) == n0 and tb.ask("OUTP?") == "OFF"
    tb.ok("*RST")
    assert tb.ask("WDOG?") == "10.000000,IDLE,0"  # *RST: the default again
