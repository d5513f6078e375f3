"""Byte-exact protocol tests of the trigger-box driver against a scripted serial port.

:func:`expected_protocol` hands the driver a :class:`ScriptedSerial` (through its
``serial_factory`` argument) that knows, in order, every line the driver must write and the
bytes the box answers to each. It fails at the first byte written that differs, and on leaving
the block if any scripted exchange was never made. An answer may also be an exception, raised
when the driver writes (``Fail(exc, on="write")``) or reads (``Fail(exc)``) that exchange.
"""

from __future__ import annotations

import random
from contextlib import contextmanager
from dataclasses import dataclass

import pytest
import serial

from vts_hw.drivers.trigger import (
    CLOCK,
    DUTY,
    EDGES,
    FIRE,
    FREQUENCY,
    LEVELS,
    PULSE,
    TriggerError,
    TriggerGenerator,
    TriggerLog,
    Unsupported,
    read_log,
)
from vts_hw.drivers.trigger_box import (
    BoxGone,
    BoxRefused,
    RoundTrip,
    TriggerBox,
    best_round_trips,
    fit_clock,
    number_text,
    wire_skew,
)

PORT = "/dev/ttyFAKE0"


# ---- the scripted port ----------------------------------------------------------------------------

class ProtocolMismatch(AssertionError):
    pass


@dataclass
class Fail:
    """Raise ``exc`` when the driver writes (``on="write"``) or reads the answer of this exchange."""

    exc: BaseException
    on: str = "read"


class ScriptedSerial:
    """Stands where a ``serial.Serial`` would; checks every byte the driver writes."""

    def __init__(self, pairs, port, **kwargs):
        for p in pairs:
            if not (isinstance(p, tuple) and len(p) == 2 and isinstance(p[0], bytes)
                    and isinstance(p[1], (bytes, Fail))):
                raise TypeError(f"each pair is (bytes written, bytes answered or Fail), not {p!r}")
        self.pairs = list(pairs)
        self.port = port
        self.kwargs = kwargs
        self.done = 0               # pairs completed
        self.written = b""          # bytes of the current pair written so far
        self.rx = bytearray()       # bytes the "box" sent that the driver has not read
        self.pending_fail: BaseException | None = None
        self.is_open = True
        self.errors: list[str] = []  # every mismatch, even if the driver swallowed the exception

    def _mismatch(self, text: str):
        self.errors.append(text)
        raise ProtocolMismatch(text)

    # what the driver calls
    def write(self, data: bytes) -> int:
        if not self.is_open:
            self._mismatch(f"write {data!r} after close")
        if not isinstance(data, bytes):
            self._mismatch(f"write of {type(data).__name__}, not bytes: {data!r}")
        if self.done >= len(self.pairs):
            self._mismatch(f"{data!r} written after the script's {len(self.pairs)} exchanges")
        want, answer = self.pairs[self.done]
        if isinstance(answer, Fail) and answer.on == "write":
            self.done += 1
            raise answer.exc
        sofar = self.written + data
        if not want.startswith(sofar):
            self._mismatch(f"exchange {self.done + 1}: expected {want!r}, got {sofar!r}")
        self.written = sofar
        if sofar == want:
            self.written = b""
            self.done += 1
            if isinstance(answer, Fail):
                self.pending_fail = answer.exc
            else:
                self.rx += answer
        return len(data)

    def _maybe_fail(self):
        if self.pending_fail is not None:
            exc, self.pending_fail = self.pending_fail, None
            raise exc

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        self._maybe_fail()
        i = self.rx.find(expected)
        n = len(self.rx) if i < 0 else i + len(expected)
        if size is not None:
            n = min(n, size)
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out  # no terminator: what a real port returns when the timeout runs out

    def read(self, size: int = 1) -> bytes:
        self._maybe_fail()
        out = bytes(self.rx[:size])
        del self.rx[:size]
        return out

    @property
    def in_waiting(self) -> int:
        self._maybe_fail()
        return len(self.rx)

    def reset_input_buffer(self) -> None:
        self.rx.clear()

    def close(self) -> None:
        self.is_open = False

    # what the test calls
    def assert_complete(self) -> None:
        if self.errors:
            raise ProtocolMismatch(self.errors[0])
        if self.written:
            raise ProtocolMismatch(f"a partial line {self.written!r} was written")
        if self.done != len(self.pairs):
            raise ProtocolMismatch(f"{len(self.pairs) - self.done} exchange(s) never made, first "
                                   f"{self.pairs[self.done]!r}")


class FakeClock:
    """Host time that moves only when told (each read may advance it by ``step``)."""

    def __init__(self, t=1_700_000_000.0, step=0.0):
        self.t = t
        self.step = step

    def __call__(self) -> float:
        t = self.t
        self.t += self.step
        return t

    def sleep(self, s: float) -> None:
        self.t += s


@contextmanager
def expected_protocol(pairs, **kwargs):
    """A TriggerBox on a ScriptedSerial; on leaving, every scripted pair must have been used."""
    made = {}

    def factory(port, **kw):
        made["fake"] = ScriptedSerial(pairs, port, **kw)
        return made["fake"]

    kwargs.setdefault("clock", FakeClock())
    kwargs.setdefault("sleep", getattr(kwargs["clock"], "sleep", lambda s: None))
    box = TriggerBox(PORT, serial_factory=factory, **kwargs)
    box.fake = made["fake"]
    yield box
    made["fake"].assert_complete()


def lines(*pairs):
    """('CMD', 'REPLY') text pairs as wire bytes, each with its "\\n"."""
    return [(c.encode() + b"\n", r.encode() + b"\n") for c, r in pairs]


STATUS_OFF = [("OUTP?", "OFF"), ("FREQ?", "10"), ("DUTY?", "0.25"), ("EDGES?", "0,0,0"),
              ("SYST:ERR?", '0,"No error"')]


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
    assert box.capabilities == {FREQUENCY, DUTY, PULSE, FIRE, CLOCK, EDGES}
    assert LEVELS not in box.capabilities     # fixed TTL outputs


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
    with expected_protocol([(b"*RST\n", b"OK\n"), (b"OUTP?\n", b"ON\n"), (b"OUTP?\n", b"ON\n"),
                            (b"OUTP?\n", b"OFF\n")]) as box:
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
    with expected_protocol([(b"FREQ 10\n", b"OK\n"), (b"FREQ?\n", b"10.000\n"),
                            (b"DUTY 0.25\n", b"OK\n"), (b"DUTY?\n", b"0.250000\n"),
                            (b"FREQ 0.1\n", b"OK\n"), (b"FREQ 1000\n", b"OK\n"),
                            (b"FREQ 333.333\n", b"OK\n"), (b"DUTY 0.99\n", b"OK\n")]) as box:
        box.frequency_hz = 10
        assert box.frequency_hz == 10.0
        box.duty = 0.25
        assert box.duty == 0.25
        box.frequency_hz = 0.1
        box.frequency_hz = 1000.0
        box.frequency_hz = 1000 / 3
        box.duty = 0.99


@pytest.mark.parametrize("attr,value", [("frequency_hz", 0.09), ("frequency_hz", 1000.5),
                                        ("frequency_hz", float("nan")), ("frequency_hz", "10"),
                                        ("frequency_hz", True), ("duty", 0.0), ("duty", 0.995),
                                        ("duty", 1), ("duty", None)])
def test_validators_refuse_before_anything_is_written(attr, value):
    with expected_protocol([]) as box:
        with pytest.raises(ValueError, match="nothing was sent"):
            setattr(box, attr, value)
    assert box.fake.done == 0 and box.fake.written == b""


def test_configure_sets_reads_back_and_checks_errors():
    pairs = lines(("SYST:ERR?", '0,"No error"'), ("FREQ 10", "OK"), ("DUTY 0.25", "OK"),
                  ("OUTP?", "OFF"), ("FREQ?", "9.99998"), ("DUTY?", "0.25"), ("EDGES?", "0,0,0"),
                  ("SYST:ERR?", '0,"No error"'))
    with expected_protocol(pairs) as box:
        st = box.configure(10, 0.25)
    # what the box confirms, not what was asked
    assert st.frequency_hz == 9.99998 and st.duty == 0.25 and not st.running
    assert st.edges == 0 and st.first_edge_device_us is None and st.errors == ()
    assert st.device == "triggerbox"


def test_configure_logs_and_ignores_errors_left_from_before():
    pairs = lines(("SYST:ERR?", '-113,"Undefined header"'), ("SYST:ERR?", '0,"No error"'),
                  ("FREQ 2.5", "OK"), ("DUTY 0.5", "OK"), ("OUTP?", "OFF"), ("FREQ?", "2.5"),
                  ("DUTY?", "0.5"), ("EDGES?", "0,0,0"), ("SYST:ERR?", '0,"No error"'))
    with expected_protocol(pairs) as box:
        st = box.configure(2.5)
    assert not st.running
    assert any(r[3] == "event" and 'queued before configure: -113,"Undefined header"' in r[4]
               for r in box.log.lines)


def test_configure_raises_on_an_error_queued_by_the_new_settings():
    pairs = lines(("SYST:ERR?", '0,"No error"'), ("FREQ 10", "OK"), ("DUTY 0.25", "OK"),
                  *STATUS_OFF[:4], ("SYST:ERR?", '-222,"Data out of range"'),
                  ("SYST:ERR?", '0,"No error"'))
    with expected_protocol(pairs) as box:
        with pytest.raises(TriggerError, match='reports errors after configure: -222,"Data out of range"'):
            box.configure(10, 0.25)


def test_configure_raises_when_the_box_confirms_something_else():
    pairs = lines(("SYST:ERR?", '0,"No error"'), ("FREQ 10", "OK"), ("DUTY 0.25", "OK"),
                  ("OUTP?", "OFF"), ("FREQ?", "1"), ("DUTY?", "0.25"), ("EDGES?", "0,0,0"),
                  ("SYST:ERR?", '0,"No error"'))
    with expected_protocol(pairs) as box:
        with pytest.raises(TriggerError, match="asked for 10 Hz but confirms 1.0 Hz"):
            box.configure(10, 0.25)


@pytest.mark.parametrize("kwargs,match", [({"frequency_hz": 0.05}, "frequency 0.05 Hz is outside"),
                                          ({"frequency_hz": 10, "duty": 1.2}, "duty cycle 1.2 is outside")])
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
    pairs = lines(("OUTP ON", "OK"), ("OUTP?", "ON"), ("FREQ?", "10"), ("DUTY?", "0.25"),
                  ("EDGES?", "1,5000000,5000000"), ("SYST:ERR?", '0,"No error"'),
                  ("OUTP OFF", "OK"), ("OUTP?", "OFF"), ("FREQ?", "10"), ("DUTY?", "0.25"),
                  ("EDGES?", "30,5000000,7900000"), ("SYST:ERR?", '0,"No error"'),
                  ("*TRG", "OK"), ("OUTP?", "ON"), ("FREQ?", "10"), ("DUTY?", "0.25"),
                  ("EDGES?", "1,9000125,9000125"), ("SYST:ERR?", '0,"No error"'),
                  ("PULSE:WIDTH 20", "OK"), ("*TRG", "OK"), ("OUTP?", "ON"), ("FREQ?", "10"),
                  ("DUTY?", "0.25"), ("EDGES?", "1,9000125,9000125"), ("SYST:ERR?", '0,"No error"'))
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
    pairs = lines(("OUTP OFF", "OK"), ("OUTP?", "ON"), ("FREQ?", "2"), ("DUTY?", "0.5"),
                  ("EDGES?", "7,5000000,8000000"), ("SYST:ERR?", '0,"No error"'),
                  ("OUTP?", "ON"), ("OUTP?", "ON"), ("OUTP?", "OFF"),
                  ("OUTP?", "OFF"), ("FREQ?", "2"), ("DUTY?", "0.5"),
                  ("EDGES?", "7,5000000,8000000"), ("SYST:ERR?", '0,"No error"'))
    with expected_protocol(pairs) as box:
        st = box.stop()
    assert not st.running and st.edges == 7


def test_stop_without_waiting_reports_the_last_period_running():
    pairs = lines(("OUTP OFF", "OK"), ("OUTP?", "ON"), ("FREQ?", "0.1"), ("DUTY?", "0.5"),
                  ("EDGES?", "1,5000000,5000000"), ("SYST:ERR?", '0,"No error"'))
    with expected_protocol(pairs) as box:
        assert box.stop(wait=False).running


def test_stop_gives_up_after_one_period():
    # 4 Hz: one period 0.25 s, plus two timeouts of 0.125 s = 0.5 s; polls every 1/16 s here
    clock = FakeClock(1000.0)
    pairs = lines(("OUTP OFF", "OK"), ("OUTP?", "ON"), ("FREQ?", "4"), ("DUTY?", "0.5"),
                  ("EDGES?", "7,5000000,6500000"), ("SYST:ERR?", '0,"No error"'),
                  *[("OUTP?", "ON")] * 10)
    with expected_protocol(pairs, timeout=0.125, clock=clock,
                           sleep=lambda s: setattr(clock, "t", clock.t + 0.0625)) as box:
        with pytest.raises(TriggerError, match=r"still reports its output ON 0.25 s \(one period\) "
                                               r"after 'OUTP OFF'"):
            box.stop()


def test_start_raises_if_the_box_stays_off():
    pairs = lines(("OUTP ON", "OK"), *STATUS_OFF)
    with expected_protocol(pairs) as box:
        with pytest.raises(TriggerError, match="switched on but reports its output OFF"):
            box.start()


def test_status_drains_the_error_queue():
    pairs = lines(*STATUS_OFF[:4], ("SYST:ERR?", '-113,"Undefined header"'),
                  ("SYST:ERR?", '-222,"Data out of range"'), ("SYST:ERR?", '0,"No error"'))
    with expected_protocol(pairs) as box:
        st = box.status()
    assert st.errors == ('-113,"Undefined header"', '-222,"Data out of range"')


def test_pulse():
    with expected_protocol(lines(("PULSE 1 100", "OK"), ("PULSE 2 10000", "OK"), ("PULSE 1 1", "OK"))) as box:
        box.pulse(1, 100)
        box.pulse(2, 10_000)
        box.pulse(1, 1.0)


@pytest.mark.parametrize("channel,ms,match", [(0, 100, "channel must be 1"), (3, 100, "channel must be 1"),
                                              (1, "100", "whole number of ms"),
                                              (1, 0, "whole number of ms"), (1, 10_001, "whole number"),
                                              (2, 1.5, "whole number"), (2, True, "whole number"),
                                              (1, float("inf"), "whole number")])
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
        with pytest.raises(BoxRefused,
                           match="trigger box on /dev/ttyFAKE0 refused 'FREQ 10': ERR 2 busy") as e:
            box.frequency_hz = 10
        assert (e.value.code, e.value.device_message) == (2, "busy")
        with pytest.raises(TriggerError, match="refused 'BOGUS': ERR 1 unknown command"):
            box.query("BOGUS")


def test_errors_already_raised_are_not_reported_again_by_the_queue():
    # the box answers ERR and also queues the error; status() lists only errors not yet raised
    pairs = lines(("FREQ 10", "ERR -221 Settings conflict"), ("BOGUS", "ERR -113 Undefined header"),
                  *STATUS_OFF[:4], ("SYST:ERR?", '-221,"Settings conflict"'),
                  ("SYST:ERR?", '-363,"Input buffer overrun"'), ("SYST:ERR?", '-113,"Undefined header"'),
                  ("SYST:ERR?", '0,"No error"'))
    with expected_protocol(pairs) as box:
        with pytest.raises(BoxRefused, match=r"refused 'FREQ 10': ERR -221 Settings conflict \(the box "
                                             r"takes a new frequency or duty only while its output is "
                                             r"off: stop\(\) first\)"):
            box.frequency_hz = 10
        with pytest.raises(BoxRefused):
            box.query("BOGUS")
        st = box.status()
    assert st.errors == ('-363,"Input buffer overrun"',)
    assert sum("already raised" in r[4] for r in box.log.lines) == 2


def test_no_answer_is_a_timeout_naming_port_and_command():
    with expected_protocol([(b"FREQ 10\n", b"")]) as box:
        with pytest.raises(TriggerError, match=r"^trigger box on /dev/ttyFAKE0 did not answer 'FREQ 10' "
                                               r"within 1 s$"):
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
        ["cmd", "FREQ?"], ["reply", "10"], ["event", "discarded stale input 'OK\\n'"],
        ["cmd", "DUTY?"], ["reply", "0.5"]]


def test_crlf_replies_are_accepted():
    with expected_protocol([(b"OUTP?\n", b"ON\r\n")]) as box:
        assert box.query("OUTP?") == "ON"


@pytest.mark.parametrize("on", ["read", "write"])
def test_a_vanished_port_is_one_clear_error_and_stays_gone(on):
    exc = serial.SerialException("read failed: [Errno 5] Input/output error") if on == "read" else \
        OSError(5, "Input/output error")
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


# ---- trigger.csv ------------------------------------------------------------------------------------

def test_trigger_csv_lines(tmp_path):
    path = tmp_path / "trigger.csv"
    clock = FakeClock(1_700_000_000.0, step=0.001)
    log = TriggerLog(path, clock=clock)
    pairs = lines(("*IDN?", "VTS,TRIGGERBOX,0042,1.0.0"), ("OUTP ON", "OK"), ("OUTP?", "ON"),
                  ("FREQ?", "10"), ("DUTY?", "0.25"), ("EDGES?", "1,5000000,5000000"),
                  ("SYST:ERR?", '0,"No error"'), ("EDGES?", "1,5000000,5000000"),
                  ("EDGES?", "4,5000000,5300000"))
    with expected_protocol(pairs, log=log, clock=clock) as box:
        box.identify()
        box.start()
        box.edges()       # the same edge again: not logged twice
        box.edges()       # a new last edge
        box.close()
    rows = read_log(path)
    assert [(r["kind"], r["text"]) for r in rows] == [
        ("event", "open /dev/ttyFAKE0 115200 baud"),
        ("cmd", "*IDN?"), ("reply", "VTS,TRIGGERBOX,0042,1.0.0"),
        ("cmd", "OUTP ON"), ("reply", "OK"),
        ("cmd", "OUTP?"), ("reply", "ON"),
        ("cmd", "FREQ?"), ("reply", "10"),
        ("cmd", "DUTY?"), ("reply", "0.25"),
        ("cmd", "EDGES?"), ("reply", "1,5000000,5000000"),
        ("edge", "first rising edge (1 of 1); host time = when reported (no clock mapping)"),
        ("cmd", "SYST:ERR?"), ("reply", '0,"No error"'),
        # the neutral row (docs/trigger-log-format.md): no clock mapping, so the host time of
        # the write plus the command's 8 bytes on the wire, ± until its reply came
        ("wave_start", "period_s=0.1 duty=0.25 high_v=5.0 low_v=0.0 start_pulse=no time=host_write "
                       "uncertainty_s=0.001"),
        ("cmd", "EDGES?"), ("reply", "1,5000000,5000000"),
        ("cmd", "EDGES?"), ("reply", "4,5000000,5300000"),
        ("edge", "last rising edge (4 of 4); host time = when reported (no clock mapping)"),
        ("event", "closed /dev/ttyFAKE0"),
    ]
    assert all(r["device"] == "triggerbox" for r in rows)
    start = next(r for r in rows if r["kind"] == "wave_start")
    outp_on = next(r for r in rows if r["text"] == "OUTP ON")
    assert float(start["host_time"]) == pytest.approx(float(outp_on["host_time"]) + 8 * 10 / 115200, abs=2e-6)
    assert start["device_time_us"] == "5000000"
    rows = [r for r in rows if r["kind"] != "wave_start"]
    # commands and replies carry host time only; edge lines carry the device time
    assert all(r["device_time_us"] == "" for r in rows if r["kind"] in ("cmd", "reply", "event"))
    assert [r["device_time_us"] for r in rows if r["kind"] == "edge"] == ["5000000", "5300000"]
    times = [float(r["host_time"]) for r in rows]
    assert times == sorted(times) and times[0] >= 1_700_000_000.0
    # a reply is stamped after its command
    cmd, reply = rows[1], rows[2]
    assert float(reply["host_time"]) > float(cmd["host_time"])


def test_edges_are_logged_in_host_time_once_the_clock_is_mapped(tmp_path):
    clock = FakeClock(1000.0)
    # a box whose clock reads 0 us at host 990 s, running exactly at host rate
    replies = []
    for i in range(4):
        replies.append(("TIME?", str(round((1000.0 + 0.25 * i - 990.0) * 1e6))))
    pairs = lines(*replies, ("EDGES?", "2,10500000,10600000"))
    with expected_protocol(pairs, log=TriggerLog(tmp_path / "trigger.csv", clock=clock), clock=clock) as box:
        box.sleep = clock.sleep  # host time moves only by the pacing sleeps: instant round trips
        m = box.clock_mapping(samples=4, over_s=0.75, keep=1.0)
        assert m.drift_ppm == pytest.approx(0.0, abs=1e-3)
        # (instant round trips, yet the reply is 3 bytes longer than the command: the driver
        # places the box's reading half of that earlier)
        skew = wire_skew("TIME?", "10000000", 115200)
        assert skew == pytest.approx(-3 * 10 / 115200 / 2)
        assert m.to_host(10_500_000) == pytest.approx(1000.5 + skew, abs=1e-6)
        box.edges()
    edge_rows = [r for r in read_log(tmp_path / "trigger.csv") if r["kind"] == "edge"]
    assert [(r["device_time_us"], float(r["host_time"])) for r in edge_rows] == [
        ("10500000", pytest.approx(1000.5 + skew, abs=1e-5)),
        ("10600000", pytest.approx(1000.6 + skew, abs=1e-5))]
    assert all("mapped from the box clock" in r["text"] for r in edge_rows)
    event = [r for r in read_log(tmp_path / "trigger.csv")
             if r["kind"] == "event" and "clock mapping" in r["text"]]
    assert len(event) == 1 and "drift +0.000" in event[0]["text"]



def test_neutral_rows_of_a_fire_and_its_stop(tmp_path):
    """What the box started and stopped, in the rows every backend writes: the start at the
    first edge through the clock mapping, the end after the rising edges it counted once off."""
    from vts_hw.recording.trigger_wave import wave_from_trigger_log
    clock = FakeClock(1000.0)
    trips = [("TIME?", str(round((1000.0 + 0.25 * i - 990.0) * 1e6))) for i in range(4)]
    pairs = lines(*trips, ("*TRG", "OK"), ("OUTP?", "ON"), ("FREQ?", "2"), ("DUTY?", "0.25"),
                  ("EDGES?", "1,11000000,11000000"), ("SYST:ERR?", '0,"No error"'),
                  ("OUTP OFF", "OK"), ("OUTP?", "ON"), ("FREQ?", "2"), ("DUTY?", "0.25"),
                  ("EDGES?", "6,11000000,13500000"), ("SYST:ERR?", '0,"No error"'),
                  ("OUTP?", "OFF"), ("OUTP?", "OFF"), ("FREQ?", "2"), ("DUTY?", "0.25"),
                  ("EDGES?", "7,11000000,14000000"), ("SYST:ERR?", '0,"No error"'))
    path = tmp_path / "trigger.csv"
    with expected_protocol(pairs, log=TriggerLog(path, clock=clock), clock=clock) as box:
        m = box.clock_mapping(samples=4, over_s=0.75, keep=1.0)
        box.fire()
        box.stop()
    rows = read_log(path)
    assert [r["kind"] for r in rows if r["kind"] in ("wave_start", "wave_stop", "clock")] == \
        ["clock", "wave_start", "wave_stop"]
    w = wave_from_trigger_log(path)
    assert w.start_host == pytest.approx(m.to_host(11_000_000), abs=1e-6) and w.time_source == "device_clock_mapped"
    assert (w.period_s, w.duty, w.high_v, w.low_v, w.start_pulse) == (0.5, 0.25, 5.0, 0.0, True)
    assert w.n_rising == 7 and w.stop_host == pytest.approx(w.start_host + 3.5, abs=1e-6)   # the count once off
    assert w.uncertainty_s == pytest.approx(m.uncertainty_s, rel=1e-2) and w.drift_ppm == pytest.approx(0, abs=1e-3)

# ---- the clock mapping --------------------------------------------------------------------------------

class SyntheticBox:
    """TIME? replies of a box whose clock reads 0 at host ``boot`` and maps to host time with
    ``drift_ppm`` as ClockMapping defines it (host s = device s * (1 + drift_ppm * 1e-6), so a
    positive drift is a box clock that runs slow).

    The box reads its clock once the command's 6 bytes have crossed the 115200-baud line and
    its reply then takes its own bytes' time back (11 bytes here: not symmetric). On top come
    host delays (scheduling, USB polling) that fall at random before or after that reading:
    mostly a fraction of a millisecond, now and then 5-50 ms (the host was busy). Those
    delays are what the fit must see through."""

    def __init__(self, boot, drift_ppm, seed=1):
        self.boot = boot
        self.drift = drift_ppm
        self.rng = random.Random(seed)

    def round_trip(self, clock: FakeClock) -> bytes:
        extra = self.rng.expovariate(1 / 0.0003)
        if self.rng.random() < 0.1:
            extra += self.rng.uniform(0.005, 0.05)
        before = self.rng.random() * extra
        t_read = clock.t + 6 * 10 / 115200 + before
        reply = str(round((t_read - self.boot) * 1e6 / (1 + self.drift * 1e-6))).encode() + b"\n"
        clock.t = t_read + len(reply) * 10 / 115200 + (extra - before)  # the reply is complete
        return reply


class LiveScriptedSerial(ScriptedSerial):
    """The TIME? answers are computed when the command is written (they depend on host time)."""

    def __init__(self, synth, clock, n, port, **kw):
        super().__init__([(b"TIME?\n", b"")] * n, port, **kw)
        self.synth = synth
        self.clock = clock

    def write(self, data):
        n = super().write(data)
        self.rx += self.synth.round_trip(self.clock)
        return n


def synthetic_box(drift_ppm, n, boot=1_699_999_000.0, seed=1, **kw):
    clock = FakeClock(1_700_000_000.0)
    synth = SyntheticBox(boot, drift_ppm, seed)
    fakes = {}

    def factory(port, **k):
        fakes["f"] = LiveScriptedSerial(synth, clock, n, port, **k)
        return fakes["f"]

    box = TriggerBox(PORT, serial_factory=factory, clock=clock, sleep=clock.sleep, **kw)
    return box, clock, synth, fakes["f"]


@pytest.mark.parametrize("drift_ppm", [37.0, -120.0, 0.0])
@pytest.mark.parametrize("seed", range(5))
def test_clock_mapping_recovers_offset_and_drift(drift_ppm, seed):
    box, clock, synth, fake = synthetic_box(drift_ppm, 60, seed=seed)
    m = box.clock_mapping(samples=60, over_s=10.0)
    fake.assert_complete()
    assert box.mapping is m
    # the drift within 4 of its standard errors, and that error small over 10 s
    assert box.drift_se_ppm < 3.0
    assert m.drift_ppm == pytest.approx(drift_ppm, abs=4 * box.drift_se_ppm)
    # the mapping puts a device time where the truth does: well within the stated uncertainty
    # (half the shortest round trip), as the line's asymmetry is taken out (skew)
    for host_t in (1_700_000_000.0, 1_700_000_005.0, 1_700_000_010.0):
        dev = (host_t - synth.boot) * 1e6 / (1 + drift_ppm * 1e-6)
        assert abs(m.to_host(dev) - host_t) < 75e-6
        assert abs(m.to_device_us(host_t) - dev) < 75
    assert m.samples <= 30 and m.uncertainty_s >= (6 + 10) * 10 / 115200 / 2  # >= wire time / 2
    assert m.residual_s < 100e-6


def test_clock_mapping_takes_out_the_asymmetry_of_the_line():
    trips = [RoundTrip(100.0 + i, 100.0 + i + 0.0013, 5_000_000 + i * 1_000_000 + 520) for i in range(5)]
    assert wire_skew("TIME?", "5000000", 115200) == pytest.approx((6 - 8) * 10 / 115200 / 2)
    assert wire_skew("TIME?", "5000000", None) == 0.0
    skewed = [RoundTrip(t.host_sent, t.host_received, t.device_us, skew=-0.00013) for t in trips]
    # the box read its clock 0.52 ms after the write: the midpoint (0.65 ms) is 0.13 ms late
    assert fit_clock(trips)[0].to_host(5_000_520) == pytest.approx(100.00065, abs=1e-7)
    assert fit_clock(skewed)[0].to_host(5_000_520) == pytest.approx(100.00052, abs=1e-7)


def test_clock_mapping_paces_samples_over_the_span():
    box, clock, synth, fake = synthetic_box(0.0, 11)
    t0 = clock.t
    box.clock_mapping(samples=11, over_s=5.0)
    assert 5.0 <= clock.t - t0 < 5.1


def test_clock_mapping_history_fits_the_drift_over_the_whole_session():
    box, clock, synth, fake = synthetic_box(37.0, 40)
    box.clock_mapping(samples=20, over_s=0.5)
    clock.t += 600.0  # ten minutes of scanning
    m = box.clock_mapping(samples=20, over_s=0.5)
    assert m.drift_ppm == pytest.approx(37.0, abs=0.5)
    assert m.samples == 20  # the best 10 of each call


def test_clock_mapping_with_64_bit_device_times_keeps_microseconds():
    # a box whose count is past 2^62 us (it never wraps; floats of that size lose whole ms)
    boot = 1_700_000_000.0 - 2**62 * 1e-6
    trips = [RoundTrip(1_700_000_000.0 + i, 1_700_000_000.0 + i + 0.001,
                       2**62 + i * 1_000_000 + 500) for i in range(10)]
    m, se = fit_clock(trips)
    assert m.drift_ppm == pytest.approx(0.0, abs=1e-3)
    assert isinstance(m.ref_device_us, int) and m.ref_device_us > 2**62
    assert m.to_host(2**62 + 3_000_500) == pytest.approx(1_700_000_003.0005, abs=2e-6)
    assert boot  # (the origin is far in the past, as it should be)


def test_clock_fit_rejects_outliers_and_weights_short_round_trips():
    rng = random.Random(3)
    trips = []
    for i in range(30):
        t = 1000.0 + i * 0.1
        rtt = 0.001
        dev = round((t + rtt / 2 - 900.0) * 1e6)
        if i in (7, 19):  # the device answered late although the round trip looks short
            dev -= 20_000
        trips.append(RoundTrip(t, t + rtt + rng.uniform(0, 1e-5), dev))
    m, se = fit_clock(trips)
    assert m.samples == 28
    assert m.drift_ppm == pytest.approx(0.0, abs=20)
    assert m.residual_s < 20e-6


def test_best_round_trips_keeps_the_shortest_in_time_order():
    trips = [RoundTrip(i, i + r, i) for i, r in enumerate([0.5, 0.1, 0.3, 0.2, 0.9, 0.15])]
    assert [t.device_us for t in best_round_trips(trips, 0.5)] == [1, 3, 5]
    assert len(best_round_trips(trips[:2], 0.1)) == 2


def test_a_reboot_between_mappings_drops_the_history():
    box, clock, synth, fake = synthetic_box(37.0, 40)
    box.clock_mapping(samples=20, over_s=0.5)
    clock.t += 600.0
    synth.boot = clock.t - 30.0   # it rebooted 30 s ago: its clock is far ahead of nothing
    m = box.clock_mapping(samples=20, over_s=0.5)
    assert m.samples == 10        # this call's samples only
    assert any("clock jumped" in r[4] for r in box.log.lines)


def test_clock_going_back_during_a_mapping_is_an_error():
    with expected_protocol(lines(("TIME?", "5000000"), ("TIME?", "1000"))) as box:
        box.sleep = lambda s: None
        with pytest.raises(TriggerError, match="clock went back from 5000000 to 1000 us .*reboot"):
            box.clock_mapping(samples=2, over_s=0.0)


def test_clock_mapping_needs_two_samples():
    with expected_protocol([]) as box:
        with pytest.raises(ValueError, match="at least 2 samples"):
            box.clock_mapping(samples=1)


# ---- odds and ends ------------------------------------------------------------------------------------

def test_number_text():
    assert [number_text(v) for v in (10, 0.1, 1000.0, 0.25, 12.5, 1000 / 3, 0.01)] == \
        ["10", "0.1", "1000", "0.25", "12.5", "333.333", "0.01"]


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
    pairs = lines(("OUTP ON", "OK"), ("OUTP?", "ON"), ("FREQ?", "10"), ("DUTY?", "1.5"), ("EDGES?", "1,5,5"),
                  ("SYST:ERR?", '0,"No error"'))
    with expected_protocol(pairs) as box:
        with pytest.raises(TriggerError, match="confirms 10.0 Hz at duty 1.5: not a square wave"):
            box.start()
