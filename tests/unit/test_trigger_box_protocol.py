"""Byte-exact protocol tests of the trigger-box driver against a scripted serial port
(tests/scripted_serial.py): opening, every command's bytes, errors on the line, odds and ends.
trigger.csv and the clock mapping: tests/unit/test_trigger_box_clock.py."""

from __future__ import annotations

import pytest
import serial

from scripted_serial import PORT, STATUS_OFF, Fail, FakeClock, ProtocolMismatch, expected_protocol, lines
from vts_hw.drivers.trigger import (
    CLOCK,
    DUTY,
    EDGES,
    FIRE,
    FREQUENCY,
    LEVELS,
    PULSE,
    WATCHDOG,
    TriggerError,
    TriggerGenerator,
    Unsupported,
)
from vts_hw.drivers.trigger_box import BoxGone, BoxRefused, TriggerBox, number_text

# ---- the helper itself ----------------------------------------------------------------------------


def test_the_scripted_port_catches_a_wrong_command_order_and_leftovers():
    with pytest.raises(ProtocolMismatch, match="expected b'FREQ\\?\\\\n', got b'DUTY\\?\\\\n'"):
        with expected_protocol(lines(("FREQ?", "10"), ("DUTY?", "0.5"))) as box:
            box.duty
    with pytest.raises(ProtocolMismatch, match="1 exchange\\(s\\) never made"):
        with expected_protocol(lines(("FREQ?", "10"), ("DUTY?", "0.5"))) as box:
            box.frequency_hz
    with pytest.raises(ProtocolMismatch, match="written after the script"):
        with expected_protocol([]) as box:
            box.frequency_hz


# ---- opening --------------------------------------------------------------------------------------


def test_open_sends_nothing_and_uses_the_line_settings():
    with expected_protocol([], timeout=0.5) as box:
        assert box.fake.port == PORT
        assert box.fake.kwargs == {"baudrate": 115200, "timeout": 0.5, "write_timeout": 0.5}
    assert isinstance(box, TriggerGenerator)
    assert box.capabilities == {FREQUENCY, DUTY, PULSE, FIRE, CLOCK, EDGES, WATCHDOG}
    assert LEVELS not in box.capabilities  # fixed TTL outputs


def test_a_port_that_cannot_be_opened_is_one_clear_error():
    def factory(port, **kw):
        raise serial.SerialException(f"[Errno 2] could not open port {port}: No such file or directory")

    with pytest.raises(TriggerError, match=r"cannot open the trigger box on /dev/ttyNOPE: .*could not open"):
        TriggerBox("/dev/ttyNOPE", serial_factory=factory)


# ---- every command's bytes --------------------------------------------------------------------------


def test_identify():
    with expected_protocol([(b"*IDN?\n", b"VTS,TRIGGERBOX,0042,1.0.0\n")]) as box:
        idn = box.identify()
    assert (idn.vendor, idn.model, idn.serial, idn.firmware) == ("VTS", "TRIGGERBOX", "0042", "1.0.0")
    assert "serial 0042 firmware 1.0.0" in repr(box)


def test_identify_refuses_another_device():
    with expected_protocol(lines(("*IDN?", "Arduino,Uno,1,2"))) as box:
        with pytest.raises(TriggerError, match="not 'VTS,TRIGGERBOX,<serial>,<firmware>'"):
            box.identify()


def test_reset_waits_for_the_output_to_be_off():
    # *RST ends a running wave on a whole period: OUTP? says ON until then
    with expected_protocol(
        [(b"*RST\n", b"OK\n"), (b"OUTP?\n", b"ON\n"), (b"OUTP?\n", b"ON\n"), (b"OUTP?\n", b"OFF\n")]
    ) as box:
        box.reset()
    assert box.clock.t - 1_700_000_000.0 == pytest.approx(0.02)  # two polls of 10 ms


def test_clear_errors():
    with expected_protocol([(b"*CLS\n", b"OK\n")]) as box:
        box.clear_errors()


def test_fire_pulse_width():
    with expected_protocol(lines(("PULSE:WIDTH 250", "OK"), ("PULSE:WIDTH?", "250"))) as box:
        box.fire_pulse_ms = 250.0
        assert box.fire_pulse_ms == 250
    with expected_protocol([]) as box:
        for bad in (0, 10_001, 2.5, "100", True):
            with pytest.raises(ValueError, match="start pulse width must be a whole number of ms"):
                box.fire_pulse_ms = bad


def test_settings_write_and_read_exact_bytes():
    with expected_protocol(
        [
            (b"FREQ 10\n", b"OK\n"),
            (b"FREQ?\n", b"10.000\n"),
            (b"DUTY 0.25\n", b"OK\n"),
            (b"DUTY?\n", b"0.250000\n"),
            (b"FREQ 0.1\n", b"OK\n"),
            (b"FREQ 1000\n", b"OK\n"),
            (b"FREQ 333.333\n", b"OK\n"),
            (b"DUTY 0.99\n", b"OK\n"),
        ]
    ) as box:
        box.frequency_hz = 10
        assert box.frequency_hz == 10.0
        box.duty = 0.25
        assert box.duty == 0.25
        box.frequency_hz = 0.1
        box.frequency_hz = 1000.0
        box.frequency_hz = 1000 / 3
        box.duty = 0.99


@pytest.mark.parametrize(
    "attr,value",
    [
        ("frequency_hz", 0.09),
        ("frequency_hz", 1000.5),
        ("frequency_hz", float("nan")),
        ("frequency_hz", "10"),
        ("frequency_hz", True),
        ("duty", 0.0),
        ("duty", 0.995),
        ("duty", 1),
        ("duty", None),
    ],
)
def test_validators_refuse_before_anything_is_written(attr, value):
    with expected_protocol([]) as box:
        with pytest.raises(ValueError, match="nothing was sent"):
            setattr(box, attr, value)
    assert box.fake.done == 0 and box.fake.written == b""


def test_configure_sets_reads_back_and_checks_errors():
    pairs = lines(
        ("SYST:ERR?", '0,"No error"'),
        ("FREQ 10", "OK"),
        ("DUTY 0.25", "OK"),
        ("OUTP?", "OFF"),
        ("FREQ?", "9.99998"),
        ("DUTY?", "0.25"),
        ("EDGES?", "0,0,0"),
        ("WDOG?", "10.000000,IDLE,0"),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        st = box.configure(10, 0.25)
    # what the box confirms, not what was asked
    assert st.frequency_hz == 9.99998 and st.duty == 0.25 and not st.running
    assert st.edges == 0 and st.first_edge_device_us is None and st.errors == ()
    assert st.device == "triggerbox"


def test_configure_logs_and_ignores_errors_left_from_before():
    pairs = lines(
        ("SYST:ERR?", '-113,"Undefined header"'),
        ("SYST:ERR?", '0,"No error"'),
        ("FREQ 2.5", "OK"),
        ("DUTY 0.5", "OK"),
        ("OUTP?", "OFF"),
        ("FREQ?", "2.5"),
        ("DUTY?", "0.5"),
        ("EDGES?", "0,0,0"),
        ("WDOG?", "10.000000,IDLE,0"),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        st = box.configure(2.5)
    assert not st.running
    assert any(r[3] == "event" and 'queued before configure: -113,"Undefined header"' in r[4] for r in box.log.lines)


def test_configure_raises_on_an_error_queued_by_the_new_settings():
    pairs = lines(
        ("SYST:ERR?", '0,"No error"'),
        ("FREQ 10", "OK"),
        ("DUTY 0.25", "OK"),
        *STATUS_OFF[:5],
        ("SYST:ERR?", '-222,"Data out of range"'),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        with pytest.raises(TriggerError, match='reports errors after configure: -222,"Data out of range"'):
            box.configure(10, 0.25)


def test_configure_raises_when_the_box_confirms_something_else():
    pairs = lines(
        ("SYST:ERR?", '0,"No error"'),
        ("FREQ 10", "OK"),
        ("DUTY 0.25", "OK"),
        ("OUTP?", "OFF"),
        ("FREQ?", "1"),
        ("DUTY?", "0.25"),
        ("EDGES?", "0,0,0"),
        ("WDOG?", "10.000000,IDLE,0"),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        with pytest.raises(TriggerError, match="asked for 10 Hz but confirms 1.0 Hz"):
            box.configure(10, 0.25)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"frequency_hz": 0.05}, "frequency 0.05 Hz is outside"),
        ({"frequency_hz": 10, "duty": 1.2}, "duty cycle 1.2 is outside"),
    ],
)
def test_configure_validates_before_anything_is_written(kwargs, match):
    with expected_protocol([]) as box:
        with pytest.raises(ValueError, match=match):
            box.configure(**kwargs)


@pytest.mark.parametrize("levels", [{"high_v": 5.0}, {"low_v": 0.0}, {"high_v": 3.3, "low_v": 0.0}])
def test_levels_are_unsupported_and_nothing_is_written(levels):
    with expected_protocol([]) as box:
        with pytest.raises(Unsupported, match="triggerbox cannot set output levels: .*fixed 0/5 V TTL"):
            box.configure(10, 0.5, **levels)


def test_start_stop_fire_and_status():
    pairs = lines(
        ("WDOG 10", "OK"),
        ("OUTP ON", "OK"),
        ("OUTP?", "ON"),
        ("FREQ?", "10"),
        ("DUTY?", "0.25"),
        ("EDGES?", "1,5000000,5000000"),
        ("WDOG?", "10.000000,ARMED,0"),
        ("SYST:ERR?", '0,"No error"'),
        ("OUTP OFF", "OK"),
        ("OUTP?", "OFF"),
        ("FREQ?", "10"),
        ("DUTY?", "0.25"),
        ("EDGES?", "30,5000000,7900000"),
        ("WDOG?", "10.000000,IDLE,0"),
        ("SYST:ERR?", '0,"No error"'),
        ("WDOG 10", "OK"),
        ("*TRG", "OK"),
        ("OUTP?", "ON"),
        ("FREQ?", "10"),
        ("DUTY?", "0.25"),
        ("EDGES?", "1,9000125,9000125"),
        ("WDOG?", "10.000000,ARMED,0"),
        ("SYST:ERR?", '0,"No error"'),
        ("PULSE:WIDTH 20", "OK"),
        ("WDOG 10", "OK"),
        ("*TRG", "OK"),
        ("OUTP?", "ON"),
        ("FREQ?", "10"),
        ("DUTY?", "0.25"),
        ("EDGES?", "1,9000125,9000125"),
        ("WDOG?", "10.000000,ARMED,0"),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        st = box.start()
        assert st.running and (st.edges, st.first_edge_device_us) == (1, 5_000_000)
        st = box.stop()
        assert not st.running and (st.edges, st.last_edge_device_us) == (30, 7_900_000)
        st = box.fire()
        assert st.running and st.first_edge_device_us == 9_000_125
        box.fire(pulse_ms=20)


def test_stop_waits_for_the_last_period():
    # OUTP OFF finishes the period under way: OUTP? stays ON until its falling edge
    pairs = lines(
        ("OUTP OFF", "OK"),
        ("OUTP?", "ON"),
        ("FREQ?", "2"),
        ("DUTY?", "0.5"),
        ("EDGES?", "7,5000000,8000000"),
        ("WDOG?", "10.000000,ARMED,0"),
        ("SYST:ERR?", '0,"No error"'),
        ("OUTP?", "ON"),
        ("OUTP?", "ON"),
        ("OUTP?", "OFF"),
        ("OUTP?", "OFF"),
        ("FREQ?", "2"),
        ("DUTY?", "0.5"),
        ("EDGES?", "7,5000000,8000000"),
        ("WDOG?", "10.000000,IDLE,0"),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        st = box.stop()
    assert not st.running and st.edges == 7


def test_stop_without_waiting_reports_the_last_period_running():
    pairs = lines(
        ("OUTP OFF", "OK"),
        ("OUTP?", "ON"),
        ("FREQ?", "0.1"),
        ("DUTY?", "0.5"),
        ("EDGES?", "1,5000000,5000000"),
        ("WDOG?", "10.000000,ARMED,0"),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        assert box.stop(wait=False).running


def test_stop_gives_up_after_one_period():
    # 4 Hz: one period 0.25 s, plus two timeouts of 0.125 s = 0.5 s; polls every 1/16 s here
    clock = FakeClock(1000.0)
    pairs = lines(
        ("OUTP OFF", "OK"),
        ("OUTP?", "ON"),
        ("FREQ?", "4"),
        ("DUTY?", "0.5"),
        ("EDGES?", "7,5000000,6500000"),
        ("WDOG?", "10.000000,ARMED,0"),
        ("SYST:ERR?", '0,"No error"'),
        *[("OUTP?", "ON")] * 10,
    )
    with expected_protocol(
        pairs, timeout=0.125, clock=clock, sleep=lambda s: setattr(clock, "t", clock.t + 0.0625)
    ) as box:
        with pytest.raises(
            TriggerError,
            match=r"still reports its output ON 0.25 s \(one period\) "
            r"after 'OUTP OFF'",
        ):
            box.stop()


def test_start_raises_if_the_box_stays_off():
    pairs = lines(("WDOG 10", "OK"), ("OUTP ON", "OK"), *STATUS_OFF)
    with expected_protocol(pairs) as box:
        with pytest.raises(TriggerError, match="switched on but reports its output OFF"):
            box.start()


def test_status_drains_the_error_queue():
    pairs = lines(
        *STATUS_OFF[:5],
        ("SYST:ERR?", '-113,"Undefined header"'),
        ("SYST:ERR?", '-222,"Data out of range"'),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        st = box.status()
    assert st.errors == ('-113,"Undefined header"', '-222,"Data out of range"')


def test_pulse():
    with expected_protocol(lines(("PULSE 1 100", "OK"), ("PULSE 2 10000", "OK"), ("PULSE 1 1", "OK"))) as box:
        box.pulse(1, 100)
        box.pulse(2, 10_000)
        box.pulse(1, 1.0)


@pytest.mark.parametrize(
    "channel,ms,match",
    [
        (0, 100, "channel must be 1"),
        (3, 100, "channel must be 1"),
        (1, "100", "whole number of ms"),
        (1, 0, "whole number of ms"),
        (1, 10_001, "whole number"),
        (2, 1.5, "whole number"),
        (2, True, "whole number"),
        (1, float("inf"), "whole number"),
    ],
)
def test_pulse_validates_before_anything_is_written(channel, ms, match):
    with expected_protocol([]) as box:
        with pytest.raises(ValueError, match=match):
            box.pulse(channel, ms)


def test_time_and_edges_take_64_bit_counts():
    big = 2**63 + 12345
    with expected_protocol(lines(("TIME?", str(big)), ("EDGES?", f"3,{big},{big + 200000}"))) as box:
        assert box.device_time_us() == big
        assert box.edges() == (3, big, big + 200_000)


@pytest.mark.parametrize("reply", ["3,100", "x,1,2", "3,-1,2", "3,1.5,2", ""])
def test_a_malformed_edges_reply_is_an_error(reply):
    with expected_protocol([(b"EDGES?\n", reply.encode() + b"\n")]) as box:
        with pytest.raises(TriggerError, match="answered 'EDGES\\?' with"):
            box.edges()


def test_a_setting_answered_with_something_other_than_ok():
    with expected_protocol(lines(("FREQ 5", "?"))) as box:
        with pytest.raises(TriggerError, match="answered 'FREQ 5' with '\\?', not OK"):
            box.frequency_hz = 5


# ---- errors on the line -----------------------------------------------------------------------------


def test_err_reply_raises_with_the_device_message():
    with expected_protocol(lines(("FREQ 10", "ERR 2 busy"), ("BOGUS", "ERR 1 unknown command"))) as box:
        with pytest.raises(BoxRefused, match="trigger box on /dev/ttyFAKE0 refused 'FREQ 10': ERR 2 busy") as e:
            box.frequency_hz = 10
        assert (e.value.code, e.value.device_message) == (2, "busy")
        with pytest.raises(TriggerError, match="refused 'BOGUS': ERR 1 unknown command"):
            box.query("BOGUS")


def test_errors_already_raised_are_not_reported_again_by_the_queue():
    # the box answers ERR and also queues the error; status() lists only errors not yet raised
    pairs = lines(
        ("FREQ 10", "ERR -221 Settings conflict"),
        ("BOGUS", "ERR -113 Undefined header"),
        *STATUS_OFF[:5],
        ("SYST:ERR?", '-221,"Settings conflict"'),
        ("SYST:ERR?", '-363,"Input buffer overrun"'),
        ("SYST:ERR?", '-113,"Undefined header"'),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        with pytest.raises(
            BoxRefused,
            match=r"refused 'FREQ 10': ERR -221 Settings conflict \(the box "
            r"takes a new frequency or duty only while its output is "
            r"off: stop\(\) first\)",
        ):
            box.frequency_hz = 10
        with pytest.raises(BoxRefused):
            box.query("BOGUS")
        st = box.status()
    assert st.errors == ('-363,"Input buffer overrun"',)
    assert sum("already raised" in r[4] for r in box.log.lines) == 2


def test_no_answer_is_a_timeout_naming_port_and_command():
    with expected_protocol([(b"FREQ 10\n", b"")]) as box:
        with pytest.raises(
            TriggerError,
            match=r"^trigger box on /dev/ttyFAKE0 did not answer 'FREQ 10' "
            r"within 1 s$",
        ):
            box.frequency_hz = 10


def test_half_a_line_is_a_timeout_too():
    with expected_protocol([(b"FREQ?\n", b"10.0")], timeout=0.25) as box:
        with pytest.raises(TriggerError, match=r"did not answer 'FREQ\?' within 0.25 s \(only '10.0' came\)"):
            box.frequency_hz


def test_stale_input_is_discarded_and_logged_before_the_next_command():
    # a reply that came late (or a boot banner) must not be taken as the next command's answer
    with expected_protocol([(b"FREQ?\n", b"10\nOK\n"), (b"DUTY?\n", b"0.5\n")]) as box:
        assert box.frequency_hz == 10
        assert box.duty == 0.5
    assert [r[3:] for r in box.log.lines[1:]] == [
        ["cmd", "FREQ?"],
        ["reply", "10"],
        ["event", "discarded stale input 'OK\\n'"],
        ["cmd", "DUTY?"],
        ["reply", "0.5"],
    ]


def test_crlf_replies_are_accepted():
    with expected_protocol([(b"OUTP?\n", b"ON\r\n")]) as box:
        assert box.query("OUTP?") == "ON"


@pytest.mark.parametrize("on", ["read", "write"])
def test_a_vanished_port_is_one_clear_error_and_stays_gone(on):
    exc = (
        serial.SerialException("read failed: [Errno 5] Input/output error")
        if on == "read"
        else OSError(5, "Input/output error")
    )
    with expected_protocol([(b"FREQ?\n", b"10\n"), (b"DUTY?\n", Fail(exc, on))]) as box:
        assert box.frequency_hz == 10
        with pytest.raises(BoxGone, match=r"^trigger box on /dev/ttyFAKE0 is gone \(unplugged\?\): 'DUTY\?'"):
            box.duty
        # later calls say the same, without touching the port
        with pytest.raises(BoxGone, match="is gone \\(unplugged\\?\\): cannot send 'OUTP\\?'"):
            box.query("OUTP?")
    assert not box.fake.is_open
    assert "gone" in repr(box)
    box.close()  # closing a gone box is quiet


def test_commands_must_be_one_ascii_line():
    with expected_protocol([]) as box:
        for bad in ["", "FREQ 1\nOUTP ON", "FREQ\r", "FRÉQ?"]:
            with pytest.raises(ValueError, match="one non-empty ASCII line"):
                box.query(bad)


def test_closed_box_refuses_commands():
    with expected_protocol([]) as box:
        box.close()
        assert "closed" in repr(box)
        with pytest.raises(TriggerError, match="is closed"):
            box.query("*IDN?")
    assert not box.fake.is_open


# ---- odds and ends ------------------------------------------------------------------------------------


def test_number_text():
    assert [number_text(v) for v in (10, 0.1, 1000.0, 0.25, 12.5, 1000 / 3, 0.01)] == [
        "10",
        "0.1",
        "1000",
        "0.25",
        "12.5",
        "333.333",
        "0.01",
    ]


def test_repr_and_thread_safety():
    import threading

    n = 50
    pairs = lines(*[("TIME?", str(1000 + i)) for i in range(n)])
    with expected_protocol(pairs, name="box-a") as box:
        got = []
        threads = [threading.Thread(target=lambda: got.append(box.device_time_us())) for _ in range(n)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert sorted(got) == list(range(1000, 1000 + n))
    assert repr(box).startswith("<TriggerBox 'box-a' on /dev/ttyFAKE0 at 115200 baud")


def test_start_raises_when_the_box_confirms_no_square_wave():
    # found by bench/fuzz.py (trigger_box): a duty of 1.5 read back made the log's wave_start a ValueError
    pairs = lines(
        ("WDOG 10", "OK"),
        ("OUTP ON", "OK"),
        ("OUTP?", "ON"),
        ("FREQ?", "10"),
        ("DUTY?", "1.5"),
        ("EDGES?", "1,5,5"),
        ("WDOG?", "10.000000,ARMED,0"),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        with pytest.raises(TriggerError, match="confirms 10.0 Hz at duty 1.5: not a square wave"):
            box.start()


# ---- the host watchdog (docs/decisions/0083) ------------------------------------------------------------

ON = [("OUTP?", "ON"), ("FREQ?", "10"), ("DUTY?", "0.25"), ("EDGES?", "1,5000000,5000000")]


def test_the_watchdog_is_set_before_every_start():
    pairs = lines(
        ("WDOG 2.5", "OK"),
        ("OUTP ON", "OK"),
        *ON,
        ("WDOG?", "2.500000,ARMED,0"),
        ("SYST:ERR?", '0,"No error"'),
        ("OUTP OFF", "OK"),
        *STATUS_OFF,
        ("WDOG 0", "OK"),
        ("*TRG", "OK"),
        *ON,
        ("WDOG?", "0.000000,OFF,0"),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs, watchdog_s=2.5) as box:
        st = box.start()
        assert box.heartbeat is not None and box.heartbeat.every_s == 0.625  # a quarter of T
        assert st.extra["watchdog"] == {"seconds": 2.5, "state": "armed", "cut_device_us": None}
        assert st.notes == ("watchdog 2.5 s: the box switches its output off 2.5 s after the last command it hears",)
        box.stop()
        box.heartbeat = None
        box.watchdog_s = 0  # the wave outlives the program (vts trigger start, fire)
        st = box.fire()
        assert box.heartbeat is None and "watchdog off" in st.notes[0]


@pytest.mark.parametrize("bad", [0.05, -1, 3600.5, float("nan"), "10", True])
def test_a_watchdog_time_out_of_range_is_refused_before_anything_is_sent(bad):
    from vts_hw.drivers.trigger import OutOfRange
    from vts_hw.drivers.trigger_box import BoxSettings

    with pytest.raises(OutOfRange, match="watchdog time must be 0 \\(off\\) or 0.1 to 3600 s"):
        with expected_protocol([], watchdog_s=bad):
            pass
    with pytest.raises(ValueError, match="watchdog_s"):  # rig.yaml's trigger: watchdog_s
        BoxSettings(watchdog_s=bad)


def test_the_heartbeat_speaks_only_after_silence_and_stops_at_a_cut(tmp_path):
    from vts_hw.drivers.trigger import TriggerLog, read_log

    mono = FakeClock(0.0)
    clock = FakeClock(1000.0)
    pairs = lines(
        ("WDOG 1", "OK"),
        ("OUTP ON", "OK"),
        *ON,
        ("WDOG?", "1.000000,ARMED,0"),
        ("SYST:ERR?", '0,"No error"'),
        ("WDOG?", "1.000000,ARMED,0"),  # the first beat
        ("WDOG?", "1.000000,TRIPPED,7250000"),
        ("EDGES?", "23,5000000,7200000"),
    )  # the host stalled
    path = tmp_path / "trigger.csv"
    with expected_protocol(pairs, watchdog_s=1, monotonic=mono, clock=clock, log=TriggerLog(path, clock=clock)) as box:
        box.start()
        hb = box.heartbeat
        assert hb.beat_if_due() and box.fake.done == 8  # the driver spoke just now: nothing sent
        mono.t += 0.2
        assert hb.beat_if_due() and box.fake.done == 8  # 0.2 s of silence: not yet (every 0.25 s)
        mono.t += 0.1
        assert hb.beat_if_due() and box.fake.done == 9  # a beat; the box says ARMED: go on
        mono.t += 0.3
        assert not hb.beat_if_due()  # the box cut the wave: no more beats
        mono.t += 5
        assert not hb.beat_if_due() and box.fake.done == 11  # stopped: nothing more sent
    rows = read_log(path)
    cut = [r for r in rows if r["kind"] == "event" and "watchdog cut" in r["text"]]
    assert len(cut) == 1 and cut[0]["device_time_us"] == "7250000"
    assert "heard nothing from this host for 1 s" in cut[0]["text"]
    stop = [r for r in rows if r["kind"] == "wave_stop"]
    start = [r for r in rows if r["kind"] == "wave_start"]
    # no clock mapping: the cut placed from the first edge's device time, on the start's host time
    assert len(stop) == 1 and "rising_edges=23" in stop[0]["text"] and "time=host_write" in stop[0]["text"]
    assert float(stop[0]["host_time"]) == pytest.approx(float(start[0]["host_time"]) + 2.25, abs=1e-6)


def test_status_after_a_cut_says_when_and_the_stop_adds_no_second_end():
    pairs = lines(
        ("OUTP?", "OFF"),
        ("FREQ?", "10"),
        ("DUTY?", "0.25"),
        ("EDGES?", "23,5000000,7200000"),
        ("WDOG?", "10.000000,TRIPPED,7250000"),
        ("TIME?", "9750000"),
        ("SYST:ERR?", '-310,"Watchdog: host silent, output off"'),
        ("SYST:ERR?", '0,"No error"'),
        ("OUTP OFF", "OK"),
        ("OUTP?", "OFF"),
        ("FREQ?", "10"),
        ("DUTY?", "0.25"),
        ("EDGES?", "23,5000000,7200000"),
        ("WDOG?", "10.000000,TRIPPED,7250000"),
        ("TIME?", "9760000"),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        st = box.status()  # a new connection after the host died (vts trigger status)
        assert not st.running and st.errors == ('-310,"Watchdog: host silent, output off"',)
        assert st.extra["watchdog"] == {"seconds": 10.0, "state": "tripped", "cut_device_us": 7_250_000}
        assert st.notes == (
            "watchdog TRIPPED: the box heard nothing from its host for 10 s and cut the square "
            "wave (output off) at device time 7.250000 s, 2.5 s ago",
        )
        box.stop()
    assert sum("watchdog cut" in r[4] for r in box.log.lines) == 1  # one event for one cut
    assert not [r for r in box.log.lines if r[3] == "wave_stop"]  # a wave another program started


@pytest.mark.parametrize(
    "reply", ["10,ARMED", "10.000000,MAYBE,0", "x,OFF,0", "10.000000,TRIPPED,-1", "4000.000000,OFF,0"]
)
def test_a_malformed_watchdog_reply_is_an_error(reply):
    with expected_protocol(lines(("WDOG?", reply))) as box:
        with pytest.raises(TriggerError, match="answered 'WDOG\\?' with .*not a watchdog state"):
            box.watchdog()


def test_a_box_whose_firmware_has_no_watchdog_is_not_switched_on_and_says_why():
    """A box still on firmware 1.0.0 (no WDOG): its status works and says so; a start that asks for
    the watchdog sends nothing more and refuses; one that asks for none (vts trigger start) starts."""
    old = "ERR -113 Undefined header"
    pairs = lines(
        *STATUS_OFF[:4],
        ("WDOG?", old),
        ("SYST:ERR?", '-113,"Undefined header"'),
        ("SYST:ERR?", '0,"No error"'),
        ("WDOG 10", old),
        ("WDOG 0", old),
        ("OUTP ON", "OK"),
        *ON,
        ("WDOG?", old),
        *[("SYST:ERR?", '-113,"Undefined header"')] * 3,
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        st = box.status()
        assert st.errors == () and st.extra["watchdog"] is None
        assert st.notes == ("no host watchdog: its firmware predates it (1.1.0); vts trigger flash updates it",)
        with pytest.raises(
            BoxRefused,
            match=r"^trigger box on /dev/ttyFAKE0 has no host watchdog \(its firmware "
            r"predates 1.1.0\): switched on, it would drive the scanner's gating "
            r"input for ever if this program died, so its output was left off; "
            r"vts trigger flash updates it$",
        ):
            box.start()
        box.watchdog_s = 0
        st = box.start()
        assert st.running and box.heartbeat is None and st.errors == ()  # its refusals were said already


def test_configure_says_before_a_scan_records_that_the_box_has_no_watchdog():
    old = "ERR -113 Undefined header"
    pairs = lines(
        ("SYST:ERR?", '0,"No error"'),
        ("FREQ 10", "OK"),
        ("DUTY 0.25", "OK"),
        *STATUS_OFF[:4],
        ("WDOG?", old),
        ("SYST:ERR?", '-113,"Undefined header"'),
        ("SYST:ERR?", '0,"No error"'),
    )
    with expected_protocol(pairs) as box:
        with pytest.raises(
            TriggerError,
            match=r"^trigger box on /dev/ttyFAKE0 has no host watchdog: its firmware "
            r"predates it \(1.1.0\); vts trigger flash updates it; without it a "
            r"start is refused",
        ):
            box.configure(10, 0.25)
    with expected_protocol(pairs, watchdog_s=0) as box:  # none asked for (vts trigger start)
        assert box.configure(10, 0.25).extra["watchdog"] is None
