"""Our trigger box (ATmega328P firmware in ``firmware/``) over its USB serial line.

The wire protocol (its command table, ranges, refusals and reply parsers) is in
:mod:`vts_hw.drivers.trigger_box_protocol`; the clock fit over ``TIME?`` round trips in
:mod:`vts_hw.drivers.trigger_box_clock`; this module is the driver.

Everything goes through one primitive, :meth:`TriggerBox.query`: clear stale input, write the
line, read one line within the timeout, log both to ``trigger.csv``. A refusal raises
:class:`BoxRefused` (a :class:`~vts_hw.drivers.trigger.TriggerError`) with the box's own code and
message; no answer raises TriggerError naming the port and the command; a port that vanished
(USB unplugged, emulator gone) raises :class:`BoxGone` and every later call does the same.

Settable values are declared once (:class:`BoxSetting`, PyMeasure style) with a validator that
refuses a bad value before a byte is sent. The box has fixed TTL levels, so it does not have the
LEVELS capability. The box's clock can be mapped to host time (:meth:`TriggerBox.clock_mapping`,
a fit over ``TIME?`` round trips weighted towards the shortest), and the edge times the box
reports are logged in host time through that mapping (docs/decisions/0011). What it starts
and stops goes into ``trigger.csv`` as neutral rows too (docs/trigger-log-format.md).
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import serial
from pydantic import Field, field_validator

from vts_hw.drivers.settings import in_range, whole_in_range
from vts_hw.drivers.trigger import (
    CLOCK,
    DUTY,
    EDGES,
    FIRE,
    FREQUENCY,
    LEVELS,
    PULSE,
    WATCHDOG,
    BackendSettings,
    ClockMapping,
    OutOfRange,
    TriggerBackend,
    TriggerBase,
    TriggerError,
    TriggerLog,
    TriggerStatus,
)

# re-exported: the box's clock mapping and wire protocol, as they were importable from here
from vts_hw.drivers.trigger_box_clock import (  # noqa: F401
    MAX_ROUND_TRIPS_KEPT,
    BoxClock,
    RoundTrip,
    best_round_trips,
    clock_jumped,
    fit_clock,
    wire_skew,
    wire_time,
)
from vts_hw.drivers.trigger_box_protocol import (  # noqa: F401
    BAUDRATE,
    DEVICE,
    DUTY_ABS_TOLERANCE,
    DUTY_MAX,
    DUTY_MIN,
    FREQ_MAX_HZ,
    FREQ_MIN_HZ,
    FREQ_REL_TOLERANCE,
    MAX_ERRORS_READ,
    MAX_LINE,
    MODEL,
    POLL_S,
    PULSE_MS_MAX,
    PULSE_MS_MIN,
    SETTINGS_CONFLICT,
    VENDOR,
    WATCHDOG_DEFAULT_S,
    BoxGone,
    BoxIdentity,
    BoxRefused,
    BoxSetting,
    _pulse_ms,
    number_text,
    parse_refusal,
    watchdog_seconds,
)
from vts_hw.drivers.trigger_box_watchdog import BoxWatchdog
from vts_hw.recording.trigger_log import DEVICE_CLOCK_MAPPED, HOST_WRITE

#: the levels of the box's TTL outputs, as the neutral log rows state them
HIGH_V, LOW_V = 5.0, 0.0

# ---- the driver -----------------------------------------------------------------------------------


class TriggerBox(BoxClock, BoxWatchdog, TriggerBase):
    """The trigger box on a serial port, as a :class:`~vts_hw.drivers.trigger.TriggerGenerator`."""

    capabilities = frozenset({FREQUENCY, DUTY, PULSE, FIRE, CLOCK, EDGES, WATCHDOG})

    frequency_hz = BoxSetting(
        "FREQ {}",
        "FREQ?",
        in_range(FREQ_MIN_HZ, FREQ_MAX_HZ, "frequency", "Hz", DEVICE),
        doc="square-wave frequency in Hz; reads back what the timer makes",
    )
    duty = BoxSetting(
        "DUTY {}",
        "DUTY?",
        in_range(DUTY_MIN, DUTY_MAX, "duty cycle", "", DEVICE),
        doc="square-wave duty cycle, a fraction",
    )
    fire_pulse_ms = BoxSetting(
        "PULSE:WIDTH {}",
        "PULSE:WIDTH?",
        whole_in_range(PULSE_MS_MIN, PULSE_MS_MAX, "start pulse width", "ms"),
        fmt=str,
        parse=int,
        doc="width of the start pulses *TRG sends",
    )

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = BAUDRATE,
        timeout: float = 1.0,
        log: TriggerLog | None = None,
        name: str = "triggerbox",
        clock=time.time,
        serial_factory: Callable[..., Any] = serial.serial_for_url,
        sleep: Callable[[float], None] = time.sleep,
        watchdog_s: float = WATCHDOG_DEFAULT_S,
        heartbeat: bool = True,
        monotonic: Callable[[], float] = time.monotonic,
    ):
        """Open ``port`` (a device path or any pyserial URL). Nothing is sent until asked.

        ``clock`` stamps the log and the clock-mapping round trips (host epoch seconds);
        ``serial_factory(port, baudrate=, timeout=, write_timeout=)`` opens the line (the
        protocol tests pass a scripted fake); ``sleep`` paces clock-mapping samples.
        ``watchdog_s``, ``heartbeat``, ``monotonic``: the box's watchdog time set at every start and
        the heartbeat thread that feeds it (:class:`~vts_hw.drivers.trigger_box_watchdog.BoxWatchdog`).
        """
        self._init_watchdog(watchdog_s, heartbeat, monotonic)  # a bad watchdog time: before the port
        super().__init__(name, log)
        self.port = port
        self.baudrate = baudrate
        self.timeout = timeout
        self.clock = clock
        self.sleep = sleep
        self.identity: BoxIdentity | None = None
        self.mapping: ClockMapping | None = None
        self.drift_se_ppm: float | None = None  # the standard error of mapping.drift_ppm
        self._lock = threading.RLock()
        self._gone: str | None = None  # the reason, once the port has vanished
        self._closed = False
        self._batches: list[list[RoundTrip]] = []  # kept TIME? round trips, per clock_mapping call
        self._logged_edges: tuple[int | None, int | None] = (None, None)
        self._reported: deque[int] = deque()  # codes raised as BoxRefused, still in the box's queue
        self._wave: tuple[float, float, str, float | None] | None = None  # start host, period, time, ±
        self._wave_first_us: int | None = None  # the device time of that start's first edge
        try:
            self._serial = serial_factory(port, baudrate=baudrate, timeout=timeout, write_timeout=timeout)
        except (serial.SerialException, OSError, ValueError) as e:
            raise TriggerError(f"cannot open the trigger box on {port}: {e}") from e
        self._log("event", f"open {port} {baudrate} baud")

    def _log(self, kind: str, text: str, device_us: int | None = None, host_time: float | None = None) -> None:
        """A trigger.csv line, stamped with this driver's clock unless a host time is given."""
        self.log.write(
            self.name, kind, text, device_us=device_us, host_time=self.clock() if host_time is None else host_time
        )

    @property
    def where(self) -> str:
        """How messages name this device: ``trigger box on /dev/ttyACM0``."""
        if self.name == "triggerbox":
            return f"trigger box on {self.port}"
        return f"trigger box {self.name!r} on {self.port}"

    def __repr__(self) -> str:
        state = "gone" if self._gone else "closed" if self._closed else "open"
        who = (
            f", {self.identity.model} serial {self.identity.serial} firmware {self.identity.firmware}"
            if self.identity
            else ""
        )
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
                self._last_sent = self.monotonic()
                raw = ser.read_until(b"\n", MAX_LINE)
                received = self.clock()
            except serial.SerialTimeoutException as e:  # a write that the line never took
                self._log("cmd", cmd)
                raise TriggerError(f"{self.where} did not take {cmd!r} within {self.timeout:g} s ({e})") from e
            except (serial.SerialException, OSError) as e:
                self._log("cmd", cmd)
                raise self._vanished(cmd, e) from e
            self._log("cmd", cmd, host_time=sent)
            if not raw.endswith(b"\n"):
                if raw:
                    self._log(
                        "event",
                        f"partial reply to {cmd} without end of line: {raw.decode('ascii', 'replace')!r}",
                        host_time=received,
                    )
                    if len(raw) >= MAX_LINE:
                        raise TriggerError(
                            f"{self.where} answered {cmd!r} with {len(raw)} bytes and no end of line: {raw[:40]!r}..."
                        )
                raise TriggerError(
                    f"{self.where} did not answer {cmd!r} within {self.timeout:g} s"
                    + (f" (only {raw.decode('ascii', 'replace')!r} came)" if raw else "")
                )
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
        code, message = parse_refusal(reply)
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

    def _command_timed(self, cmd: str) -> tuple[float, float]:
        """A command whose only good answer is ``OK``: (host time just before the write, host
        time the reply was complete)."""
        reply, sent, received = self._exchange(cmd)
        if reply != "OK":
            raise TriggerError(f"{self.where} answered {cmd!r} with {reply!r}, not OK")
        return sent, received

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
            raise TriggerError(
                f"{self.where} answers *IDN? with {raw!r}, not "
                f"'{VENDOR},{MODEL},<serial>,<firmware>': is it a trigger box?"
            )
        self.identity = BoxIdentity(parts[0], parts[1], parts[2], parts[3], raw=raw)
        return self.identity

    def reset(self) -> None:
        """``*RST``: defaults restored; returns once the output is off (a running wave first
        finishes its period, up to 10 s at 0.1 Hz). The box's clock keeps running."""
        with self._lock:
            sent, received = self._command_timed("*RST")
            self._wait_off("*RST", 1.0 / FREQ_MIN_HZ)
            self._stop_heartbeat()  # the watchdog is back at the box's default, its trip forgotten
            if self._wave is not None:  # *RST ended it on a whole period; the count is reset too
                self._wave_stopped("*RST", sent, None)
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
                raise TriggerError(
                    f"{self.where} still reports its output ON {period_s:g} s (one period) after {what!r}"
                )
            self.sleep(POLL_S)

    # -- the trigger contract ---------------------------------------------------------------------------

    def configure(
        self, frequency_hz: float, duty: float = 0.5, high_v: float | None = None, low_v: float | None = None
    ) -> TriggerStatus:
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
        self._check_watchdog(st)
        if st.frequency_hz is None or not math.isclose(st.frequency_hz, f, rel_tol=FREQ_REL_TOLERANCE):
            raise TriggerError(f"{self.where} was asked for {f:g} Hz but confirms {st.frequency_hz!r} Hz")
        if st.duty is None or abs(st.duty - d) > DUTY_ABS_TOLERANCE:
            raise TriggerError(f"{self.where} was asked for duty {d:g} but confirms {st.duty!r}")
        return st

    def start(self) -> TriggerStatus:
        """``WDOG`` (:attr:`watchdog_s`), then ``OUTP ON``: the square wave alone, from a rising edge.
        Returns the box's status; while the output is on, the heartbeat keeps the watchdog fed."""
        with self._lock:
            self._set_watchdog()
            sent, received = self._command_timed("OUTP ON")
            st = self.status()
            self._wave_started("OUTP ON", sent, received, st, start_pulse=False)
            self._start_heartbeat(st)
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
            sent, _ = self._command_timed("OUTP OFF")
            st = self.status()
            if st.running and wait:
                self._wait_off("OUTP OFF", 1.0 / (st.frequency_hz or FREQ_MIN_HZ))
                st = self.status()
                if st.running:  # pragma: no cover - it said OFF a moment ago
                    raise TriggerError(f"{self.where} was switched off but reports its output ON")
            if not st.running:  # (still finishing its period: the heartbeat goes on until off)
                self._stop_heartbeat()
            self._wave_stopped("OUTP OFF", sent, st)
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
        is 100 ms and *RST restores it); then ``WDOG`` as in :meth:`start`."""
        self.require(FIRE)
        with self._lock:
            if pulse_ms is not None:
                self.fire_pulse_ms = pulse_ms
            self._set_watchdog()
            sent, received = self._command_timed("*TRG")
            st = self.status()
            self._wave_started("*TRG", sent, received, st, start_pulse=True)
            self._start_heartbeat(st)
        if not st.running:
            raise TriggerError(f"{self.where} was fired but reports its output OFF")
        return st

    def status(self) -> TriggerStatus:
        """``OUTP?``, ``FREQ?``, ``DUTY?``, ``EDGES?``, ``WDOG?`` (and ``TIME?`` after a watchdog
        cut, to say how long ago) and the error queue (read empty)."""
        with self._lock:
            running = self._output_on()
            f = self.frequency_hz
            d = self.duty
            n, first, last = self.edges()
            watchdog, said = self._status_watchdog()
            errors = self.read_errors()
        extra: dict[str, Any] = {"port": self.port, "watchdog": watchdog}
        if self.identity is not None:
            extra["idn"] = self.identity.raw
        if self.mapping is not None and n:
            extra["first_edge_host"] = self.mapping.to_host(first)
            extra["last_edge_host"] = self.mapping.to_host(last)
        return TriggerStatus(
            device=self.name,
            running=running,
            frequency_hz=f,
            duty=d,
            edges=n,
            first_edge_device_us=first if n else None,
            last_edge_device_us=last if n else None,
            errors=errors,
            extra=extra,
            notes=(said,),
        )

    def read_errors(self) -> tuple[str, ...]:
        """``SYST:ERR?`` until ``0,...``; the errors read before it, as the box wrote them.

        The box also queues every error it answered with ``ERR``; those were raised already
        (BoxRefused), so they are logged and left out here, and what is returned is news.
        """
        errors: list[str] = []
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
        raise TriggerError(
            f"{self.where} still reports errors after {MAX_ERRORS_READ} reads of SYST:ERR?: {'; '.join(errors[:3])} ..."
        )

    # -- the neutral rows of trigger.csv (docs/trigger-log-format.md) ---------------------------------

    def _wave_started(self, cmd: str, sent: float, received: float, st: TriggerStatus, start_pulse: bool) -> None:
        """``wave_start``: the first edge through the clock mapping when there is one, else the
        host time the command was sent plus its time on the wire (± until its reply came)."""
        if not st.running:
            return
        wrong = st.not_a_square_wave()
        if wrong or (frequency := st.frequency_hz) is None or (duty := st.duty) is None:  # nothing to time by
            raise TriggerError(f"{self.where} answered {cmd!r} but confirms {wrong}: not a square wave")
        period, first, m = 1.0 / frequency, st.first_edge_device_us, self.mapping
        if m is not None and first is not None:
            host, how, unc = m.to_host(first), DEVICE_CLOCK_MAPPED, m.uncertainty_s
        else:
            host = sent + (len(cmd) + 1) * 10 / (self._wire_baud() or BAUDRATE)
            how, unc = HOST_WRITE, received - sent
        self._wave = (host, period, how, unc)
        self._wave_first_us = first
        self.log.wave_started(
            self.name,
            host,
            period_s=period,
            duty=duty,
            high_v=HIGH_V,
            low_v=LOW_V,
            start_pulse=start_pulse,
            time_source=how,
            uncertainty_s=unc,
            device_us=first,
        )

    def _wave_stopped(self, cmd: str, sent: float, st: TriggerStatus | None) -> None:
        """``wave_stop``: the box ends on a whole period, so the rising edges it counted (once it
        reports its output off; while the last period runs, at least the periods begun before
        the command) place the end at start + n periods. A wave the box's watchdog cut has had its
        row written at the cut (:meth:`_watchdog_cut`)."""
        if st is not None and (st.extra.get("watchdog") or {}).get("state") == "tripped":
            self._wave = None
            return
        n = st.edges if st is not None else None
        if self._wave is not None:
            start, period, how, unc = self._wave
            if st is None or n is None or st.running:  # (no status: no count either)
                n = max(n or 0, math.ceil((sent - start) / period - 1e-9))
            host = start + n * period
        elif st is not None and st.frequency_hz and st.last_edge_device_us is not None:
            period = 1.0 / st.frequency_hz  # started by another program: end of the last period
            m = self.mapping
            host = (m.to_host(st.last_edge_device_us) if m else sent) + period
            how, unc = (DEVICE_CLOCK_MAPPED, m.uncertainty_s) if m else (HOST_WRITE, period)
        else:
            return
        self._wave = None
        self.log.wave_stopped(self.name, host, rising_edges=n, time_source=how, uncertainty_s=unc)

    # -- closing ---------------------------------------------------------------------------------------

    def close(self) -> None:
        """Close the port (the box keeps doing what it was doing) and the log."""
        self._stop_heartbeat()  # the output stays as it is; the box's watchdog (if set) ends it
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


# ---- the backend (vts_hw.drivers.registry.TRIGGER_BACKENDS["triggerbox"]) -------------------------------


class BoxSettings(BackendSettings):
    """The trigger box's own keys in rig.yaml's ``trigger:`` section (``address``: its serial
    port or a pyserial URL)."""

    timeout_s: float = Field(default=1.0, gt=0, le=60, description="how long to wait for each reply")
    watchdog_s: float = Field(
        default=WATCHDOG_DEFAULT_S,
        description=(
            "the box switches its output off this long after the last command it heard from us "
            "(0 = off, else 0.1 to 3600 s)"
        ),
    )

    @field_validator("watchdog_s", mode="before")
    @classmethod
    def _watchdog(cls, v: Any) -> float:
        return watchdog_seconds(v)  # the raw value: `watchdog_s: yes` is not 1 s


def _open_box(cfg, settings: BoxSettings, log: TriggerLog) -> TriggerBox:
    return TriggerBox(cfg.address, timeout=settings.timeout_s, log=log, watchdog_s=settings.watchdog_s)


BACKEND = TriggerBackend("triggerbox", "our trigger box on a serial line", BoxSettings, _open_box)
