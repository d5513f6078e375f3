"""Our trigger box (ATmega328P firmware in ``firmware/``) over its USB serial line.

115200 baud 8N1, one ASCII command per line, one reply line per command, lines end in ``\n``
(docs/design.md, "Trigger box (our own firmware, serial)"; firmware/trigger_box/commands.h):

    *IDN?                  VTS,TRIGGERBOX,<serial>,<firmware>
    *RST                   OK                (wave ends on a whole period, defaults restored)
    *CLS                   OK                (error queue emptied)
    FREQ <hz>    FREQ?     OK / the frequency the timer actually makes (FREQ only while off)
    DUTY <f>     DUTY?     OK / the duty cycle it makes, a fraction   (DUTY only while off)
    OUTP ON|OFF  OUTP?     OK / ON or OFF    (starts with a rising edge; OFF finishes the
                                              period under way, and OUTP? says ON until then)
    PULSE <ch> <ms>        OK                (contact closure on channel 1 VTS, 2 SPECT)
    PULSE:WIDTH <ms> / ?   OK / the width of the pulses *TRG sends (default 100 ms)
    *TRG                   OK                (wave and both start pulses on one timer tick)
    TIME?                  device microseconds since boot (64-bit, never wraps in practice)
    EDGES?                 <rising edges since start>,<device us of the first>,<of the last>
    SYST:ERR?              <code>,"<message>" or 0,"No error"
    anything refused       ERR <code> <message>  (nothing changes; the error is queued too)

Everything goes through one primitive, :meth:`TriggerBox.query`: clear stale input, write the
line, read one line within the timeout, log both to ``trigger.csv``. A refusal raises
:class:`BoxRefused` (a :class:`~vts_hw.drivers.trigger.TriggerError`) with the box's own code and
message; no answer raises TriggerError naming the port and the command; a port that vanished
(USB unplugged, emulator gone) raises :class:`BoxGone` and every later call does the same.

Settable values are declared once (:class:`BoxSetting`, PyMeasure style) with a validator that
refuses a bad value before a byte is sent. The box has fixed TTL levels, so it does not have the
LEVELS capability. The box's clock can be mapped to host time (:meth:`TriggerBox.clock_mapping`,
a fit over ``TIME?`` round trips weighted towards the shortest), and the edge times the box
reports are logged in host time through that mapping (docs/decisions/0011).
"""

from __future__ import annotations

import math
import re
from collections import deque
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import serial

from vts_hw.drivers.settings import Setting, in_range, whole_in_range
from vts_hw.drivers.trigger import (
    CLOCK,
    DUTY,
    EDGES,
    FIRE,
    FREQUENCY,
    LEVELS,
    PULSE,
    ClockMapping,
    OutOfRange,
    TriggerBase,
    TriggerError,
    TriggerLog,
    TriggerStatus,
)

DEVICE = "the trigger box"
BAUDRATE = 115200
FREQ_MIN_HZ = 0.1
FREQ_MAX_HZ = 1000.0
DUTY_MIN = 0.01
DUTY_MAX = 0.99
PULSE_MS_MIN = 1
PULSE_MS_MAX = 10_000
VENDOR = "VTS"
MODEL = "TRIGGERBOX"

#: how far a confirmed value may be from the asked one (the timer's resolution is far finer)
FREQ_REL_TOLERANCE = 1e-3
DUTY_ABS_TOLERANCE = 1e-3
MAX_LINE = 256                 # bytes; a longer "line" is noise, not a reply
MAX_ERRORS_READ = 16           # more than the firmware's error queue holds
MAX_ROUND_TRIPS_KEPT = 2000    # clock-mapping history (about 100 calls of 20)
POLL_S = 0.01                  # while waiting for the last period to finish
SETTINGS_CONFLICT = -221       # the box's code for "not while the wave is on / a pulse runs"


class BoxRefused(TriggerError):
    """The box answered ``ERR <code> <message>``."""

    def __init__(self, text: str, code: int | None, device_message: str):
        super().__init__(text)
        self.code = code
        self.device_message = device_message


class BoxGone(TriggerError):
    """The serial port vanished (USB unplugged, box powered off, emulator stopped)."""


# ---- declared settings (PyMeasure style) ----------------------------------------------------------

_pulse_ms = whole_in_range(PULSE_MS_MIN, PULSE_MS_MAX, "a start pulse", "ms")


def number_text(value: float) -> str:
    """A value as the box's parser takes it: plain decimal, no exponent, at most 6 significant
    digits (the timer quantises far more coarsely): 10 -> '10', 0.25 -> '0.25'."""
    text = f"{value:.6g}"
    if "e" in text:  # not reachable within the box's ranges; keep the wire free of exponents
        text = f"{value:.6f}".rstrip("0").rstrip(".")
    return text


class BoxSetting(Setting):
    """A value of the box: assigning validates, sends the command and requires ``OK``;
    numbers go out as the box's parser takes them."""

    default_fmt = staticmethod(number_text)


# ---- what the box reports -------------------------------------------------------------------------

@dataclass(frozen=True)
class BoxIdentity:
    """``*IDN?`` parsed: ``VTS,TRIGGERBOX,<serial>,<firmware>``."""

    vendor: str
    model: str
    serial: str
    firmware: str
    raw: str


@dataclass(frozen=True)
class RoundTrip:
    """One ``TIME?`` exchange: host time just before the write and just after the reply.

    ``skew`` moves the midpoint to where the box most likely read its clock: it reads it once
    the whole command has arrived and before the first byte of its reply leaves, so with a
    6-byte command and an 11-byte reply on a 115200-baud line the reading is
    (11 - 6) * 10 / 115200 / 2 = 0.2 ms before the midpoint: skew = (wire_in - wire_out) / 2.
    """

    host_sent: float
    host_received: float
    device_us: int
    skew: float = 0.0

    @property
    def rtt(self) -> float:
        return self.host_received - self.host_sent

    @property
    def host_mid(self) -> float:
        return 0.5 * (self.host_sent + self.host_received) + self.skew


def wire_skew(cmd: str, reply: str, baudrate: float | None, bits_per_byte: int = 10) -> float:
    """(time on the wire of the command line - of the reply line) / 2, in seconds (8N1: 10 bits
    a byte); 0 when the baud rate is unknown."""
    if not baudrate:
        return 0.0
    return (len(cmd) + 1 - (len(reply) + 1)) * bits_per_byte / baudrate / 2


# ---- the driver -----------------------------------------------------------------------------------

class TriggerBox(TriggerBase):
    """The trigger box on a serial port, as a :class:`~vts_hw.drivers.trigger.TriggerGenerator`."""

    capabilities = frozenset({FREQUENCY, DUTY, PULSE, FIRE, CLOCK, EDGES})

    frequency_hz = BoxSetting("FREQ {}", "FREQ?",
                              in_range(FREQ_MIN_HZ, FREQ_MAX_HZ, "frequency", "Hz", DEVICE),
                              doc="square-wave frequency in Hz; reads back what the timer makes")
    duty = BoxSetting("DUTY {}", "DUTY?", in_range(DUTY_MIN, DUTY_MAX, "duty cycle", "", DEVICE),
                      doc="square-wave duty cycle, a fraction")
    fire_pulse_ms = BoxSetting("PULSE:WIDTH {}", "PULSE:WIDTH?",
                               whole_in_range(PULSE_MS_MIN, PULSE_MS_MAX, "start pulse width", "ms"),
                               fmt=str, parse=int, doc="width of the start pulses *TRG sends")

    def __init__(self, port: str, *, baudrate: int = BAUDRATE, timeout: float = 1.0,
                 log: TriggerLog | None = None, name: str = "triggerbox", clock=time.time,
                 serial_factory: Callable[..., Any] = serial.serial_for_url,
                 sleep: Callable[[float], None] = time.sleep):
        """Open ``port`` (a device path or any pyserial URL). Nothing is sent until asked.

        ``clock`` stamps the log and the clock-mapping round trips (host epoch seconds);
        ``serial_factory(port, baudrate=, timeout=, write_timeout=)`` opens the line (the
        protocol tests pass a scripted fake); ``sleep`` paces clock-mapping samples.
        """
        super().__init__(name, log)
        self.port = port
        self.baudrate = baudrate
        self.timeout = timeout
        self.clock = clock
        self.sleep = sleep
        self.identity: BoxIdentity | None = None
        self.mapping: ClockMapping | None = None
        self.drift_se_ppm: float | None = None   # the standard error of mapping.drift_ppm
        self._lock = threading.RLock()
        self._gone: str | None = None          # the reason, once the port has vanished
        self._closed = False
        self._batches: list[list[RoundTrip]] = []   # kept TIME? round trips, per clock_mapping call
        self._logged_edges: tuple[int | None, int | None] = (None, None)
        self._reported: deque[int] = deque()     # codes raised as BoxRefused, still in the box's queue
        try:
            self._serial = serial_factory(port, baudrate=baudrate, timeout=timeout,
                                          write_timeout=timeout)
        except (serial.SerialException, OSError, ValueError) as e:
            raise TriggerError(f"cannot open the trigger box on {port}: {e}") from e
        self._log("event", f"open {port} {baudrate} baud")

    def _log(self, kind: str, text: str, device_us: int | None = None,
             host_time: float | None = None) -> None:
        """A trigger.csv line, stamped with this driver's clock unless a host time is given."""
        self.log.write(self.name, kind, text, device_us=device_us,
                       host_time=self.clock() if host_time is None else host_time)

    @property
    def where(self) -> str:
        """How messages name this device: ``trigger box on /dev/ttyACM0``."""
        if self.name == "triggerbox":
            return f"trigger box on {self.port}"
        return f"trigger box {self.name!r} on {self.port}"

    def __repr__(self) -> str:
        state = "gone" if self._gone else "closed" if self._closed else "open"
        who = (f", {self.identity.model} serial {self.identity.serial} firmware {self.identity.firmware}"
               if self.identity else "")
        clock = ""
        if self.mapping is not None:
            m = self.mapping
            clock = f", clock mapped (drift {m.drift_ppm:+.1f} ppm, ±{m.uncertainty_s * 1e6:.0f} us)"
        return f"<TriggerBox {self.name!r} on {self.port} at {self.baudrate} baud{who}, {state}{clock}>"

    # -- the wire ------------------------------------------------------------------------------------

    def query(self, cmd: str) -> str:
        """Send one command line and return the box's one-line reply (without ``\\n``).

        Raises BoxRefused on ``ERR ...``, TriggerError on no (whole) reply within the timeout,
        BoxGone when the port has vanished.
        """
        return self._exchange(cmd)[0]

    def _exchange(self, cmd: str) -> tuple[str, float, float]:
        """(reply, host time just before the write, host time the reply was complete)."""
        if not isinstance(cmd, str) or not cmd or not cmd.isascii() or "\n" in cmd or "\r" in cmd:
            raise ValueError(f"a trigger box command is one non-empty ASCII line, not {cmd!r}")
        with self._lock:
            if self._gone:
                raise BoxGone(f"{self.where} is gone (unplugged?): cannot send {cmd!r} ({self._gone})")
            if self._closed:
                raise TriggerError(f"{self.where} is closed: cannot send {cmd!r}")
            ser = self._serial
            try:
                self._discard_stale(ser)
                sent = self.clock()
                ser.write((cmd + "\n").encode("ascii"))
                raw = ser.read_until(b"\n", MAX_LINE)
                received = self.clock()
            except serial.SerialTimeoutException as e:  # a write that the line never took
                self._log("cmd", cmd)
                raise TriggerError(f"{self.where} did not take {cmd!r} within {self.timeout:g} s "
                                   f"({e})") from e
            except (serial.SerialException, OSError) as e:
                self._log("cmd", cmd)
                raise self._vanished(cmd, e) from e
            self._log("cmd", cmd, host_time=sent)
            if not raw.endswith(b"\n"):
                if raw:
                    self._log("event", f"partial reply to {cmd} without end of line: "
                                       f"{raw.decode('ascii', 'replace')!r}", host_time=received)
                    if len(raw) >= MAX_LINE:
                        raise TriggerError(f"{self.where} answered {cmd!r} with {len(raw)} bytes and "
                                           f"no end of line: {raw[:40]!r}...")
                raise TriggerError(f"{self.where} did not answer {cmd!r} within {self.timeout:g} s"
                                   + (f" (only {raw.decode('ascii', 'replace')!r} came)" if raw else ""))
            reply = raw.decode("ascii", "replace").strip("\r\n")
            self._log("reply", reply, host_time=received)
            if reply == "ERR" or reply.startswith("ERR "):
                raise self._refused(cmd, reply)
        return reply, sent, received

    def _discard_stale(self, ser) -> None:
        """Drop (and log) whatever arrived unasked: a late reply, a boot banner, line noise."""
        waiting = ser.in_waiting
        if waiting:
            stale = ser.read(waiting)
            if stale:
                self._log("event", f"discarded stale input {stale.decode('ascii', 'replace')!r}")

    def _vanished(self, cmd: str, e: Exception) -> BoxGone:
        self._gone = str(e) or type(e).__name__
        self._log("event", f"port gone during {cmd}: {self._gone}")
        try:
            self._serial.close()
        except Exception:  # a dead port may fail to close; the error that killed it matters
            pass
        return BoxGone(f"{self.where} is gone (unplugged?): {cmd!r} failed ({self._gone})")

    def _refused(self, cmd: str, reply: str) -> BoxRefused:
        m = re.match(r"ERR\s+(-?\d+)\s*(.*)$", reply)
        code, message = (int(m.group(1)), m.group(2).strip()) if m else (None, reply[3:].strip())
        said = f"ERR {code} {message}".strip() if code is not None else reply
        if code is not None:
            self._reported.append(code)  # the box queues it too; read_errors() will skip it
        hint = ""
        if code == SETTINGS_CONFLICT and cmd.split()[0].upper() in ("FREQ", "DUTY"):
            hint = " (the box takes a new frequency or duty only while its output is off: stop() first)"
        return BoxRefused(f"{self.where} refused {cmd!r}: {said}{hint}", code, message)

    def _command(self, cmd: str) -> None:
        """A command whose only good answer is ``OK``."""
        reply = self.query(cmd)
        if reply != "OK":
            raise TriggerError(f"{self.where} answered {cmd!r} with {reply!r}, not OK")

    def _parse(self, cmd: str, reply: str, parse: Callable[[str], Any], what: str) -> Any:
        try:
            return parse(reply)
        except (TypeError, ValueError):
            raise TriggerError(f"{self.where} answered {cmd!r} with {reply!r}, not a {what}") from None

    def _read_setting(self, setting: BoxSetting) -> Any:
        return self._parse(setting.query, self.query(setting.query), setting.parse, setting.name)

    def _write_setting(self, setting: BoxSetting, value: Any) -> None:
        self._command(setting.command.format(self._validate(setting, value, setting.fmt)))

    def _validate(self, setting: BoxSetting, value: Any, fmt: Callable[[Any], str] | None = None):
        try:
            v = setting.validator(value)
        except OutOfRange as e:
            raise OutOfRange(f"{self.where}: {e}; nothing was sent") from None
        return fmt(v) if fmt else v

    # -- identity and reset ----------------------------------------------------------------------------

    def identify(self) -> BoxIdentity:
        """``*IDN?``, parsed; TriggerError if the port answers but is not our box."""
        raw = self.query("*IDN?")
        parts = [p.strip() for p in raw.split(",")]
        if len(parts) != 4 or parts[0] != VENDOR or parts[1] != MODEL:
            raise TriggerError(f"{self.where} answers *IDN? with {raw!r}, not "
                               f"'{VENDOR},{MODEL},<serial>,<firmware>': is it a trigger box?")
        self.identity = BoxIdentity(*parts, raw=raw)
        return self.identity

    def reset(self) -> None:
        """``*RST``: defaults restored; returns once the output is off (a running wave first
        finishes its period, up to 10 s at 0.1 Hz). The box's clock keeps running."""
        with self._lock:
            self._command("*RST")
            self._wait_off("*RST", 1.0 / FREQ_MIN_HZ)
            self._logged_edges = (None, None)

    def clear_errors(self) -> None:
        """``*CLS``: empty the box's error queue."""
        with self._lock:
            self._command("*CLS")
            self._reported.clear()

    def _output_on(self) -> bool:
        outp = self.query("OUTP?")
        if outp not in ("ON", "OFF"):
            raise TriggerError(f"{self.where} answered 'OUTP?' with {outp!r}, not ON or OFF")
        return outp == "ON"

    def _wait_off(self, what: str, period_s: float) -> None:
        """Poll ``OUTP?`` until OFF: the box ends the wave on a whole period."""
        deadline = self.clock() + period_s + 2 * self.timeout
        while self._output_on():
            if self.clock() > deadline:
                raise TriggerError(f"{self.where} still reports its output ON {period_s:g} s "
                                   f"(one period) after {what!r}")
            self.sleep(POLL_S)

    # -- the trigger contract ---------------------------------------------------------------------------

    def configure(self, frequency_hz: float, duty: float = 0.5, high_v: float | None = None,
                  low_v: float | None = None) -> TriggerStatus:
        """Set frequency and duty; return what the box confirms (its actual frequency).

        Everything is checked before a byte is sent. Errors already queued in the box are read
        first (and logged, not raised: they are not this call's); then FREQ and DUTY, the
        read-back (:meth:`status`) and its error queue, which must be empty.
        """
        self.require(FREQUENCY)
        self.require(DUTY)
        if high_v is not None or low_v is not None:
            self.require(LEVELS, "set output levels: its outputs are fixed 0/5 V TTL levels")
        f = self._validate(TriggerBox.frequency_hz, frequency_hz)
        d = self._validate(TriggerBox.duty, duty)
        with self._lock:
            for err in self.read_errors():
                self._log("event", f"error queued before configure: {err}")
            self._command(f"FREQ {number_text(f)}")
            self._command(f"DUTY {number_text(d)}")
            st = self.status()
        if st.errors:
            raise TriggerError(f"{self.where} reports errors after configure: {'; '.join(st.errors)}")
        if st.frequency_hz is None or not math.isclose(st.frequency_hz, f, rel_tol=FREQ_REL_TOLERANCE):
            raise TriggerError(f"{self.where} was asked for {f:g} Hz but confirms {st.frequency_hz!r} Hz")
        if st.duty is None or abs(st.duty - d) > DUTY_ABS_TOLERANCE:
            raise TriggerError(f"{self.where} was asked for duty {d:g} but confirms {st.duty!r}")
        return st

    def start(self) -> TriggerStatus:
        """``OUTP ON``: the square wave alone, from a rising edge. Returns the box's status."""
        with self._lock:
            self._command("OUTP ON")
            st = self.status()
        if not st.running:
            raise TriggerError(f"{self.where} was switched on but reports its output OFF")
        return st

    def stop(self, wait: bool = True) -> TriggerStatus:
        """``OUTP OFF``: the box finishes the period under way, then stops.

        With ``wait`` (the default) this returns once the last period has ended (at most one
        period, 10 s at 0.1 Hz), with the edges of the whole run; without, at once, with
        ``running`` still True while the last period finishes.
        """
        with self._lock:
            self._command("OUTP OFF")
            st = self.status()
            if st.running and wait:
                self._wait_off("OUTP OFF", 1.0 / (st.frequency_hz or FREQ_MIN_HZ))
                st = self.status()
                if st.running:  # pragma: no cover - it said OFF a moment ago
                    raise TriggerError(f"{self.where} was switched off but reports its output ON")
        return st

    def pulse(self, channel: int, ms: int) -> None:
        """``PULSE <channel> <ms>``: a contact closure of ``ms`` (1..10000) on channel 1 or 2."""
        self.require(PULSE)
        self.check_channel(channel)
        try:
            ms = _pulse_ms(ms)
        except OutOfRange as e:
            raise OutOfRange(f"{self.where}: {e}; nothing was sent") from None
        self._command(f"PULSE {channel} {ms}")

    def fire(self, pulse_ms: int | None = None) -> TriggerStatus:
        """``*TRG``: the square wave and both start pulses on the same timer tick.

        ``pulse_ms`` first sets the width of those pulses (``PULSE:WIDTH``; the box's default
        is 100 ms and *RST restores it)."""
        self.require(FIRE)
        with self._lock:
            if pulse_ms is not None:
                self.fire_pulse_ms = pulse_ms
            self._command("*TRG")
            st = self.status()
        if not st.running:
            raise TriggerError(f"{self.where} was fired but reports its output OFF")
        return st

    def status(self) -> TriggerStatus:
        """``OUTP?``, ``FREQ?``, ``DUTY?``, ``EDGES?`` and the error queue (read empty)."""
        with self._lock:
            running = self._output_on()
            f = self.frequency_hz
            d = self.duty
            n, first, last = self.edges()
            errors = self.read_errors()
        extra: dict[str, Any] = {"port": self.port}
        if self.identity is not None:
            extra["idn"] = self.identity.raw
        if self.mapping is not None and n:
            extra["first_edge_host"] = self.mapping.to_host(first)
            extra["last_edge_host"] = self.mapping.to_host(last)
        return TriggerStatus(device=self.name, running=running, frequency_hz=f, duty=d,
                             edges=n, first_edge_device_us=first if n else None,
                             last_edge_device_us=last if n else None, errors=errors, extra=extra)

    def read_errors(self) -> tuple[str, ...]:
        """``SYST:ERR?`` until ``0,...``; the errors read before it, as the box wrote them.

        The box also queues every error it answered with ``ERR``; those were raised already
        (BoxRefused), so they are logged and left out here, and what is returned is news.
        """
        errors = []
        with self._lock:
            for _ in range(MAX_ERRORS_READ):
                reply = self.query("SYST:ERR?")
                code = self._parse("SYST:ERR?", reply.partition(",")[0], int, "error code")
                if code == 0:
                    self._reported.clear()  # anything still listed was cleared or lost in the box
                    return tuple(errors)
                if self._reported and code == self._reported[0]:
                    self._reported.popleft()
                    self._log("event", f"queued error already raised: {reply}")
                    continue
                errors.append(reply)
        raise TriggerError(f"{self.where} still reports errors after {MAX_ERRORS_READ} reads of "
                           f"SYST:ERR?: {'; '.join(errors[:3])} ...")

    # -- edges and the clock ------------------------------------------------------------------------------

    def device_time_us(self) -> int:
        """``TIME?``: microseconds since the box booted."""
        return self._parse("TIME?", self.query("TIME?"), _uint, "count of microseconds")

    def edges(self) -> tuple[int, int, int]:
        """``EDGES?``: (rising edges since the last start, device us of the first, of the last).

        A first or last edge not logged before is written to ``trigger.csv`` as an ``edge`` line
        with its device time, and its host time through :attr:`mapping` when one has been fitted
        (else the host time of the report, and the text says so).
        """
        self.require(EDGES)
        with self._lock:
            reply = self.query("EDGES?")
            parts = reply.split(",")
            if len(parts) != 3:
                raise TriggerError(f"{self.where} answered 'EDGES?' with {reply!r}, "
                                   f"not '<count>,<first us>,<last us>'")
            n, first, last = (self._parse("EDGES?", p.strip(), _uint, "count or time") for p in parts)
            if n:
                self._log_edges(n, first, last)
        return n, first, last

    def _log_edges(self, n: int, first: int, last: int) -> None:
        logged_first, logged_last = self._logged_edges
        m = self.mapping
        how = "host time mapped from the box clock" if m else "host time = when reported (no clock mapping)"
        if first != logged_first:
            self._log("edge", f"first rising edge (1 of {n}); {how}", device_us=first,
                      host_time=m.to_host(first) if m else None)
        if last != logged_last and last != first:
            self._log("edge", f"last rising edge ({n} of {n}); {how}", device_us=last,
                      host_time=m.to_host(last) if m else None)
        self._logged_edges = (first, last)

    def clock_mapping(self, samples: int = 20, *, over_s: float = 1.0, keep: float = 0.5,
                      history: bool = True) -> ClockMapping:
        """Map the box's microseconds to host time from ``samples`` ``TIME?`` round trips.

        The samples are spread evenly over ``over_s`` seconds; of each call's samples the
        ``keep`` fraction with the shortest round trips is used. With ``history`` the fit also
        uses the samples kept by earlier calls since the box's clock last went back (a reboot),
        so a mapping at the end of a session fits the drift over the whole session. The fit
        (:func:`fit_clock`) weights each sample by 1/round-trip²; the result is kept in
        :attr:`mapping`, used for the edge lines of the log, and logged as an ``event``.
        """
        self.require(CLOCK)
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
            raise ValueError(f"clock_mapping needs at least 2 samples, not {samples!r}")
        if not over_s >= 0 or not 0 < keep <= 1:
            raise ValueError(f"clock_mapping: over_s must be >= 0 and keep in (0, 1] "
                             f"(got {over_s!r}, {keep!r})")
        gap = over_s / (samples - 1)
        trips: list[RoundTrip] = []
        t_begin = self.clock()
        for i in range(samples):
            if i and gap > 0:
                wait = t_begin + i * gap - self.clock()
                if wait > 0:
                    self.sleep(wait)
            reply, sent, received = self._exchange("TIME?")
            device_us = self._parse("TIME?", reply, _uint, "count of microseconds")
            if trips and device_us < trips[-1].device_us:
                raise TriggerError(f"{self.where}: its clock went back from {trips[-1].device_us} "
                                   f"to {device_us} us during the clock mapping (did it reboot?)")
            trips.append(RoundTrip(sent, received, device_us,
                                   wire_skew("TIME?", reply, self._wire_baud())))
        kept = best_round_trips(trips, keep)
        with self._lock:
            if self._batches and _clock_jumped(self._batches[-1][-1], kept[0]):
                self._log("event", "box clock jumped since the last clock mapping (reboot?): "
                                   "earlier samples dropped")
                self._batches.clear()
            if not history:
                self._batches.clear()
            self._batches.append(kept)
            while sum(len(b) for b in self._batches) > MAX_ROUND_TRIPS_KEPT and len(self._batches) > 1:
                self._batches.pop(0)
            used = [t for b in self._batches for t in b]
            mapping, drift_se = fit_clock(used)
            self.mapping = mapping
            self.drift_se_ppm = drift_se
            span = (used[-1].device_us - used[0].device_us) * 1e-6
            self._log("event",
                      f"clock mapping: host = {mapping.ref_host:.6f} + (device_us - "
                      f"{mapping.ref_device_us}) * 1e-6 * (1 + {mapping.drift_ppm:.3f}e-6); "
                      f"drift {mapping.drift_ppm:+.3f} ± {drift_se:.3f} ppm, residual "
                      f"{mapping.residual_s * 1e6:.1f} us, uncertainty {mapping.uncertainty_s * 1e6:.1f} us, "
                      f"{mapping.samples} samples over {span:.3f} s ({len(kept)} of {len(trips)} kept now)",
                      device_us=mapping.ref_device_us, host_time=mapping.ref_host)
        return mapping

    def _wire_baud(self) -> float | None:
        """The line's baud rate when it is a real (or emulated) serial line, else None."""
        baud = getattr(self._serial, "baudrate", self.baudrate)
        return float(baud) if isinstance(baud, (int, float)) and baud > 0 else None

    # -- closing ---------------------------------------------------------------------------------------

    def close(self) -> None:
        """Close the port (the box keeps doing what it was doing) and the log."""
        with self._lock:
            if not self._closed:
                self._closed = True
                if not self._gone:
                    try:
                        self._serial.close()
                    except (serial.SerialException, OSError):
                        pass
                self._log("event", f"closed {self.port}")
        super().close()


# ---- clock fit --------------------------------------------------------------------------------------

def _uint(text: str) -> int:
    """A non-negative decimal integer of any size (the box's counters are 64-bit)."""
    if not text.isdigit():
        raise ValueError(text)
    return int(text)


def _clock_jumped(before: RoundTrip, after: RoundTrip) -> bool:
    """The box's clock did not advance with the host's between two samples (to 1 %, far more
    than any resonator is off, plus 50 ms): it rebooted, or it is another box."""
    dh = after.host_mid - before.host_mid
    dd = (after.device_us - before.device_us) * 1e-6
    return dd < 0 or abs(dd - dh) > 0.01 * abs(dh) + 0.05


def best_round_trips(trips: Sequence[RoundTrip], keep: float = 0.5) -> list[RoundTrip]:
    """The ``keep`` fraction (at least 2, at most all) with the shortest round trips, in time order."""
    n = min(len(trips), max(2, math.ceil(keep * len(trips))))
    best = sorted(range(len(trips)), key=lambda i: trips[i].rtt)[:n]
    return [trips[i] for i in sorted(best)]


def fit_clock(trips: Sequence[RoundTrip]) -> tuple[ClockMapping, float]:
    """Fit host_mid = ref_host + (device_us - ref_device_us) * 1e-6 * (1 + drift * 1e-6).

    Weighted least squares, weight 1/rtt² (the midpoint of a round trip is off by at most half
    of it, so short round trips count most), then once more without samples whose residual is
    beyond 4 robust SDs (and beyond their own half round trip). Differences are taken from the
    first sample in integers before any float arithmetic, so 64-bit device counts and epoch
    host times keep their microseconds. ``ref_device_us`` is the weighted centre of the samples
    (where the offset is best known). Returns the mapping and the drift's standard error in ppm
    (``inf`` when it cannot be estimated).
    """
    if len(trips) < 2:
        raise ValueError("a clock fit needs at least 2 round trips")
    d0 = trips[0].device_us
    h0 = trips[0].host_mid
    xs = [(t.device_us - d0) * 1e-6 for t in trips]
    ys = [t.host_mid - h0 for t in trips]
    rtts = [max(t.rtt, 1e-7) for t in trips]
    use = [True] * len(trips)

    def solve(mask):
        w = [1.0 / r ** 2 if u else 0.0 for r, u in zip(rtts, mask)]
        sw = sum(w)
        xm = sum(wi * x for wi, x in zip(w, xs)) / sw
        ym = sum(wi * y for wi, y in zip(w, ys)) / sw
        sxx = sum(wi * (x - xm) ** 2 for wi, x in zip(w, xs))
        if sxx <= 0 or sum(mask) < 2:
            b = 1.0  # one device time only: offset alone, no drift
        else:
            b = sum(wi * (x - xm) * (y - ym) for wi, x, y in zip(w, xs, ys)) / sxx
        res = [y - (ym + b * (x - xm)) for x, y in zip(xs, ys)]
        return w, sw, xm, ym, sxx, b, res

    w, sw, xm, ym, sxx, b, res = solve(use)
    if len(trips) >= 6:
        kept = sorted(abs(r) for r in res)
        sigma = 1.4826 * kept[len(kept) // 2]
        mask = [abs(r) <= max(4 * sigma, rt / 2) for r, rt in zip(res, rtts)]
        if sum(mask) >= 3 and not all(mask):
            use = mask
            w, sw, xm, ym, sxx, b, res = solve(use)

    n = sum(use)
    ref_device_us = d0 + round(xm * 1e6)
    x_ref = (ref_device_us - d0) * 1e-6
    ref_host = h0 + ym + b * (x_ref - xm)
    used_res = [r for r, u in zip(res, use) if u]
    residual = math.sqrt(sum(r * r for r in used_res) / n)
    if sxx > 0 and n > 2:
        chi = sum(wi * r * r for wi, r in zip(w, res)) / (n - 2)
        drift_se = math.sqrt(chi / sxx) * 1e6
    else:
        drift_se = math.inf
    mapping = ClockMapping(ref_host=ref_host, ref_device_us=ref_device_us, drift_ppm=(b - 1.0) * 1e6,
                           residual_s=residual,
                           uncertainty_s=min(r for r, u in zip(rtts, use) if u) / 2, samples=n)
    return mapping, drift_se
