"""Keysight (Agilent) 33500-series function generator over VISA: the square wave for the SPECT gating input.

One :class:`FunctionGenerator` per instrument channel, speaking a small SCPI subset through
pyvisa (docs/design.md, "Function generator (VISA, SCPI)"):

    *IDN?  *RST  SYST:ERR?
    FUNC SQU              FUNC?
    FREQ <hz>             FREQ?
    FUNC:SQU:DCYC <pct>   FUNC:SQU:DCYC?
    VOLT:HIGH <v>         VOLT:HIGH?
    VOLT:LOW <v>          VOLT:LOW?
    OUTP 1|0              OUTP?

(channel 2 prefixes ``SOUR2:`` and uses ``OUTP2``). Each setting is declared once as a
:class:`Setting` with its command, its query and a validator; a value outside the instrument's
range raises :class:`OutOfRange` before anything is sent. After every setting the error queue
is read (``SYST:ERR?`` until ``+0,"No error"``) and an instrument-side refusal raises
:class:`~vts_hw.drivers.trigger.TriggerError` with the instrument's own message. Every command
and reply goes to the session's ``trigger.csv``.

A 33500 has no contact-closure outputs and no clock that times its output, so this backend
can do FREQUENCY, DUTY and LEVELS only: :meth:`pulse`, :meth:`fire` and :meth:`clock_mapping`
raise :class:`~vts_hw.drivers.trigger.Unsupported` and say what to use instead.

A real 33500 is reached on the LAN as ``TCPIP::HOST::5025::SOCKET`` (or ``TCPIP::HOST::INSTR``),
the simulated rig's as ``TCPIP::127.0.0.1::PORT::SOCKET`` (``vts_hw.sim_devices.scpi_server``),
both through pyvisa's default VISA (pyvisa-py where no IVI VISA is installed); opening and VISA
failures (refused, timed out, connection lost) are one-sentence TriggerErrors naming the resource
(:mod:`.visa`). ``sim=True`` talks to the pyvisa-sim model shipped as
``vts_hw/sim_devices/keysight_33500.yaml`` instead, for the unit tests; each instance gets a
freshly parsed simulated device (docs/decisions/0010, 0021).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from typing import Any, Literal

from pydantic import Field

from vts_hw.drivers.settings import Setting, in_range
from vts_hw.drivers.trigger import (
    CLOCK,
    DUTY,
    FIRE,
    FREQUENCY,
    LEVELS,
    PULSE,
    BackendSettings,
    ClockMapping,
    OutOfRange,
    TriggerBackend,
    TriggerBase,
    TriggerError,
    TriggerLog,
    TriggerStatus,
)
from vts_hw.drivers.visa import is_visa_error, open_message_resource, query_within, sim_yaml_path, visa_failure
from vts_hw.recording.trigger_log import HOST_WRITE

__all__ = ["FunctionGenerator", "OutOfRange", "SIM_RESOURCE", "sim_yaml_path", "scpi_number"]

DEVICE = "the instrument"
#: an address the simulated generator answers on (pyvisa-sim opens no socket)
SIM_RESOURCE = "TCPIP0::127.0.0.1::inst0::INSTR"

# The instrument's ranges (33500B family, square wave, output termination 50 ohm = *RST default).
FREQ_MIN_HZ = 1e-6  # 1 uHz on every 33500 model
FREQ_MAX_HZ = 20e6  # square wave on the 20 MHz models; the 30 MHz models go further
DUTY_MIN_PCT = 0.01  # square duty cycle at low frequencies ...
DUTY_MAX_PCT = 99.99
MIN_PULSE_S = 16e-9  # ... narrowed at high frequency by the 16 ns minimum pulse width
LEVEL_LIMIT_V = 5.0  # |VOLT:HIGH|, |VOLT:LOW| into the 50 ohm setting (10 V with LOAD INF)
MIN_AMPLITUDE_V = 1e-3  # VOLT:HIGH - VOLT:LOW, 1 mVpp into 50 ohm
FUNCTIONS = ("SIN", "SQU", "TRI", "RAMP", "PULS", "PRBS", "NOIS", "ARB", "DC")
MAX_ERRORS_READ = 32  # more than the instrument's error queue holds

# what a confirmed value may differ from the asked one by (instrument resolution)
_TOLERANCE = {"frequency_hz": (1e-9, 1e-6), "duty_percent": (0.0, 1e-3), "high_v": (0.0, 1e-3), "low_v": (0.0, 1e-3)}

_MODEL = re.compile(r"^335\d\d[AB]$")
_NO_PULSE = (
    "a Keysight 33500 has no contact-closure outputs; send the start pulses from the "
    "trigger box or an NI-DAQmx digital line (backend daqmx)"
)


# ---- declared settings (PyMeasure-style) -------------------------------------------------------


def one_of(*choices: str, what: str) -> Callable[[Any], str]:
    def check(value: Any) -> str:
        if not isinstance(value, str) or value.upper() not in choices:
            raise OutOfRange(f"{what} must be one of {', '.join(choices)}, not {value!r}")
        return value.upper()

    check.__doc__ = f"{what}: one of {', '.join(choices)}"
    return check


def boolean(value: Any) -> bool:
    """on/off: True or False (1 or 0)"""
    if value not in (True, False):  # 1 and 0 compare equal to True and False
        raise OutOfRange(f"output state must be True or False, not {value!r}")
    return bool(value)


def scpi_number(value: float) -> str:
    """The shortest text that reads back as the same float: 1 -> '1', 1e-06 -> '1E-06'."""
    text = repr(float(value))
    if text.endswith(".0"):
        text = text[:-2]
    return text.upper()


def _scpi_bool(value: bool) -> str:
    return "1" if value else "0"


def _parse_bool(reply: str) -> bool:
    if reply in ("1", "ON"):
        return True
    if reply in ("0", "OFF"):
        return False
    raise ValueError(reply)


class ScpiSetting(Setting):
    """A setting of the instrument. ``{src}`` in a command becomes ``SOUR2:`` on channel 2,
    ``{ch}`` becomes ``2``; numbers go out in their shortest exact form."""

    default_fmt = staticmethod(scpi_number)


# ---- the driver ----------------------------------------------------------------------------------


class FunctionGenerator(TriggerBase):
    """A Keysight/Agilent 33500-series channel as the square-wave source of the trigger contract."""

    capabilities = frozenset({FREQUENCY, DUTY, LEVELS})

    function = ScpiSetting(
        "{src}FUNC {value}", "{src}FUNC?", one_of(*FUNCTIONS, what="function"), parse=str, fmt=str, doc="waveform"
    )
    frequency_hz = ScpiSetting(
        "{src}FREQ {value}",
        "{src}FREQ?",
        in_range(FREQ_MIN_HZ, FREQ_MAX_HZ, "frequency", "Hz", DEVICE),
        doc="frequency in Hz",
    )
    duty_percent = ScpiSetting(
        "{src}FUNC:SQU:DCYC {value}",
        "{src}FUNC:SQU:DCYC?",
        in_range(DUTY_MIN_PCT, DUTY_MAX_PCT, "square duty cycle", "%", DEVICE),
        doc="square-wave duty cycle in percent",
    )
    high_v = ScpiSetting(
        "{src}VOLT:HIGH {value}",
        "{src}VOLT:HIGH?",
        in_range(-LEVEL_LIMIT_V, LEVEL_LIMIT_V, "high level", "V", DEVICE),
        doc="high level in volts (as the instrument's 50 ohm termination setting states it)",
    )
    low_v = ScpiSetting(
        "{src}VOLT:LOW {value}",
        "{src}VOLT:LOW?",
        in_range(-LEVEL_LIMIT_V, LEVEL_LIMIT_V, "low level", "V", DEVICE),
        doc="low level in volts (as the instrument's 50 ohm termination setting states it)",
    )
    output = ScpiSetting("OUTP{ch} {value}", "OUTP{ch}?", boolean, parse=_parse_bool, fmt=_scpi_bool, doc="output on")

    def __init__(
        self,
        resource: str | Any,
        *,
        sim: bool = False,
        visa_library: str | None = None,
        log: TriggerLog | None = None,
        name: str = "fgen",
        timeout_ms: int = 2000,
        channel: int = 1,
    ):
        """Open ``resource`` (a VISA address) and identify the instrument.

        ``sim=True`` uses the shipped pyvisa-sim model (a fresh simulated device per instance);
        ``visa_library`` picks another VISA backend (``"@py"``, ``"path/to/model.yaml@sim"``);
        neither means pyvisa's default. ``resource`` may also be an already open pyvisa-like
        resource (``write``/``query``/``close``), as the protocol tests do.
        """
        super().__init__(name, log)
        if channel not in (1, 2):
            raise ValueError(f"a 33500 has channel 1 or 2, not {channel!r}")
        if sim and visa_library:
            raise ValueError("give sim=True or visa_library, not both")
        self.channel = channel
        self._src = "" if channel == 1 else f"SOUR{channel}:"
        self._ch = "" if channel == 1 else str(channel)
        self._known: dict[str, Any] = {}  # last values the instrument confirmed or accepted
        self._started: float | None = None  # host time this instance switched the output on
        self._closed = False
        self.idn = ""
        self.stale_errors: tuple[str, ...] = ()
        if isinstance(resource, str):
            library = f"{sim_yaml_path()}@sim" if sim else (visa_library or "")
            self.address = resource
            self.resource = open_message_resource(resource, library, timeout_ms, name)
            self.log.write(name, "event", f"open {resource} ({'simulated' if sim else library or 'default VISA'})")
        else:
            self.address = str(getattr(resource, "resource_name", type(resource).__name__))
            self.resource = resource
        try:
            self._identify()
        except BaseException:
            self._close_resource()
            raise

    def __repr__(self) -> str:
        return f"<FunctionGenerator {self.name} {self.address} channel {self.channel}>"

    # -- the trigger contract --------------------------------------------------------------------

    def configure(
        self, frequency_hz: float, duty: float = 0.5, high_v: float | None = None, low_v: float | None = None
    ) -> TriggerStatus:
        """A square wave of ``frequency_hz`` and ``duty`` (a fraction), levels if given (both).

        Every value is checked before anything is sent; then FUNC SQU, FREQ, DCYC and the levels
        are set (each followed by SYST:ERR?) and the instrument's read-back is returned. A
        read-back that differs from what was asked raises TriggerError.
        """
        self.require(FREQUENCY)
        self.require(DUTY)
        if (high_v is None) != (low_v is None):
            raise OutOfRange(
                f"{self.name}: give both high_v and low_v, or neither "
                f"(got high_v={high_v!r}, low_v={low_v!r}); nothing was sent"
            )
        levels = high_v is not None
        if levels:
            self.require(LEVELS)
        try:
            duty_f = float(duty)
        except (TypeError, ValueError):
            raise OutOfRange(f"{self.name}: duty must be a fraction, not {duty!r}; nothing was sent") from None
        f = self._validate(FunctionGenerator.frequency_hz, frequency_hz)
        pct = self._validate(FunctionGenerator.duty_percent, round(duty_f * 100.0, 9), frequency_hz=f)
        asked = {"frequency_hz": f, "duty_percent": pct}
        if levels:
            hi = self._validate(FunctionGenerator.high_v, high_v, low_v=_finite_or_none(low_v))
            lo = self._validate(FunctionGenerator.low_v, low_v, high_v=hi)
            asked.update(high_v=hi, low_v=lo)

        self._apply_setting(FunctionGenerator.function, "SQU")
        self._apply_setting(FunctionGenerator.frequency_hz, f)
        self._apply_setting(FunctionGenerator.duty_percent, pct)
        if levels:
            # the instrument refuses a high below the present low (and a low above the present
            # high), so the order depends on where the levels are now
            if hi > self.low_v:
                self._apply_setting(FunctionGenerator.high_v, hi)
                self._apply_setting(FunctionGenerator.low_v, lo)
            else:
                self._apply_setting(FunctionGenerator.low_v, lo)
                self._apply_setting(FunctionGenerator.high_v, hi)

        st = self.status()
        self._raise_on_errors("configure", st.errors)
        if st.extra.get("function") != "SQU":
            raise TriggerError(f"{self.name} was set to a square wave but confirms {st.extra.get('function')!r}")
        got = {
            "frequency_hz": st.frequency_hz,
            "duty_percent": st.extra["duty_percent"],
            "high_v": st.high_v,
            "low_v": st.low_v,
        }
        for key, want in asked.items():
            rel, abs_ = _TOLERANCE[key]
            if got[key] is None or not math.isclose(got[key], want, rel_tol=rel, abs_tol=abs_):
                raise TriggerError(f"{self.name} was asked for {key} {want:g} but confirms {got[key]!r}")
        return st

    def start(self) -> TriggerStatus:
        """Output on (``OUTP 1``): the square wave alone. Refused unless the function is SQU."""
        fn = self.function
        if fn != "SQU":
            raise TriggerError(f"{self.name} is set to {fn}, not a square wave: call configure() first")
        sent = self.log.clock()
        self._write_setting(FunctionGenerator.output, True, host_time=sent)
        st = self.status()
        self._raise_on_errors("start", st.errors)
        if not st.running:
            raise TriggerError(f"{self.name} was switched on but reports its output off")
        wrong = st.not_a_square_wave()
        f, duty, high, low = st.frequency_hz, st.duty, st.high_v, st.low_v  # status() reads them all
        if wrong or f is None or duty is None or high is None or low is None:
            raise TriggerError(
                f"{self.name} was switched on but confirms {wrong or f'levels {low!r}..{high!r} V'}: not a square wave"
            )
        # a rising edge when the output switched on, between the write and the read-back
        self._started = sent
        self.log.wave_started(
            self.name,
            sent,
            period_s=1.0 / f,
            duty=duty,
            high_v=high,
            low_v=low,
            start_pulse=False,
            time_source=HOST_WRITE,
            uncertainty_s=self.log.clock() - sent,
        )
        return st

    def stop(self) -> TriggerStatus:
        """Output off (``OUTP 0``). The 33500 opens its output at once, not at the end of a period."""
        sent = self.log.clock()
        self._write_setting(FunctionGenerator.output, False, host_time=sent)
        self._log_stop(sent, always=True)
        st = self.status()
        self._raise_on_errors("stop", st.errors)
        if st.running:
            raise TriggerError(f"{self.name} was switched off but reports its output on")
        return st

    def _log_stop(self, sent: float, always: bool = False) -> None:
        """``wave_stop`` at the write that opened the output (it does so at once, mid-period if
        need be): on stop(), and on reset() when this instance started the wave or the
        instrument said its output was on (a stop with no start before it is ignored by readers)."""
        if always or self._started is not None or self._known.get("output"):
            self.log.wave_stopped(
                self.name, sent, rising_edges=None, time_source=HOST_WRITE, uncertainty_s=self.log.clock() - sent
            )
        self._started = None

    def pulse(self, channel: int, ms: int) -> None:
        self.require(PULSE, f"send a start pulse: {_NO_PULSE}")
        raise AssertionError("unreachable")  # pragma: no cover

    def fire(self) -> TriggerStatus:
        self.require(
            FIRE,
            f"start the square wave and the start pulses together: {_NO_PULSE}; nothing "
            f"was sent, so no start pulses went out and the square wave was not started "
            f"(the square wave alone: vts trigger start)",
        )
        raise AssertionError("unreachable")  # pragma: no cover

    def clock_mapping(self, samples: int = 20) -> ClockMapping:
        self.require(
            CLOCK,
            "report a device clock to map to host time: a 33500 has no clock "
            "readable over SCPI that times its output; time the edges from the "
            "SPECT list-mode gating signal instead",
        )
        raise AssertionError("unreachable")  # pragma: no cover

    def status(self) -> TriggerStatus:
        """What the instrument reports now: function, frequency, duty, levels, output, errors."""
        fn = self.function
        f = self.frequency_hz
        pct = self.duty_percent
        hi = self.high_v
        lo = self.low_v
        on = self.output
        errors = self._read_errors()
        return TriggerStatus(
            device=self.name,
            running=on,
            frequency_hz=f,
            duty=pct / 100.0,
            high_v=hi,
            low_v=lo,
            errors=errors,
            extra={"function": fn, "duty_percent": pct, "channel": self.channel, "idn": self.idn},
        )

    def reset(self) -> None:
        """``*RST``: the instrument's defaults (sine 1 kHz, output off). Not simulated by pyvisa-sim."""
        sent = self.log.clock()
        self._write("*RST", host_time=sent)
        self._log_stop(sent)
        self._known.clear()
        self._raise_on_errors("'*RST'", self._read_errors())

    def check_errors(self) -> None:
        """Read the error queue; raise TriggerError with the instrument's messages if any."""
        self._raise_on_errors("the last commands", self._read_errors())

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._close_resource()
            self.log.write(self.name, "event", "closed")
        super().close()

    # -- settings ----------------------------------------------------------------------------------

    def _validate(self, setting: Setting, value: Any, **context: Any) -> Any:
        """The value as it will be sent, or OutOfRange naming this device. Sends nothing.

        Cross-checks use ``context`` (values about to be set) and else the last values the
        instrument confirmed: the duty cycle against the 16 ns minimum pulse at the frequency,
        and high above low by at least 1 mV.
        """
        try:
            v = setting.validator(value)
            if setting is FunctionGenerator.duty_percent:
                f = context.get("frequency_hz", self._known.get("frequency_hz"))
                if f is not None:
                    low = max(DUTY_MIN_PCT, 100.0 * MIN_PULSE_S * f)
                    high = min(DUTY_MAX_PCT, 100.0 * (1.0 - MIN_PULSE_S * f))
                    if not low <= v <= high:
                        raise OutOfRange(
                            f"square duty cycle {v:g} % is outside the instrument's "
                            f"range {low:g} to {high:g} % at {f:g} Hz"
                        )
            elif setting is FunctionGenerator.high_v:
                lo = context["low_v"] if "low_v" in context else self._known.get("low_v")
                if lo is not None and v - lo < MIN_AMPLITUDE_V:
                    raise OutOfRange(
                        f"high level {v:g} V must be at least {MIN_AMPLITUDE_V * 1e3:g} mV above the low level {lo:g} V"
                    )
            elif setting is FunctionGenerator.low_v:
                hi = context["high_v"] if "high_v" in context else self._known.get("high_v")
                if hi is not None and hi - v < MIN_AMPLITUDE_V:
                    raise OutOfRange(
                        f"low level {v:g} V must be at least {MIN_AMPLITUDE_V * 1e3:g} mV below the high level {hi:g} V"
                    )
        except OutOfRange as e:
            raise OutOfRange(f"{self.name}: {e}; nothing was sent") from None
        return v

    def _write_setting(self, setting: Setting, value: Any, host_time: float | None = None) -> None:
        self._apply_setting(setting, self._validate(setting, value), host_time)

    def _apply_setting(self, setting: Setting, value: Any, host_time: float | None = None) -> None:
        command = self._scpi(setting.command, setting.fmt(value))
        self._write(command, host_time)
        self._raise_on_errors(repr(command), self._read_errors())
        self._known[setting.name] = value

    def _read_setting(self, setting: Setting) -> Any:
        query = self._scpi(setting.query)
        reply = self._query(query)
        try:
            value = setting.parse(reply)
        except ValueError:
            raise TriggerError(f"{self.name} answered {query!r} with {reply!r}, not a {setting.name} value") from None
        self._known[setting.name] = value
        return value

    def _scpi(self, template: str, value: str = "") -> str:
        return template.format(src=self._src, ch=self._ch, value=value)

    # -- the wire ----------------------------------------------------------------------------------

    def _write(self, command: str, host_time: float | None = None) -> None:
        self.log.write(self.name, "cmd", command, host_time=host_time)
        try:
            self.resource.write(command)
        except Exception as e:
            if is_visa_error(e):
                raise self._failure(e, command) from None
            raise

    def _query(self, command: str) -> str:
        self.log.write(self.name, "cmd", command)
        try:
            reply = query_within(self.resource, command).strip()  # one deadline for the reply
        except Exception as e:
            if is_visa_error(e) or isinstance(e, UnicodeDecodeError):
                raise self._failure(e, command) from None
            raise
        self.log.write(self.name, "reply", reply)
        return reply

    def _failure(self, e: BaseException, command: str) -> TriggerError:
        err = visa_failure(e, self.name, self.address, command, getattr(self.resource, "timeout", None))
        self.log.write(self.name, "event", str(err))
        return err

    def _read_errors(self) -> tuple[str, ...]:
        """SYST:ERR? until +0,"No error"; the messages read before it."""
        errors: list[str] = []
        for _ in range(MAX_ERRORS_READ):
            reply = self._query("SYST:ERR?")
            code, _, _message = reply.partition(",")
            try:
                n = int(code)
            except ValueError:
                raise TriggerError(f"{self.name} answered SYST:ERR? with {reply!r}") from None
            if n == 0:
                return tuple(errors)
            errors.append(reply)
        raise TriggerError(
            f"{self.name} still reports errors after {MAX_ERRORS_READ} reads of SYST:ERR?: {'; '.join(errors[:3])} ..."
        )

    def _raise_on_errors(self, what: str, errors: tuple[str, ...]) -> None:
        if errors:
            raise TriggerError(f"{self.name} refused {what}: {'; '.join(errors)}")

    def _identify(self) -> None:
        self.idn = self._query("*IDN?")
        parts = [p.strip() for p in self.idn.split(",")]
        model = parts[1] if len(parts) >= 2 else ""
        if not _MODEL.match(model):
            raise TriggerError(
                f"{self.name} at {self.address} answers *IDN? with {self.idn!r}, "
                f"not a Keysight/Agilent 33500-series generator"
            )
        if self.channel == 2 and model[4] != "2":  # 335x2: the two-channel models
            raise TriggerError(f"{self.name}: the {model} at {self.address} has one channel, not 2")
        self.model = model
        # errors left from before we connected are not ours: log them, keep them, go on
        self.stale_errors = self._read_errors()
        for err in self.stale_errors:
            self.log.write(self.name, "event", f"error left in the queue before connecting: {err}")

    def _close_resource(self) -> None:
        try:
            self.resource.close()
        except Exception:  # closing a dead connection must not hide the error that killed it
            pass


# ---- helpers -----------------------------------------------------------------------------------------


def _finite_or_none(value: Any) -> float | None:
    try:
        v = float(value)
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


# ---- the backend (vts_hw.drivers.registry.TRIGGER_BACKENDS["visa"]) -----------------------------------


class VisaSettings(BackendSettings):
    """The function generator's own keys in rig.yaml's ``trigger:`` section (``address``: its
    VISA resource, e.g. ``TCPIP::HOST::5025::SOCKET``)."""

    simulated: bool = Field(default=False, description="use the shipped pyvisa-sim instrument")
    channel: Literal[1, 2] = Field(default=1, description="the instrument's output channel")
    timeout_ms: int = Field(default=2000, ge=1, le=120_000, description="how long to wait for each reply")


def _open_visa(cfg, settings: VisaSettings, log) -> FunctionGenerator:
    return FunctionGenerator(
        cfg.address, sim=settings.simulated, log=log, channel=settings.channel, timeout_ms=settings.timeout_ms
    )


BACKEND = TriggerBackend("visa", "a SCPI function generator over VISA", VisaSettings, _open_visa, levels=True)
