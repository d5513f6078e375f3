"""The Keysight 33500 driver against the shipped pyvisa-sim model (through pyvisa), and its exact
SCPI traffic against a scripted resource (tests/protocol.py)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import yaml

from protocol import ProtocolMismatch, ProtocolResource, expected_protocol
from vts_hw.drivers.function_generator import (
    SIM_RESOURCE,
    FunctionGenerator,
    OutOfRange,
    sim_yaml_path,
)
from vts_hw.drivers.trigger import (
    CLOCK,
    DUTY,
    EDGES,
    FIRE,
    FREQUENCY,
    LEVELS,
    LOG_HEADER,
    PULSE,
    TriggerError,
    TriggerGenerator,
    TriggerLog,
    Unsupported,
    read_log,
)

IDN = "Keysight Technologies,33522B,MY00000000,3.05-1.19-2.00-52-00"
OK = '+0,"No error"'
HELLO = [("*IDN?", IDN), ("SYST:ERR?", OK)]
SIM_ERROR = '-200,"Execution error;simulated 33522B: unknown command or value out of range"'


def e(x: float) -> str:
    """A number as the 33500 answers it."""
    return f"{x:+.14E}"


@pytest.fixture()
def fgen(tmp_path):
    with FunctionGenerator(SIM_RESOURCE, sim=True, log=TriggerLog(tmp_path / "trigger.csv")) as fg:
        yield fg


def raw(fg: FunctionGenerator, query: str) -> str:
    """Ask the (simulated) instrument directly, around the driver."""
    return fg.resource.query(query).strip()


def sim_state(fg: FunctionGenerator) -> dict[str, str]:
    return {q: raw(fg, q) for q in ("FUNC?", "FREQ?", "FUNC:SQU:DCYC?", "VOLT:HIGH?", "VOLT:LOW?", "OUTP?")}


class WriteSpy:
    """Records every write that reaches the resource (pyvisa's query writes through it too)."""

    def __init__(self, resource):
        self.calls: list[str] = []
        self._write = resource.write
        resource.write = self

    def __call__(self, message, *args, **kwargs):
        self.calls.append(message)
        return self._write(message, *args, **kwargs)


# ---- against pyvisa-sim, through pyvisa ----------------------------------------------------------


def test_a_1hz_50pct_square_wave_is_configured_started_and_confirmed(fgen):
    st = fgen.configure(1.0, 0.5, high_v=5.0, low_v=0.0)
    assert (st.frequency_hz, st.duty, st.high_v, st.low_v, st.running) == (1.0, 0.5, 5.0, 0.0, False)
    assert st.extra["function"] == "SQU" and st.errors == ()

    st = fgen.start()
    assert st.running and st.frequency_hz == 1.0 and st.duty == 0.5

    # the instrument itself, asked around the driver
    assert sim_state(fgen) == {
        "FUNC?": "SQU",
        "FREQ?": e(1),
        "FUNC:SQU:DCYC?": e(50),
        "VOLT:HIGH?": e(5),
        "VOLT:LOW?": e(0),
        "OUTP?": "1",
    }
    assert float(raw(fgen, "FREQ?")) == 1.0 and float(raw(fgen, "FUNC:SQU:DCYC?")) == 50.0

    st = fgen.stop()
    assert not st.running and raw(fgen, "OUTP?") == "0"


def test_the_driver_satisfies_the_trigger_contract(fgen):
    assert isinstance(fgen, TriggerGenerator)
    assert fgen.capabilities == {FREQUENCY, DUTY, LEVELS}
    assert fgen.idn == IDN and fgen.model == "33522B"


@pytest.mark.parametrize(
    "call",
    [
        pytest.param(lambda fg: fg.configure(0.0), id="frequency 0"),
        pytest.param(lambda fg: fg.configure(25e6), id="frequency above 20 MHz (the sim model would take it)"),
        pytest.param(lambda fg: fg.configure(float("nan")), id="frequency NaN"),
        pytest.param(lambda fg: fg.configure(1.0, 0.0), id="duty 0"),
        pytest.param(lambda fg: fg.configure(1.0, 1.0), id="duty 1"),
        pytest.param(lambda fg: fg.configure(1.0, 0.99999), id="duty 99.999 %"),
        pytest.param(lambda fg: fg.configure(10e6, 0.01), id="duty 1 % at 10 MHz (16 ns minimum pulse)"),
        pytest.param(lambda fg: fg.configure(1.0, 0.5, high_v=6.0, low_v=0.0), id="high 6 V"),
        pytest.param(lambda fg: fg.configure(1.0, 0.5, high_v=1.0, low_v=-5.5), id="low -5.5 V"),
        pytest.param(lambda fg: fg.configure(1.0, 0.5, high_v=0.0, low_v=1.0), id="high below low"),
        pytest.param(lambda fg: fg.configure(1.0, 0.5, high_v=1.0, low_v=0.9995), id="under 1 mVpp"),
        pytest.param(lambda fg: fg.configure(1.0, 0.5, high_v=5.0), id="high without low"),
        pytest.param(lambda fg: fg.configure("fast"), id="not a number"),
        pytest.param(lambda fg: setattr(fg, "frequency_hz", -1), id="property: frequency -1"),
        pytest.param(lambda fg: setattr(fg, "duty_percent", 100), id="property: duty 100 %"),
        pytest.param(lambda fg: setattr(fg, "function", "SAW"), id="property: function SAW"),
        pytest.param(lambda fg: setattr(fg, "output", "yes"), id="property: output 'yes'"),
    ],
)
def test_a_value_out_of_range_is_refused_before_anything_is_sent(fgen, call):
    before = sim_state(fgen)
    spy = WriteSpy(fgen.resource)
    with pytest.raises(OutOfRange, match="nothing was sent|must be") as err:
        call(fgen)
    assert spy.calls == []
    assert isinstance(err.value, ValueError) and isinstance(err.value, TriggerError)
    assert str(err.value).startswith("fgen")
    assert sim_state(fgen) == before


def test_the_duty_check_uses_the_confirmed_frequency(fgen):
    fgen.configure(10e6, 0.5)
    spy = WriteSpy(fgen.resource)
    with pytest.raises(OutOfRange, match=r"at 1e\+07 Hz"):
        fgen.duty_percent = 5.0  # 5 ns at 10 MHz: below the 16 ns minimum
    assert spy.calls == []
    fgen.duty_percent = 20.0
    assert fgen.duty_percent == 20.0


def test_the_error_queue_is_read_after_every_setting(fgen):
    fgen.configure(1.0, 0.5, high_v=3.3, low_v=0.0)
    fgen.start()
    rows = fgen.log.lines
    commands = [r[4] for r in rows if r[3] == "cmd"]
    settings = [i for i, c in enumerate(commands) if "?" not in c]
    assert [commands[i] for i in settings] == [
        "FUNC SQU",
        "FREQ 1",
        "FUNC:SQU:DCYC 50",
        "VOLT:HIGH 3.3",
        "VOLT:LOW 0",
        "OUTP 1",
    ]
    for i in settings:
        assert commands[i + 1] == "SYST:ERR?"


def narrower_model(tmp_path: Path, **changes) -> str:
    """The shipped model with some property specs changed: a VISA library string for it."""
    data = yaml.safe_load(sim_yaml_path().read_text())
    props = data["devices"]["keysight_33522B"]["properties"]
    for prop, specs in changes.items():
        props[prop]["specs"].update(specs)
    path = tmp_path / "narrow_33500.yaml"
    path.write_text(yaml.safe_dump(data))
    return f"{path}@sim"


def test_an_instrument_side_refusal_raises_with_the_instruments_message(tmp_path):
    # a generator that refuses below 1 Hz, which the driver allows
    lib = narrower_model(tmp_path, frequency={"min": 1})
    with FunctionGenerator(SIM_RESOURCE, visa_library=lib) as fg:
        with pytest.raises(TriggerError, match=r"fgen refused 'FREQ 0.5': -200,\"Execution error") as err:
            fg.configure(0.5)
        assert not isinstance(err.value, OutOfRange)
        assert raw(fg, "FREQ?") == e(1000)  # unchanged
        assert raw(fg, "SYST:ERR?") == OK  # the driver emptied the queue
        replies = [r[4] for r in fg.log.lines if r[3] == "reply"]
        assert SIM_ERROR in replies
        # and it goes on working
        assert fg.configure(50.0).frequency_hz == 50.0


def test_the_simulated_instrument_itself_refuses_out_of_range_values(fgen):
    for command in (
        "FREQ 4E7",
        "FUNC:SQU:DCYC 0",
        "VOLT:HIGH 5.5",
        "VOLT:LOW -6",
        "OUTP 2",
        "FUNC SAW",
        "OUTP ON",
    ):  # ON: see the YAML, the sim takes 1|0 only
        before = sim_state(fgen)
        fgen.resource.write(command)
        assert raw(fgen, "SYST:ERR?") == SIM_ERROR, command
        assert raw(fgen, "SYST:ERR?") == OK
        assert sim_state(fgen) == before, command


def test_every_instance_starts_from_a_fresh_simulator(tmp_path):
    a = FunctionGenerator(SIM_RESOURCE, sim=True)
    a.configure(5.0, 0.25)
    a.start()
    b = FunctionGenerator(SIM_RESOURCE, sim=True)  # while a is still open
    assert (b.frequency_hz, b.duty_percent, b.output, b.function) == (1000.0, 50.0, False, "SIN")
    assert (a.frequency_hz, a.output) == (5.0, True)  # a keeps its own device
    b.resource.write("FREQ 7")  # and b does not reach it
    assert a.frequency_hz == 5.0
    a.close()
    b.close()
    with FunctionGenerator(SIM_RESOURCE, sim=True) as c:
        assert (c.frequency_hz, c.output) == (1000.0, False)


def test_pulse_fire_and_clock_mapping_are_unsupported_and_say_what_to_use(fgen):
    spy = WriteSpy(fgen.resource)
    with pytest.raises(
        Unsupported, match="fgen cannot send a start pulse: .*no contact-closure.*trigger box.*NI-DAQmx"
    ):
        fgen.pulse(1, 100)
    with pytest.raises(
        Unsupported, match="fgen cannot start the square wave and the start pulses together: .*trigger box"
    ):
        fgen.fire()
    with pytest.raises(Unsupported, match="fgen cannot report a device clock.*list-mode"):
        fgen.clock_mapping()
    assert spy.calls == []
    assert not {PULSE, FIRE, CLOCK, EDGES} & fgen.capabilities


def test_start_is_refused_unless_the_function_is_a_square_wave(fgen):
    with pytest.raises(TriggerError, match="set to SIN, not a square wave"):
        fgen.start()
    assert raw(fgen, "OUTP?") == "0"


def test_channel_2_is_a_separate_output(tmp_path):
    with FunctionGenerator(SIM_RESOURCE, sim=True, channel=2) as fg:
        fg.configure(2.0, 0.5)
        fg.start()
        assert raw(fg, "SOUR2:FREQ?") == e(2) and raw(fg, "OUTP2?") == "1"
        assert raw(fg, "FREQ?") == e(1000) and raw(fg, "OUTP?") == "0"


def test_trigger_csv_has_every_command_and_reply(tmp_path):
    path = tmp_path / "session" / "trigger.csv"
    with FunctionGenerator(SIM_RESOURCE, sim=True, log=TriggerLog(path)) as fg:
        fg.configure(1.0, 0.5)
        fg.start()
    rows = read_log(path)
    assert list(rows[0]) == LOG_HEADER
    assert {r["device"] for r in rows} == {"fgen"}
    assert rows[0]["kind"] == "event" and rows[0]["text"].startswith("open TCPIP0::127.0.0.1::inst0::INSTR")
    assert [(r["kind"], r["text"]) for r in rows[1:5]] == [
        ("cmd", "*IDN?"),
        ("reply", IDN),
        ("cmd", "SYST:ERR?"),
        ("reply", OK),
    ]
    pairs = [(r["kind"], r["text"]) for r in rows]
    assert ("cmd", "FREQ 1") in pairs and ("cmd", "OUTP 1") in pairs
    assert ("cmd", "FREQ?") in pairs and ("reply", e(1)) in pairs
    # every query is followed by its reply
    for r, nxt in zip(rows, rows[1:]):
        if r["kind"] == "cmd" and r["text"].endswith("?"):
            assert nxt["kind"] == "reply"
    assert rows[-1]["kind"] == "event" and rows[-1]["text"] == "closed"
    # the wire rows are stamped as written; the neutral row (docs/trigger-log-format.md) carries
    # the time of what it describes: the wave started at the host time OUTP 1 was written
    times = [float(r["host_time"]) for r in rows if r["kind"] != "wave_start"]
    assert times == sorted(times)
    (start,) = [r for r in rows if r["kind"] == "wave_start"]
    assert start["host_time"] == next(r for r in rows if r["text"] == "OUTP 1")["host_time"]
    assert start["text"].startswith("period_s=1.0 duty=0.5 high_v=0.05 low_v=-0.05 start_pulse=no time=host_write ")


def test_the_shipped_model_is_package_data_that_sim_finds():
    path = sim_yaml_path()
    assert path.name == "keysight_33500.yaml" and path.is_file()
    import vts_hw.sim_devices

    assert path.parent == Path(vts_hw.sim_devices.__file__).parent


def test_an_instrument_that_does_not_answer_is_a_trigger_error(tmp_path):
    data = yaml.safe_load(sim_yaml_path().read_text())
    data["devices"]["keysight_33522B"]["dialogues"] = [{"q": "*RST"}]  # no *IDN?
    path = tmp_path / "mute.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(
        TriggerError,
        match=r"fgen: the instrument at TCPIP0::127.0.0.1::inst0::INSTR did not answer '\*IDN\?' within 0.1 s",
    ):
        FunctionGenerator(SIM_RESOURCE, visa_library=f"{path}@sim", timeout_ms=100)


def test_an_unknown_address_is_a_trigger_error():
    with pytest.raises(TriggerError, match="cannot open TCPIP0::10.9.9.9::inst0::INSTR"):
        FunctionGenerator("TCPIP0::10.9.9.9::inst0::INSTR", sim=True)


# ---- byte-exact protocol --------------------------------------------------------------------------

STATUS_1HZ_OFF = [
    ("FUNC?", "SQU"),
    ("FREQ?", e(1)),
    ("FUNC:SQU:DCYC?", e(50)),
    ("VOLT:HIGH?", e(5)),
    ("VOLT:LOW?", e(0)),
    ("OUTP?", "0"),
    ("SYST:ERR?", OK),
]


def test_protocol_configure():
    with expected_protocol(
        FunctionGenerator,
        HELLO
        + [
            ("FUNC SQU", None),
            ("SYST:ERR?", OK),
            ("FREQ 1", None),
            ("SYST:ERR?", OK),
            ("FUNC:SQU:DCYC 50", None),
            ("SYST:ERR?", OK),
            ("VOLT:LOW?", e(-0.05)),  # where the low level is now decides the order
            ("VOLT:HIGH 5", None),
            ("SYST:ERR?", OK),
            ("VOLT:LOW 0", None),
            ("SYST:ERR?", OK),
        ]
        + STATUS_1HZ_OFF,
    ) as fg:
        st = fg.configure(1, 0.5, high_v=5, low_v=0)
        assert (st.frequency_hz, st.duty, st.high_v, st.low_v, st.running) == (1.0, 0.5, 5.0, 0.0, False)


def test_protocol_levels_going_down_set_the_low_level_first():
    with expected_protocol(
        FunctionGenerator,
        HELLO
        + [
            ("FUNC SQU", None),
            ("SYST:ERR?", OK),
            ("FREQ 0.1", None),
            ("SYST:ERR?", OK),
            ("FUNC:SQU:DCYC 25", None),
            ("SYST:ERR?", OK),
            ("VOLT:LOW?", e(0)),  # now 0..5 V; asked -2..-1 V
            ("VOLT:LOW -2", None),
            ("SYST:ERR?", OK),
            ("VOLT:HIGH -1", None),
            ("SYST:ERR?", OK),
            ("FUNC?", "SQU"),
            ("FREQ?", e(0.1)),
            ("FUNC:SQU:DCYC?", e(25)),
            ("VOLT:HIGH?", e(-1)),
            ("VOLT:LOW?", e(-2)),
            ("OUTP?", "0"),
            ("SYST:ERR?", OK),
        ],
    ) as fg:
        fg.configure(0.1, 0.25, high_v=-1, low_v=-2)


def test_protocol_start_and_stop():
    status_on = [(q, "1" if q == "OUTP?" else r) for q, r in STATUS_1HZ_OFF]
    with expected_protocol(
        FunctionGenerator,
        HELLO
        + [
            ("FUNC?", "SQU"),
            ("OUTP 1", None),
            ("SYST:ERR?", OK),
            *status_on,
            ("OUTP 0", None),
            ("SYST:ERR?", OK),
            *STATUS_1HZ_OFF,
        ],
    ) as fg:
        assert fg.start().running
        assert not fg.stop().running


def test_protocol_channel_2():
    with expected_protocol(
        FunctionGenerator,
        HELLO
        + [
            ("SOUR2:FREQ 1E-06", None),
            ("SYST:ERR?", OK),
            ("OUTP2?", "0"),
        ],
        channel=2,
    ) as fg:
        fg.frequency_hz = 1e-6
        assert fg.output is False


def test_protocol_an_instrument_error_is_read_to_the_end_of_the_queue():
    with expected_protocol(
        FunctionGenerator,
        HELLO
        + [
            ("FUNC SQU", None),
            ("SYST:ERR?", OK),
            ("FREQ 1000", None),
            ("SYST:ERR?", '-221,"Settings conflict;frequency forced duty cycle change"'),
            ("SYST:ERR?", '-222,"Data out of range"'),
            ("SYST:ERR?", OK),
        ],
    ) as fg:
        with pytest.raises(
            TriggerError,
            match=r"fgen refused 'FREQ 1000': -221,\"Settings conflict;"
            r"frequency forced duty cycle change\"; -222,\"Data out of range\"",
        ):
            fg.configure(1000, 0.5)


def test_protocol_a_read_back_that_differs_is_an_error():
    with expected_protocol(
        FunctionGenerator,
        HELLO
        + [
            ("FUNC SQU", None),
            ("SYST:ERR?", OK),
            ("FREQ 1", None),
            ("SYST:ERR?", OK),
            ("FUNC:SQU:DCYC 50", None),
            ("SYST:ERR?", OK),
            ("FUNC?", "SQU"),
            ("FREQ?", e(2)),
            ("FUNC:SQU:DCYC?", e(50)),
            ("VOLT:HIGH?", e(5)),
            ("VOLT:LOW?", e(0)),
            ("OUTP?", "0"),
            ("SYST:ERR?", OK),
        ],
    ) as fg:
        with pytest.raises(TriggerError, match="asked for frequency_hz 1 but confirms 2.0"):
            fg.configure(1, 0.5)


def test_protocol_errors_left_from_before_are_logged_not_raised():
    with expected_protocol(
        FunctionGenerator,
        [
            ("*IDN?", IDN),
            ("SYST:ERR?", '-113,"Undefined header"'),
            ("SYST:ERR?", OK),
        ],
    ) as fg:
        assert fg.stale_errors == ('-113,"Undefined header"',)
        assert ["fgen", "event", 'error left in the queue before connecting: -113,"Undefined header"'] == fg.log.lines[
            -1
        ][2:]


def test_protocol_not_a_33500_is_refused_and_closed():
    fake = ProtocolResource([("*IDN?", "Rigol Technologies,DG1022Z,DG1ZA0000,00.01.14")])
    with pytest.raises(TriggerError, match="not a Keysight/Agilent 33500-series generator"):
        FunctionGenerator(fake)
    assert fake.closed


def test_protocol_channel_2_on_a_one_channel_model_is_refused():
    fake = ProtocolResource([("*IDN?", "Keysight Technologies,33511B,MY00000000,3.05-1.19-2.00-52-00")])
    with pytest.raises(TriggerError, match="33511B .* has one channel"):
        FunctionGenerator(fake, channel=2)


def test_the_protocol_helper_catches_a_wrong_command():
    fake = ProtocolResource([("FREQ 1", None)])
    with pytest.raises(ProtocolMismatch, match=r"expected 'FREQ 1', got 'FREQ 1.0'"):
        fake.write("FREQ 1.0")
    fake = ProtocolResource([("FREQ?", e(1)), ("OUTP 1", None)])
    fake.write("FREQ?")
    with pytest.raises(ProtocolMismatch, match="never read"):
        fake.write("OUTP 1")
    with pytest.raises(ProtocolMismatch, match="never made"):
        ProtocolResource([("*RST", None)]).assert_complete()


@pytest.mark.parametrize(
    "value, text",
    [
        (1.0, "1"),
        (0.1, "0.1"),
        (1e-6, "1E-06"),
        (20e6, "20000000"),
        (-0.05, "-0.05"),
        (49.99, "49.99"),
        (1 / 3, "0.3333333333333333"),
    ],
)
def test_numbers_are_sent_exactly(value, text):
    from vts_hw.drivers.function_generator import scpi_number

    assert scpi_number(value) == text
    assert float(text) == value and math.isfinite(float(text))


class _Replies:
    """A resource answering each query with the next line, decoded as pyvisa does (ASCII, strict)."""

    resource_name, timeout = "TCPIP::127.0.0.1::5025::SOCKET", 100

    def __init__(self, *replies: bytes):
        self.replies = list(replies)

    def write(self, command):
        return len(command)

    def query(self, command):
        return self.replies.pop(0).decode("ascii")

    def close(self):
        pass


def test_a_reply_that_is_not_ascii_is_a_trigger_error():
    # found by bench/fuzz.py (function_generator): pyvisa's UnicodeDecodeError went through
    with pytest.raises(TriggerError, match="answered '\\*IDN\\?' with bytes that are not text"):
        FunctionGenerator(_Replies(b"\xffgilent Technologies,33522B,MY1,4.00"))


def test_start_raises_when_the_instrument_confirms_0_hz():
    # found by bench/fuzz.py (function_generator): FREQ? 0 after OUTP 1 was a ZeroDivisionError
    with expected_protocol(
        FunctionGenerator,
        HELLO
        + [
            ("FUNC?", "SQU"),
            ("OUTP 1", None),
            ("SYST:ERR?", OK),
            ("FUNC?", "SQU"),
            ("FREQ?", e(0)),
            ("FUNC:SQU:DCYC?", e(50)),
            ("VOLT:HIGH?", e(5)),
            ("VOLT:LOW?", e(0)),
            ("OUTP?", "1"),
            ("SYST:ERR?", OK),
        ],
    ) as fg:
        with pytest.raises(TriggerError, match="confirms 0.0 Hz at duty 0.5: not a square wave"):
            fg.start()
