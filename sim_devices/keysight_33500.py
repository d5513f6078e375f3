"""A simulated Keysight 33522B: the SCPI subset of the 33500 family, as the instrument answers it.

:class:`Keysight33500` is the instrument (state, parser, error queue) with no I/O; the simulated
rig serves it on a TCP socket on 127.0.0.1 (:mod:`.scpi_server`), where a VISA client reaches it
as ``TCPIP::127.0.0.1::PORT::SOCKET``, as a real 33500 is reached on port 5025 of the LAN. The
driver's unit tests use the pyvisa-sim model ``keysight_33500.yaml`` instead.

What it understands (docs/design.md, "Function generator"; short or long forms, any case, several
commands in one line separated by ``;``, the SCPI path rules for headers without a leading colon)::

    *IDN?  *RST  *CLS  *OPC  *OPC?  *WAI          SYSTem:ERRor[:NEXT]?  SYSTem:VERSion?
    [SOURce[1|2]:]FUNCtion {SINusoid|SQUare|TRIangle|RAMP|PULSe|PRBS|NOISe|ARB|DC}   and ?
    [SOURce[1|2]:]FREQuency {<hz>|MINimum|MAXimum|DEFault}                           and ? [MIN|MAX]
    [SOURce[1|2]:]FUNCtion:SQUare:DCYCle {<percent>|MIN|MAX|DEF}                     and ? [MIN|MAX]
    [SOURce[1|2]:]VOLTage:HIGH {<v>|MIN|MAX|DEF}   [SOURce[1|2]:]VOLTage:LOW ...     and ? [MIN|MAX]
    OUTPut[1|2] {ON|1|OFF|0}                                                          and ? (1|0)

How it answers, as the instrument does (docs/decisions/0021):

* a value beyond a limit is clipped to it and queues ``-222,"Data out of range;value clipped to
  upper limit"`` (or lower); a high level set at or below the low level moves the low level to
  1 mV below it and queues ``-221,"Settings conflict;..."`` (and the same the other way round); a
  frequency at which the square duty cycle no longer fits the 16 ns minimum pulse changes the duty
  cycle and queues ``-221,"Settings conflict;frequency forced duty cycle change"``;
* an unknown header ``-113,"Undefined header"``; a missing, extra or wrong parameter ``-109``,
  ``-108``, ``-104``, ``-224``, ``-131``; channel 3 ``-114,"Header suffix out of range"``;
* the queue holds 20 errors; a 21st replaces the last with ``-350,"Queue overflow"``;
  ``SYST:ERR?`` answers ``+0,"No error"`` when empty; ``*CLS`` empties it, ``*RST`` does not;
* numbers as ``+1.00000000000000E+03``, ``OUTP?`` as ``1|0``, ``FUNC?`` in short form;
  several queries in one line are answered in one line, joined by ``;``.

The state (function, frequency, duty cycle, levels, output, per channel) lasts as long as the
object; every change of an output, and every change of the wave while an output is on, is kept
with the host time it happened (:attr:`Keysight33500.events`, :meth:`Keysight33500.runs`), so a
simulation can know when the wave ran and what it was.
"""

from __future__ import annotations

import math
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, replace

IDN = "Keysight Technologies,33522B,MY00000000,3.05-1.19-2.00-52-00"
CHANNELS = 2
QUEUE_SIZE = 20
LEVEL_LIMIT_V = 5.0  # |high|, |low| into the 50 ohm setting (the *RST default)
MIN_AMPLITUDE_V = 1e-3
FREQ_MIN_HZ = 1e-6
FREQ_MAX_HZ = {
    "SIN": 30e6,
    "SQU": 30e6,
    "PULS": 30e6,
    "RAMP": 200e3,
    "TRI": 200e3,
    "PRBS": 30e6,
    "NOIS": 30e6,
    "ARB": 30e6,
    "DC": 30e6,
}  # a 33522B (30 MHz)
DUTY_MIN_PCT, DUTY_MAX_PCT = 0.01, 99.99
MIN_PULSE_S = 16e-9
FUNCTIONS = {
    "SIN": "SINUSOID",
    "SQU": "SQUARE",
    "TRI": "TRIANGLE",
    "RAMP": "RAMP",
    "PULS": "PULSE",
    "PRBS": "PRBS",
    "NOIS": "NOISE",
    "ARB": "ARB",
    "DC": "DC",
}

# SCPI error numbers and texts (SCPI 1999 / IEEE 488.2; the part after ';' as the 33500 adds it)
NO_ERROR = (0, "No error")
UNDEFINED_HEADER = (-113, "Undefined header")
SUFFIX_OUT_OF_RANGE = (-114, "Header suffix out of range")
MISSING_PARAMETER = (-109, "Missing parameter")
PARAMETER_NOT_ALLOWED = (-108, "Parameter not allowed")
DATA_TYPE_ERROR = (-104, "Data type error")
INVALID_CHARACTER = (-101, "Invalid character")
INVALID_SUFFIX = (-131, "Invalid suffix")
ILLEGAL_VALUE = (-224, "Illegal parameter value")
CLIPPED_UP = (-222, "Data out of range;value clipped to upper limit")
CLIPPED_DOWN = (-222, "Data out of range;value clipped to lower limit")
QUEUE_OVERFLOW = (-350, "Queue overflow")


class ScpiError(Exception):
    def __init__(self, error: tuple[int, str]):
        super().__init__(error[1])
        self.error = error


@dataclass
class Channel:
    """One output's settings; the defaults are the instrument's *RST state."""

    function: str = "SIN"
    frequency_hz: float = 1000.0
    duty_percent: float = 50.0
    high_v: float = 0.05
    low_v: float = -0.05
    output: bool = False


@dataclass(frozen=True)
class OutputEvent:
    """An output switched, or its wave changed while it was on, at ``host_time``."""

    host_time: float
    channel: int
    output: bool
    function: str
    frequency_hz: float
    duty_percent: float
    high_v: float
    low_v: float


@dataclass(frozen=True)
class WaveRun:
    """An interval during which an output was on with one wave (``stop`` None: still on)."""

    channel: int
    start: float
    stop: float | None
    function: str
    frequency_hz: float
    duty_percent: float
    high_v: float
    low_v: float


# ---- headers ------------------------------------------------------------------------------------


def _header_regex(pattern: str) -> re.Pattern:
    """``[SOURce#:]FREQuency`` -> a regex over an upper-case header: each mnemonic in its short
    (upper-case part) or long form, ``[...]`` optional, ``#`` an optional numeric suffix."""
    out, i = [], 0
    while i < len(pattern):
        c = pattern[i]
        if c.isalpha():
            j = i
            while j < len(pattern) and pattern[j].isalpha():
                j += 1
            word = pattern[i:j]
            short = "".join(ch for ch in word if ch.isupper())
            out.append(
                f"(?:{re.escape(word.upper())}|{re.escape(short)})" if short != word.upper() else re.escape(word)
            )
            i = j
            continue
        out.append({"[": "(?:", "]": ")?", "#": r"(?P<ch>\d+)?"}.get(c, re.escape(c)))
        i += 1
    return re.compile("".join(out))


@dataclass(frozen=True)
class _Cmd:
    regex: re.Pattern
    handler: str  # the Keysight33500 method: _x(ch, args, query)
    set_ok: bool = True
    query_ok: bool = True


_COMMANDS = [
    _Cmd(_header_regex(p), h, s, q)
    for p, h, s, q in [
        ("*IDN", "_idn", False, True),
        ("*RST", "_rst", True, False),
        ("*CLS", "_cls", True, False),
        ("*OPC", "_opc", True, True),
        ("*WAI", "_opc", True, False),
        ("SYSTem:ERRor[:NEXT]", "_error", False, True),
        ("SYSTem:VERSion", "_version", False, True),
        ("[SOURce#:]FUNCtion:SQUare:DCYCle", "_duty", True, True),
        ("[SOURce#:]FUNCtion", "_function", True, True),
        ("[SOURce#:]FREQuency", "_frequency", True, True),
        ("[SOURce#:]VOLTage:HIGH", "_high", True, True),
        ("[SOURce#:]VOLTage:LOW", "_low", True, True),
        ("OUTPut#", "_output", True, True),
    ]
]

_NUMBER = re.compile(r"^([+-]?(?:\d+\.?\d*|\.\d+)(?:E[+-]?\d+)?)\s*([A-Z]*)$")
_SUFFIXES = {
    "HZ": {"": 1.0, "HZ": 1.0, "KHZ": 1e3, "MHZ": 1e6},  # SCPI: MHZ is megahertz
    "V": {"": 1.0, "V": 1.0, "MV": 1e-3},
    "PCT": {"": 1.0},
}


def _fmt(value: float) -> str:
    return f"{value:+.14E}"


# ---- the instrument -------------------------------------------------------------------------------


class Keysight33500:
    """The instrument: :meth:`execute` takes one program message (a line without its terminator)
    and returns the response message, or None when nothing is to be answered."""

    def __init__(self, idn: str = IDN, clock: Callable[[], float] = time.time):
        self.idn = idn
        self.clock = clock
        self.channels = {n: Channel() for n in range(1, CHANNELS + 1)}
        self.errors: deque[tuple[int, str]] = deque()
        self.events: list[OutputEvent] = []
        self.listeners: list[Callable[[OutputEvent], None]] = []
        self.lock = threading.RLock()

    # -- the message exchange -------------------------------------------------------------------------
    def execute(self, line: str) -> str | None:
        replies: list[str] = []
        with self.lock:
            if not line.isascii():
                self._queue(INVALID_CHARACTER)
                return None
            path = ""
            for unit in line.split(";"):
                unit = unit.strip()
                if not unit:
                    continue
                header, _, rest = unit.partition(" ")
                header = header.upper()
                args = [a.strip() for a in rest.split(",")] if rest.strip() else []
                if header.startswith(":"):
                    header, path = header[1:], ""
                query = header.endswith("?")
                if query:
                    header = header[:-1]
                if not header.startswith("*"):
                    header = path + header
                    path = header.rpartition(":")[0] + ":" if ":" in header else ""
                try:
                    reply = self._dispatch(header, args, query)
                except ScpiError as e:
                    self._queue(e.error)
                    continue
                if reply is not None:
                    replies.append(reply)
        return ";".join(replies) if replies else None

    def _dispatch(self, header: str, args: list[str], query: bool) -> str | None:
        for cmd in _COMMANDS:
            m = cmd.regex.fullmatch(header)
            if m is None:
                continue
            if (query and not cmd.query_ok) or (not query and not cmd.set_ok):
                raise ScpiError(UNDEFINED_HEADER)
            ch = int(m.groupdict().get("ch") or 1)
            if not 1 <= ch <= CHANNELS:
                raise ScpiError(SUFFIX_OUT_OF_RANGE)
            return getattr(self, cmd.handler)(ch, args, query)
        raise ScpiError(UNDEFINED_HEADER)

    def _queue(self, error: tuple[int, str]) -> None:
        if len(self.errors) >= QUEUE_SIZE:
            self.errors[-1] = QUEUE_OVERFLOW
        else:
            self.errors.append(error)

    # -- common and system commands ---------------------------------------------------------------------
    def _idn(self, ch, args, query):
        _no_args(args)
        return self.idn

    def _rst(self, ch, args, query):
        _no_args(args)
        for n in self.channels:
            self._change(n, **vars(Channel()))

    def _cls(self, ch, args, query):
        _no_args(args)
        self.errors.clear()

    def _opc(self, ch, args, query):
        _no_args(args)
        return "1" if query else None

    def _error(self, ch, args, query):
        _no_args(args)
        code, text = self.errors.popleft() if self.errors else NO_ERROR
        return f'{code:+d},"{text}"'

    def _version(self, ch, args, query):
        _no_args(args)
        return "1999.0"

    # -- the wave -----------------------------------------------------------------------------------------
    def _function(self, ch, args, query):
        c = self.channels[ch]
        if query:
            _no_args(args)
            return c.function
        word = _one_arg(args).upper()
        name = next((short for short, long in FUNCTIONS.items() if word in (short, long)), None)
        if name is None:
            raise ScpiError(ILLEGAL_VALUE)
        new = {"function": name}
        if c.frequency_hz > FREQ_MAX_HZ[name]:
            new["frequency_hz"] = FREQ_MAX_HZ[name]
            self._queue((-221, "Settings conflict;frequency changed due to function"))
        self._change(ch, **new)
        self._fit_duty(ch)

    def _frequency(self, ch, args, query):
        c = self.channels[ch]
        lo, hi = FREQ_MIN_HZ, FREQ_MAX_HZ[c.function]
        if query:
            return _fmt(_limit_query(args, c.frequency_hz, lo, hi))
        self._change(ch, frequency_hz=self._number(args, "HZ", lo, hi, 1000.0))
        self._fit_duty(ch)

    def _duty_limits(self, ch: int) -> tuple[float, float]:
        f = self.channels[ch].frequency_hz
        return (max(DUTY_MIN_PCT, 100.0 * MIN_PULSE_S * f), min(DUTY_MAX_PCT, 100.0 * (1 - MIN_PULSE_S * f)))

    def _duty(self, ch, args, query):
        lo, hi = self._duty_limits(ch)
        if query:
            return _fmt(_limit_query(args, self.channels[ch].duty_percent, lo, hi))
        self._change(ch, duty_percent=self._number(args, "PCT", lo, hi, 50.0))

    def _fit_duty(self, ch: int) -> None:
        """The square duty cycle must fit the 16 ns minimum pulse at the present frequency."""
        c = self.channels[ch]
        lo, hi = self._duty_limits(ch)
        if c.function == "SQU" and not lo <= c.duty_percent <= hi:
            self._change(ch, duty_percent=min(max(c.duty_percent, lo), hi))
            self._queue((-221, "Settings conflict;frequency forced duty cycle change"))

    def _high(self, ch, args, query):
        c = self.channels[ch]
        if query:
            return _fmt(_limit_query(args, c.high_v, -LEVEL_LIMIT_V + MIN_AMPLITUDE_V, LEVEL_LIMIT_V))
        v = self._number(args, "V", -LEVEL_LIMIT_V + MIN_AMPLITUDE_V, LEVEL_LIMIT_V, 0.05)
        low = c.low_v
        if v - low < MIN_AMPLITUDE_V - 1e-12:  # the low level gives way, 1 mV below
            low = v - MIN_AMPLITUDE_V
            self._queue((-221, "Settings conflict;low level changed due to high level"))
        self._change(ch, high_v=v, low_v=low)

    def _low(self, ch, args, query):
        c = self.channels[ch]
        if query:
            return _fmt(_limit_query(args, c.low_v, -LEVEL_LIMIT_V, LEVEL_LIMIT_V - MIN_AMPLITUDE_V))
        v = self._number(args, "V", -LEVEL_LIMIT_V, LEVEL_LIMIT_V - MIN_AMPLITUDE_V, -0.05)
        high = c.high_v
        if high - v < MIN_AMPLITUDE_V - 1e-12:  # the high level gives way, 1 mV above
            high = v + MIN_AMPLITUDE_V
            self._queue((-221, "Settings conflict;high level changed due to low level"))
        self._change(ch, high_v=high, low_v=v)

    def _output(self, ch, args, query):
        if query:
            _no_args(args)
            return "1" if self.channels[ch].output else "0"
        word = _one_arg(args).upper()
        if word in ("ON", "OFF"):
            on = word == "ON"
        else:
            m = _NUMBER.match(word)
            if m is None:
                raise ScpiError(ILLEGAL_VALUE)
            if m.group(2):
                raise ScpiError(INVALID_SUFFIX)
            on = round(float(m.group(1))) != 0  # IEEE 488.2 boolean: a number, rounded
        self._change(ch, output=on)

    # -- values and state -----------------------------------------------------------------------------------
    def _number(self, args: list[str], unit: str, lo: float, hi: float, default: float) -> float:
        """A numeric parameter (or MIN/MAX/DEF), clipped to [lo, hi] with -222 queued."""
        word = _one_arg(args).upper()
        if word in ("MIN", "MINIMUM"):
            return lo
        if word in ("MAX", "MAXIMUM"):
            return hi
        if word in ("DEF", "DEFAULT"):
            return default
        m = _NUMBER.match(word)
        if m is None:
            raise ScpiError(DATA_TYPE_ERROR)
        scale = _SUFFIXES[unit].get(m.group(2))
        if scale is None:
            raise ScpiError(INVALID_SUFFIX)
        v = float(m.group(1)) * scale
        if not math.isfinite(v):
            raise ScpiError(DATA_TYPE_ERROR)
        if v > hi:
            self._queue(CLIPPED_UP)
            return hi
        if v < lo:
            self._queue(CLIPPED_DOWN)
            return lo
        return v

    def _change(self, ch: int, **values) -> None:
        before = self.channels[ch]
        after = replace(before, **values)
        if after == before:
            return
        self.channels[ch] = after
        if before.output or after.output:
            ev = OutputEvent(
                self.clock(),
                ch,
                after.output,
                after.function,
                after.frequency_hz,
                after.duty_percent,
                after.high_v,
                after.low_v,
            )
            self.events.append(ev)
            for listener in list(self.listeners):
                listener(ev)

    def runs(self, channel: int = 1) -> list[WaveRun]:
        """The intervals during which ``channel``'s output was on, one per wave it sent."""
        with self.lock:
            events = [e for e in self.events if e.channel == channel]
        out: list[WaveRun] = []
        for ev in events:
            if out and out[-1].stop is None:
                out[-1] = replace(out[-1], stop=ev.host_time)
            if ev.output:
                out.append(
                    WaveRun(
                        channel, ev.host_time, None, ev.function, ev.frequency_hz, ev.duty_percent, ev.high_v, ev.low_v
                    )
                )
        return out


def _no_args(args: list[str]) -> None:
    if args:
        raise ScpiError(PARAMETER_NOT_ALLOWED)


def _one_arg(args: list[str]) -> str:
    if not args or not args[0]:
        raise ScpiError(MISSING_PARAMETER)
    if len(args) > 1:
        raise ScpiError(PARAMETER_NOT_ALLOWED)
    return args[0]


def _limit_query(args: list[str], value: float, lo: float, hi: float) -> float:
    """``X?`` the value, ``X? MIN`` / ``X? MAX`` the limits."""
    if not args:
        return value
    word = _one_arg(args).upper()
    if word in ("MIN", "MINIMUM"):
        return lo
    if word in ("MAX", "MAXIMUM"):
        return hi
    raise ScpiError(ILLEGAL_VALUE)
