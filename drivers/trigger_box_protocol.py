"""The trigger box's wire protocol: its ranges, its refusals, how numbers go out, what it reports.

What :class:`~vts_hw.drivers.trigger_box.TriggerBox` speaks: 115200 baud 8N1, one ASCII
command per line, one reply line per command, lines end in ``\\n`` (docs/design.md, "Trigger
box (our own firmware, serial)"; firmware/trigger_box/commands.h):

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
    WDOG <s>     WDOG?     OK / <s>,<OFF|IDLE|ARMED|TRIPPED>,<device us of the cut, 0 if none>
                                             (the host watchdog, 0.1..3600 s or 0 = off; 10 s
                                              at power-up and after *RST)
    SYST:ERR?              <code>,"<message>" or 0,"No error"
    anything refused       ERR <code> <message>  (nothing changes; the error is queued too)

The host watchdog (firmware 1.1.0, docs/decisions/0083): every line naming a command is the
host's heartbeat; while the output is on and none came for the watchdog time, the box cuts the
wave (output low at once), queues -310 and reports TRIPPED until the next start or *RST.

Here: constants of the firmware, the errors a reply can mean, the declared-setting type whose numbers the box's fixed-point
parser takes, and the parsers of its replies (``*IDN?``, ``WDOG?``, ``ERR <code> <message>``,
unsigned counts of any size). No I/O here.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from vts_hw.drivers.settings import Setting, whole_in_range
from vts_hw.drivers.trigger import OutOfRange, TriggerError

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
MAX_LINE = 256  # bytes; a longer "line" is noise, not a reply
MAX_ERRORS_READ = 16  # more than the firmware's error queue holds
POLL_S = 0.01  # while waiting for the last period to finish
SETTINGS_CONFLICT = -221  # the box's code for "not while the wave is on / a pulse runs"
WATCHDOG_CUT = -310  # the box's code for "Watchdog: host silent, output off"
UNDEFINED_HEADER = -113  # the box's code for a command it does not know (WDOG before 1.1.0)
WATCHDOG_MIN_S = 0.1  # the host watchdog's range (0 = off)
WATCHDOG_MAX_S = 3600.0
WATCHDOG_DEFAULT_S = 10.0  # the box's own default, and the driver's
WATCHDOG_STATES = ("OFF", "IDLE", "ARMED", "TRIPPED")


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
class WatchdogState:
    """``WDOG?`` parsed: the watchdog time (0 = off), its state and the device time of the cut."""

    seconds: float
    state: str  # off, idle (output off), armed (output on), tripped (the last run was cut)
    cut_device_us: int | None  # when the box cut the wave (tripped only)

    def describe(self, now_device_us: int | None = None) -> str:
        """One line for a person: what the watchdog does now, or what it did."""
        t = f"{self.seconds:g} s"
        if self.state == "tripped":
            ago = ""
            if now_device_us is not None and self.cut_device_us is not None and now_device_us >= self.cut_device_us:
                ago = f", {(now_device_us - self.cut_device_us) * 1e-6:.1f} s ago"
            at = f" at device time {self.cut_device_us * 1e-6:.6f} s" if self.cut_device_us is not None else ""
            return (
                f"watchdog TRIPPED: the box heard nothing from its host for {t} and cut the square wave "
                f"(output off){at}{ago}"
            )
        if self.state == "off":
            return (
                "watchdog off: the box keeps its output as it is whatever happens to its host "
                "(vts trigger stop switches it off)"
            )
        if self.state == "armed":
            return f"watchdog {t}: the box switches its output off {t} after the last command it hears"
        return f"watchdog {t} (armed while the output is on)"


def parse_watchdog(reply: str) -> WatchdogState:
    """``<seconds>,<OFF|IDLE|ARMED|TRIPPED>,<device us>`` -> WatchdogState; ValueError if not."""
    parts = [p.strip() for p in reply.split(",")]
    if len(parts) != 3 or parts[1] not in WATCHDOG_STATES:
        raise ValueError(reply)
    seconds = float(parts[0])
    if not 0 <= seconds <= WATCHDOG_MAX_S:
        raise ValueError(reply)
    cut = uint(parts[2])
    state = parts[1].lower()
    return WatchdogState(seconds, state, cut if state == "tripped" else None)


def watchdog_seconds(value) -> float:
    """The watchdog time a driver may ask for: 0 (off) or 0.1..3600 s; OutOfRange otherwise."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or not (value == 0 or WATCHDOG_MIN_S <= value <= WATCHDOG_MAX_S)
    ):
        raise OutOfRange(
            f"the trigger box's watchdog time must be 0 (off) or {WATCHDOG_MIN_S:g} to "
            f"{WATCHDOG_MAX_S:g} s, not {value!r}"
        )
    return float(value)


def uint(text: str) -> int:
    """A non-negative decimal integer of any size (the box's counters are 64-bit)."""
    if not text.isdigit():
        raise ValueError(text)
    return int(text)


def parse_refusal(reply: str) -> tuple[int | None, str]:
    """``ERR <code> <message>`` -> (code, message); (None, the text) when it has no code."""
    m = re.match(r"ERR\s+(-?\d+)\s*(.*)$", reply)
    return (int(m.group(1)), m.group(2).strip()) if m else (None, reply[3:].strip())
