"""The simulated rig's Keysight 33522B on a TCP socket on 127.0.0.1, reached through pyvisa and
pyvisa-py as ``TCPIP::127.0.0.1::PORT::SOCKET`` (as a real 33500 on the LAN), and the driver
against it: state that lasts between sessions, the instrument's own answers to bad input, and
what a user sees when the instrument is not there, hangs or goes away."""

from __future__ import annotations

import itertools

import pytest
import pyvisa

from vts_hw.drivers.function_generator import FunctionGenerator
from vts_hw.drivers.trigger import TriggerError, TriggerLog
from vts_hw.sim_devices.keysight_33500 import IDN, Keysight33500
from vts_hw.sim_devices.scpi_server import OUTPUT_LOG_HEADER, SimFunctionGenerator, read_output_log

OK = '+0,"No error"'
UP = '-222,"Data out of range;value clipped to upper limit"'
DOWN = '-222,"Data out of range;value clipped to lower limit"'


def e(x: float) -> str:
    return f"{x:+.14E}"


class Ticks:
    """A clock that says 100.0, 101.0, 102.0 ... (one tick per event)."""

    def __init__(self):
        self._n = itertools.count(100)

    def __call__(self) -> float:
        return float(next(self._n))


@pytest.fixture()
def server():
    with SimFunctionGenerator() as srv:
        yield srv


@pytest.fixture()
def rm():
    return pyvisa.ResourceManager("@py")


def session(rm, srv, timeout_ms=2000):
    return rm.open_resource(srv.resource, read_termination="\n", write_termination="\n", timeout=timeout_ms)


def errors(inst) -> list[str]:
    out = []
    while (reply := inst.query("SYST:ERR?")) != OK:
        out.append(reply)
        assert len(out) < 30
    return out


# ---- the instrument over the socket ----------------------------------------------------------------


def test_it_answers_as_a_33522b_after_rst(server, rm):
    inst = session(rm, server)
    assert server.resource == f"TCPIP::127.0.0.1::{server.port}::SOCKET" and server.port > 0
    assert inst.query("*IDN?") == IDN
    assert inst.query("FUNC?;FREQ?;FUNC:SQU:DCYC?;:VOLT:HIGH?;LOW?;:OUTP?") == ";".join(
        ["SIN", e(1000), e(50), e(0.05), e(-0.05), "0"]
    )
    assert inst.query("SYST:ERR?") == OK
    inst.close()


def test_its_state_lasts_between_sessions(server, rm):
    a = session(rm, server)
    a.write("FUNC SQU;FREQ 1;FUNC:SQU:DCYC 25;:VOLT:HIGH 2.5;LOW 0;:OUTP ON")
    assert a.query("*OPC?") == "1"
    a.close()
    b = session(pyvisa.ResourceManager("@py"), server)  # a new connection, as the next command makes
    assert b.query("FUNC?;FREQ?;FUNC:SQU:DCYC?;:VOLT:HIGH?;LOW?;:OUTP?") == ";".join(
        ["SQU", e(1), e(25), e(2.5), e(0), "1"]
    )
    b.close()


def test_long_forms_any_case_and_the_scpi_path(server, rm):
    inst = session(rm, server)
    inst.write("source2:frequency 2.5KHZ;function:square:dcycle 30")  # DCYC under SOURce2
    inst.write(":SOUR2:VOLT:HIGH 1;LOW -1")  # LOW under SOUR2:VOLT
    inst.write("OUTPut2 1;OUTPut1 OFF")
    assert inst.query("SOUR2:FREQ?;:SOUR2:FUNC:SQU:DCYC?;:SOUR2:VOLT:HIGH?;LOW?") == ";".join(
        [e(2500), e(30), e(1), e(-1)]
    )
    assert inst.query("OUTP2?;OUTP?;FREQ?") == f"1;0;{e(1000)}"  # channel 1 untouched
    assert inst.query("FREQ? MAX;FREQ? MIN") == f"{e(30e6)};{e(1e-6)}"
    assert errors(inst) == []
    inst.write("FUNC:SQU:DCYC 40;FREQ 5")  # FREQ under FUNC:SQU: does not exist
    assert errors(inst) == ['-113,"Undefined header"']


@pytest.mark.parametrize(
    "command, want, queued",
    [
        ("FREQ 4E7", ("FREQ?", e(30e6)), [UP]),
        ("FREQ 1E-7", ("FREQ?", e(1e-6)), [DOWN]),
        ("VOLT:HIGH 6", ("VOLT:HIGH?", e(5)), [UP]),
        ("VOLT:LOW -5.5", ("VOLT:LOW?", e(-5)), [DOWN]),
        ("FUNC SQU;FUNC:SQU:DCYC 0", ("FUNC:SQU:DCYC?", e(0.01)), [DOWN]),
        ("FUNC SQU;FREQ 10E6;FUNC:SQU:DCYC 5", ("FUNC:SQU:DCYC?", e(16)), [DOWN]),  # 16 ns at 10 MHz
        ("FUNC SQU;FUNC:SQU:DCYC 10;FREQ 10E6", ("FREQ?", e(1000)), ['-113,"Undefined header"']),  # FUNC:SQU:FREQ
        (
            "FUNC SQU;FUNC:SQU:DCYC 10;:FREQ 10E6",
            ("FUNC:SQU:DCYC?", e(16)),
            ['-221,"Settings conflict;frequency forced duty cycle change"'],
        ),
        ("VOLT:HIGH -1", ("VOLT:LOW?", e(-1.001)), ['-221,"Settings conflict;low level changed due to high level"']),
        ("VOLT:LOW 3", ("VOLT:HIGH?", e(3.001)), ['-221,"Settings conflict;high level changed due to low level"']),
        ("FREQ 1E6;FUNC RAMP", ("FREQ?", e(200e3)), ['-221,"Settings conflict;frequency changed due to function"']),
    ],
)
def test_a_value_it_cannot_make_is_clipped_or_adjusted_and_an_error_queued(server, rm, command, want, queued):
    inst = session(rm, server)
    inst.write(command)
    assert inst.query(want[0]) == want[1]
    assert errors(inst) == queued


@pytest.mark.parametrize(
    "command, queued",
    [
        ("BOGUS 1", '-113,"Undefined header"'),
        ("FREQUENC 5", '-113,"Undefined header"'),  # neither the short nor the long form
        ("*IDN", '-113,"Undefined header"'),  # a query-only header as a command
        ("FREQ", '-109,"Missing parameter"'),
        ("FREQ 1,2", '-108,"Parameter not allowed"'),
        ("OUTP? 1", '-108,"Parameter not allowed"'),
        ("FREQ fast", '-104,"Data type error"'),
        ("FREQ 5 V", '-131,"Invalid suffix"'),
        ("FUNC SAW", '-224,"Illegal parameter value"'),
        ("OUTP MAYBE", '-224,"Illegal parameter value"'),
        ("OUTP3 1", '-114,"Header suffix out of range"'),
    ],
)
def test_bad_input_is_refused_with_the_scpi_error_and_changes_nothing(server, rm, command, queued):
    inst = session(rm, server)
    state = "FUNC?;FREQ?;FUNC:SQU:DCYC?;:VOLT:HIGH?;LOW?;:OUTP?;OUTP2?"
    before = inst.query(state)
    inst.write(command)
    if command.endswith("? 1"):
        inst.write("*WAI")
    assert errors(inst) == [queued]
    assert inst.query(state) == before


@pytest.mark.parametrize("word, on", [("ON", True), ("1", True), ("OFF", False), ("0", False), ("on", True)])
def test_output_takes_on_off_1_and_0_and_answers_1_or_0(server, rm, word, on):
    inst = session(rm, server)
    inst.write("OUTP ON" if not on else "OUTP OFF")
    inst.write(f"OUTP {word}")
    assert inst.query("OUTP?") == ("1" if on else "0")
    assert errors(inst) == []


def test_the_error_queue_holds_20_then_says_overflow_and_cls_empties_it(server, rm):
    inst = session(rm, server)
    for _ in range(25):
        inst.write("BOGUS")
    got = errors(inst)
    assert len(got) == 20 and got[:19] == ['-113,"Undefined header"'] * 19 and got[19] == '-350,"Queue overflow"'
    inst.write("BOGUS;BOGUS")
    inst.write("*CLS")
    assert inst.query("SYST:ERR?") == OK


def test_rst_restores_the_defaults_but_keeps_the_errors(server, rm):
    inst = session(rm, server)
    inst.write("FUNC SQU;FREQ 7;OUTP 1;BOGUS")
    inst.write("*RST")
    assert inst.query("FUNC?;FREQ?;OUTP?") == f"SIN;{e(1000)};0"
    assert errors(inst) == ['-113,"Undefined header"']


def test_the_output_log_says_when_the_wave_ran(tmp_path, rm):
    with SimFunctionGenerator(Keysight33500(clock=Ticks())) as srv:
        inst = session(rm, srv)
        inst.write("FUNC SQU;FREQ 2;VOLT:HIGH 2.5;LOW 0")  # output off: nothing to log
        inst.write("OUTP 1")  # t=100
        path = srv.log_to(tmp_path / "fgen_output.csv")  # earlier events are written too
        inst.write("FREQ 4")  # t=101: the wave changed while on
        inst.write("OUTP 0")  # t=102
        inst.write("FREQ 9")  # off: not logged
        assert inst.query("*OPC?") == "1"
        runs = srv.instrument.runs(1)
    assert [(r.start, r.stop, r.function, r.frequency_hz, r.high_v, r.low_v) for r in runs] == [
        (100.0, 101.0, "SQU", 2.0, 2.5, 0.0),
        (101.0, 102.0, "SQU", 4.0, 2.5, 0.0),
    ]
    assert path.read_text().splitlines()[0] == ",".join(OUTPUT_LOG_HEADER)
    events = read_output_log(path)
    assert [(ev.host_time, ev.output, ev.frequency_hz) for ev in events] == [
        (100.0, True, 2.0),
        (101.0, True, 4.0),
        (102.0, False, 4.0),
    ]
    assert srv.instrument.runs(2) == []


# ---- the driver against it ---------------------------------------------------------------------------


def test_the_driver_configures_and_starts_it_and_a_new_driver_sees_that(server, tmp_path):
    with FunctionGenerator(server.resource, log=TriggerLog(tmp_path / "trigger.csv")) as fg:
        st = fg.configure(1.0, 0.5, high_v=2.5, low_v=0.0)
        assert (st.frequency_hz, st.duty, st.high_v, st.low_v, st.running) == (1.0, 0.5, 2.5, 0.0, False)
        assert fg.start().running
    with FunctionGenerator(server.resource) as again:
        st = again.status()
        assert (st.running, st.frequency_hz, st.duty, st.high_v, st.low_v, st.extra["function"]) == (
            True,
            1.0,
            0.5,
            2.5,
            0.0,
            "SQU",
        )
        assert again.stale_errors == ()
    (run,) = server.instrument.runs(1)
    assert run.stop is None and (run.frequency_hz, run.duty_percent) == (1.0, 50.0)


def test_channel_2_through_the_driver(server):
    with FunctionGenerator(server.resource, channel=2) as fg:
        fg.configure(3.0, 0.25, high_v=1.0, low_v=-1.0)
        fg.start()
    ch1, ch2 = server.instrument.channels[1], server.instrument.channels[2]
    assert (ch2.function, ch2.frequency_hz, ch2.duty_percent, ch2.output) == ("SQU", 3.0, 25.0, True)
    assert (ch1.function, ch1.output) == ("SIN", False)


def test_an_instrument_side_conflict_reaches_the_user_in_its_words(server):
    with FunctionGenerator(server.resource) as fg:
        with pytest.raises(
            TriggerError,
            match=r"^fgen refused 'VOLT:HIGH -1': -221,\"Settings conflict;"
            r"low level changed due to high level\"$",
        ):
            fg.high_v = -1.0  # the driver has not read the low level: the instrument adjusts it
        assert fg.low_v == pytest.approx(-1.001)


def test_errors_left_by_someone_else_are_kept_not_blamed(server, rm):
    session(rm, server).write("BOGUS")
    with FunctionGenerator(server.resource) as fg:
        assert fg.stale_errors == ('-113,"Undefined header"',)


def test_nothing_listening_is_one_sentence_naming_the_address(server):
    address = server.resource
    server.stop()
    with pytest.raises(TriggerError) as err:
        FunctionGenerator(address, timeout_ms=500)
    assert str(err.value) == (
        f"fgen: the instrument at {address} refused the connection (nothing listens "
        f"there: is it switched on, and are the address and port right?)"
    )


def test_a_hung_instrument_is_a_timeout_naming_the_address_and_command(server):
    server.go_silent()
    with pytest.raises(TriggerError) as err:
        FunctionGenerator(server.resource, timeout_ms=300)
    assert str(err.value) == f"fgen: the instrument at {server.resource} did not answer '*IDN?' within 0.3 s"


def test_an_instrument_that_goes_away_mid_session(server, tmp_path):
    log = TriggerLog(tmp_path / "trigger.csv")
    fg = FunctionGenerator(server.resource, log=log, timeout_ms=500)
    server.stop()
    with pytest.raises(
        TriggerError,
        match=rf"^fgen: the instrument at {server.resource} (closed the connection|"
        rf"did not answer)",
    ):
        fg.status()
    fg.close()
    assert any(r[3] == "event" and server.resource in r[4] for r in log.lines)  # the failure is in trigger.csv


@pytest.mark.parametrize(
    "address, message",
    [
        ("TCPIP:192.168.1.20:5025", r"^fgen: 'TCPIP:192.168.1.20:5025' is not a VISA address \(e.g. TCPIP::"),
        (
            "TCPIP::nowhere.invalid::5025::SOCKET",
            r"^fgen: cannot reach TCPIP::nowhere.invalid::5025::SOCKET: no host "
            r"is called 'nowhere.invalid' \(check the trigger address in rig.yaml\)$",
        ),
        ("TCPIP::nowhere.invalid::INSTR", r"^fgen: cannot reach TCPIP::nowhere.invalid::INSTR: no host is called"),
    ],
)
def test_a_wrong_address_is_one_sentence(address, message):
    with pytest.raises(TriggerError, match=message):
        FunctionGenerator(address, visa_library="@py")
