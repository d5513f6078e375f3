"""Firmware in the loop: the trigger-box driver against the real firmware in the AVR emulator.

Each test powers up a fresh box (:class:`~vts_hw.sim_devices.trigger_box.SimTriggerBox`: the
firmware ELF on simavr, in real time, its UART on a pty) and drives it through the real
:class:`~vts_hw.drivers.trigger_box.TriggerBox` over pyserial. What the output pins did comes
from the emulator's own log (``sim.edges()``, in emulated cycles at 16 MHz), and what reached
the device's UART from ``sim.uart()``: the driver is checked against what really happened,
not against what the firmware says happened. Waits are in emulated time (``wait_cycles``),
so a slow host makes the tests slower, not wrong.

The emulator and the firmware are built by ``make -C firmware`` (which installs the Debian
toolchain when missing); these tests never skip.
"""

from __future__ import annotations

import re
import time

import pytest

from vts_hw.drivers.trigger import TriggerLog, Unsupported, read_log
from vts_hw.drivers.trigger_box import BoxGone, BoxRefused, TriggerBox
from vts_hw.sim_devices.trigger_box import F_CPU, SimTriggerBox

CYCLES_PER_US = F_CPU // 1_000_000
TICK_CYCLES = 2000  # the firmware's 125 us tick (Timer2)
# simavr runs its timers between instructions, so it logs a pin change up to an instruction
# (a few cycles) late: a 1 600 000-cycle period shows as 1 600 000 or 1 600 001
EMU_JITTER = 4


@pytest.fixture()
def sim():
    with SimTriggerBox() as s:
        yield s


@pytest.fixture()
def csv_path(tmp_path):
    return tmp_path / "session" / "trigger.csv"


@pytest.fixture()
def box(sim, csv_path):
    b = TriggerBox(sim.port, log=TriggerLog(csv_path), timeout=2.0)
    yield b
    b.close()


def ms(n: float) -> int:
    return int(n * F_CPU / 1000)


def rising(sim, pin):
    return [e.cycle for e in sim.edges(pin) if e.value == 1]


def falling(sim, pin):
    return [e.cycle for e in sim.edges(pin) if e.value == 0]


def periods_exact(edges, period) -> bool:
    """Every period ``period`` cycles, to the emulator's granularity, with no drift over the run."""
    return (
        all(abs(b - a - period) <= EMU_JITTER for a, b in zip(edges, edges[1:]))
        and abs(edges[-1] - edges[0] - (len(edges) - 1) * period) <= EMU_JITTER
    )


def rx_bytes(sim) -> bytes:
    return bytes(b.value for b in sim.uart() if b.direction == "RX")


# ---- identity and settings --------------------------------------------------------------------------


def test_identify(box):
    idn = box.identify()
    assert (idn.vendor, idn.model) == ("VTS", "TRIGGERBOX")
    assert idn.serial == "0000"  # the build's default serial number
    assert re.fullmatch(r"\d+\.\d+\.\d+", idn.firmware)
    assert "TRIGGERBOX serial 0000" in repr(box)


def test_configure_10_hz_25_percent_reads_back(sim, box):
    st = box.configure(10, 0.25)
    assert st.frequency_hz == pytest.approx(10.0, rel=1e-9)
    assert st.duty == pytest.approx(0.25, abs=1e-6)
    assert not st.running and st.errors == ()
    assert (box.frequency_hz, box.duty) == (st.frequency_hz, st.duty)
    # the exact lines that reached the device's UART, in order
    assert rx_bytes(sim) == (
        b"SYST:ERR?\nFREQ 10\nDUTY 0.25\nOUTP?\nFREQ?\nDUTY?\nEDGES?\nWDOG?\nSYST:ERR?\nFREQ?\nDUTY?\n"
    )


def test_configure_returns_the_frequency_the_timer_makes(box):
    # 7 Hz at 16 MHz: 2285714.28 cycles a period, not a whole number: the box says what it
    # makes (7.000000875 Hz with this firmware)
    st = box.configure(7, 0.5)
    assert st.frequency_hz == pytest.approx(7.0, rel=1e-5)
    assert st.frequency_hz == box.frequency_hz


# ---- the square wave and the start pulses --------------------------------------------------------------


def test_start_makes_the_square_wave_the_log_shows(sim, box, csv_path):
    box.configure(10, 0.25)
    st = box.start()
    assert st.running and st.edges >= 1
    sim.wait_cycles(ms(520))
    end = box.stop()
    assert not end.running

    up, down = rising(sim, "OC1A"), falling(sim, "OC1A")
    assert len(up) == end.edges >= 5  # 0.52 s at 10 Hz, plus the stop
    assert periods_exact(up, ms(100))  # 100 ms periods, Timer1-exact
    assert len(down) == len(up)  # it ended on a whole period ...
    assert all(abs(d - u - ms(25)) <= EMU_JITTER for u, d in zip(up, down))  # ... each high 25 ms
    # the box's edge times are the emulator's, to the microsecond
    assert st.first_edge_device_us == end.first_edge_device_us
    assert abs(end.first_edge_device_us - up[0] / CYCLES_PER_US) <= 1
    assert abs(end.last_edge_device_us - up[-1] / CYCLES_PER_US) <= 1
    assert not rising(sim, "CH1") and not rising(sim, "CH2")  # start() is the wave alone

    edge_rows = [r for r in read_log(csv_path) if r["kind"] == "edge"]
    assert [int(r["device_time_us"]) for r in edge_rows] == [end.first_edge_device_us, end.last_edge_device_us]


def test_fire_starts_the_wave_and_both_start_pulses_together(sim, box):
    box.configure(10, 0.25)
    st = box.fire()
    assert st.running and st.edges >= 1
    sim.wait_cycles(ms(150))
    end = box.stop()

    wave, ch1, ch2 = rising(sim, "OC1A")[0], rising(sim, "CH1")[0], rising(sim, "CH2")[0]
    assert max(wave, ch1, ch2) - min(wave, ch1, ch2) <= 16  # within 1 us
    # the pulses are the default 100 ms wide (to the 125 us tick)
    for pin, start in (("CH1", ch1), ("CH2", ch2)):
        (stop,) = falling(sim, pin)
        assert abs(stop - start - ms(100)) <= TICK_CYCLES
    assert abs(end.first_edge_device_us - wave / CYCLES_PER_US) <= 1
    assert len(rising(sim, "OC1A")) == end.edges


def test_fire_with_a_pulse_width_and_a_lone_pulse(sim, box):
    box.configure(100, 0.5)
    box.fire(pulse_ms=20)
    sim.wait_cycles(ms(30))
    box.stop()
    box.pulse(2, 5)
    sim.wait_cycles(ms(10))
    (c1_up,), (c1_down,) = rising(sim, "CH1"), falling(sim, "CH1")
    assert abs(c1_down - c1_up - ms(20)) <= TICK_CYCLES
    c2_up, c2_down = rising(sim, "CH2"), falling(sim, "CH2")
    assert len(c2_up) == 2 and abs(c2_down[1] - c2_up[1] - ms(5)) <= TICK_CYCLES
    assert c2_up[1] > rising(sim, "OC1A")[-1]  # the lone pulse after the wave ended


def test_reset_restores_the_defaults(box):
    box.configure(50, 0.3)
    box.start()
    box.reset()  # waits for the last period, then the box is at its defaults
    st = box.status()
    assert not st.running
    assert (st.frequency_hz, st.duty) == (pytest.approx(1.0), pytest.approx(0.5))


# ---- refusals ------------------------------------------------------------------------------------------


def test_bad_values_are_refused_before_anything_is_sent_and_bad_commands_change_nothing(sim, box):
    box.configure(10, 0.25)
    box.start()
    sent = rx_bytes(sim)
    refused = [
        (ValueError, lambda: setattr(box, "frequency_hz", 5000)),
        (ValueError, lambda: setattr(box, "duty", 1.5)),
        (ValueError, lambda: box.configure(0.01, 0.5)),
        (Unsupported, lambda: box.configure(10, 0.5, high_v=3.3)),
        (ValueError, lambda: box.pulse(3, 10)),
        (ValueError, lambda: box.pulse(1, 0)),
        (ValueError, lambda: box.fire(pulse_ms=0)),
    ]
    for exc, bad in refused:
        with pytest.raises(exc):
            bad()
    assert rx_bytes(sim) == sent  # not one byte reached the device

    # the same mistakes sent raw: the firmware refuses them itself and the wave runs on
    t_bad = sim.cycles_now()
    with pytest.raises(BoxRefused, match=r"refused 'FREQ 5000': ERR -222 Data out of range") as e:
        box.query("FREQ 5000")
    assert e.value.code == -222
    with pytest.raises(BoxRefused, match=r"ERR -221 Settings conflict \(.*stop\(\) first\)"):
        box.query("FREQ 5")  # a good value, but not while running
    with pytest.raises(BoxRefused, match=r"refused 'WOBBLE 3': ERR -113 Undefined header"):
        box.query("WOBBLE 3")
    sim.wait_cycles(ms(250))
    st = box.status()
    assert st.running and st.frequency_hz == pytest.approx(10.0) and st.duty == pytest.approx(0.25)
    assert st.errors == ()  # the three were raised already
    up = rising(sim, "OC1A")
    assert any(c > t_bad for c in up)
    assert periods_exact(up, ms(100))  # the wave never missed a beat
    box.stop()


# ---- the clock ---------------------------------------------------------------------------------------


def test_clock_mapping_over_5_s(box, csv_path):
    m = box.clock_mapping(samples=100, over_s=5.0)
    # The emulator keeps emulated time in step with the host's clock, so the true drift is 0.
    # But its pacing lets the two wander by 0.1-0.2 ms, which over 5 s is tens of ppm: 30
    # mappings on fresh boxes gave -88 to +38 ppm (SD 31 ppm), standard errors 10-33 ppm and
    # residuals 120-280 us (docs/decisions/0011). A few ppm is tested on synthetic round trips.
    # Under CPU contention the emulator lags the host and catches up, and over 5 s that is an
    # apparent drift of a few hundred ppm that the fit rightly reports: so the drift is judged
    # against the fit's own standard error, and what matters most is checked below: fresh round
    # trips are predicted to within their half round trip plus the wander.
    # (standard errors up to 112 ppm were seen with the load at 5 busy processes per core)
    assert box.drift_se_ppm < 250
    assert abs(m.drift_ppm) < 50 + 6 * box.drift_se_ppm
    assert m.residual_s < 1e-3  # 120-280 us idle (0011); 0.62 ms seen on a busy machine
    assert 0 < m.uncertainty_s < 2e-3
    assert 40 <= m.samples <= 50  # the best half of 100, less any outliers of the fit
    # the mapping predicts fresh round trips to within their own half round trip + the wander
    for _ in range(5):
        reply, sent, received = box._exchange("TIME?")
        mid = (sent + received) / 2
        assert abs(m.to_host(int(reply)) - mid) < (received - sent) / 2 + 1e-3
    events = [r for r in read_log(csv_path) if r["kind"] == "event" and "clock mapping" in r["text"]]
    assert len(events) == 1 and int(events[0]["device_time_us"]) == m.ref_device_us


def test_edges_are_logged_in_host_time_after_a_clock_mapping(sim, box, csv_path):
    box.configure(20, 0.5)
    box.clock_mapping(samples=20, over_s=1.0)
    t0 = time.time()
    box.fire()
    t1 = time.time()
    edge = [r for r in read_log(csv_path) if r["kind"] == "edge"][-1]
    assert "mapped from the box clock" in edge["text"]
    # the first edge happened between sending *TRG and its reply, give or take the mapping
    assert t0 - 2e-3 < float(edge["host_time"]) < t1 + 2e-3
    box.stop()


def test_64_bit_device_time_past_2_to_the_32_us():
    # a build whose clock starts just before 2^32 us: a 32-bit count would wrap at once
    with SimTriggerBox(firmware="trigger_box_late") as sim, TriggerBox(sim.port) as box:
        assert box.device_time_us() > 2**32
        m = box.clock_mapping(samples=10, over_s=0.5)
        assert m.ref_device_us > 2**32
        reply, sent, received = box._exchange("TIME?")
        # a 32-bit count would be 4295 s off; the bound is the host's jitter over a 0.5 s fit
        # (0.1-0.5 ms idle; 3.2 ms seen once under a loaded make test, the fit's slope thrown by it)
        assert abs(m.to_host(int(reply)) - (sent + received) / 2) < 20e-3

        box.configure(100, 0.5)
        runs = []
        for go in (box.start, box.fire):
            go()
            sim.wait_cycles(ms(50))
            st = box.stop()
            up = rising(sim, "OC1A")[sum(r[1] for r in runs) :]
            runs.append((st, len(up), up[0]))
        for st, n, _first_cycle in runs:
            assert st.edges == n and st.first_edge_device_us > 2**32
            assert st.last_edge_device_us - st.first_edge_device_us == (n - 1) * 10_000
        # device time = emulated cycles / 16 + where the build started its clock, in both runs
        offsets = [st.first_edge_device_us - first_cycle / CYCLES_PER_US for st, n, first_cycle in runs]
        assert abs(offsets[0] - offsets[1]) <= 1
        assert 2**32 - 10_000_000 < offsets[0] < 2**32


# ---- a box that vanishes -------------------------------------------------------------------------------


def test_unplug_mid_session_is_one_clear_error_and_the_log_survives(sim, box, csv_path):
    box.identify()
    box.configure(10, 0.25)
    box.start()
    before = read_log(csv_path)
    sim.unplug()
    with pytest.raises(BoxGone, match=rf"^trigger box on {re.escape(box.port)} is gone \(unplugged\?\)"):
        box.status()
    with pytest.raises(BoxGone, match="is gone"):
        box.stop()
    assert "gone" in repr(box)
    box.close()

    rows = read_log(csv_path)
    assert rows[: len(before)] == before  # nothing written before was lost or changed
    after = rows[len(before) :]
    assert [r["kind"] for r in after] == ["cmd", "event", "event"]
    assert after[0]["text"] == "OUTP?" and after[1]["text"].startswith("port gone during OUTP?")
    assert after[2]["text"].startswith("closed")
    with open(csv_path, "rb") as f:
        assert f.read().endswith(b"\n")  # whole lines only
    # every command before the unplug has its reply
    kinds = [r["kind"] for r in before if r["kind"] in ("cmd", "reply")]
    assert kinds == ["cmd", "reply"] * (len(kinds) // 2)
