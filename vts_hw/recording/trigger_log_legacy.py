"""Trigger logs written before the neutral rows existed, converted on read: the one place that
still reads a backend's wire text (docs/decisions/0032-neutral-trigger-log.md).

A log with no ``wave_start``/``wave_stop``/``clock`` row at all was written by the drivers
before docs/trigger-log-format.md's neutral rows. The two backends of that time are read from
their ``cmd``/``reply``/``edge``/``event`` rows, with the rules the analysis used then, and
turned into neutral rows:

* trigger box (our firmware): started by ``*TRG`` (with the start pulses) or ``OUTP ON``; the
  first edge's host time is the ``edge`` line the driver logged through its clock mapping, else
  the time the command was sent plus its time on the wire; ``OUTP OFF``/``*RST`` let it finish
  the period under way; the count of rising edges comes from the last ``EDGES?`` reply (or the
  periods begun before the stop, whichever is larger); levels 0/5 V; the drift from the last
  "clock mapping" event;
* SCPI function generator: ``OUTP 1`` starts the wave at the host time it was sent (logged just
  before), from a rising edge; ``OUTP 0`` ends it at once; ``FREQ``, ``FUNC:SQU:DCYC`` (percent)
  and ``VOLT:HIGH/LOW`` as last set or read back (the 33500's ``*RST`` levels ±50 mV when never
  set).

An NI-DAQmx log of that time cannot be converted (it logged no start in a form the analysis
read); :func:`~vts_hw.recording.trigger_wave.wave_from_trigger_log` then says no wave was started.
"""

from __future__ import annotations

import math
import re
from typing import Any

from vts_hw.recording.trigger_log import (
    CLOCK,
    DEVICE_CLOCK_MAPPED,
    HOST_WRITE,
    WAVE_START,
    WAVE_STOP,
    clock_text,
    finite_float,
    wave_start_text,
    wave_stop_text,
)

__all__ = ["neutral_rows"]

_FG_CMD = re.compile(r"^(?:SOUR\d:)?(FREQ|FUNC:SQU:DCYC|VOLT:HIGH|VOLT:LOW)\s+(\S+)$", re.I)
_FG_QUERY = re.compile(r"^(?:SOUR\d:)?(FREQ|FUNC:SQU:DCYC|VOLT:HIGH|VOLT:LOW)\?$", re.I)
_FG_OUTP = re.compile(r"^OUTP\d?\s+(1|0|ON|OFF)$", re.I)
_BOX_BYTE_S = 10 / 115200  # one 8N1 byte at 115200 baud
_DRIFT = re.compile(r"drift ([+-]?[\d.]+) ± (\S+) ppm")


def _is_box(rows: list[dict], dev: str | None) -> bool:
    """A trigger box (our firmware) rather than a SCPI function generator."""
    for row in rows:
        if row.get("device") != dev:
            continue
        text = (row.get("text") or "").strip().upper()
        if row.get("kind") == "reply" and text.startswith("VTS,TRIGGERBOX"):
            return True
        if row.get("kind") == "cmd" and (
            text in ("*TRG", "OUTP ON", "OUTP OFF", "EDGES?", "TIME?") or text.startswith(("PULSE", "DUTY"))
        ):
            return True
    return False


def _fg_set(st: dict[str, Any], key: str, text: str) -> None:
    v = finite_float(text)
    if v is None:
        return
    st[{"FREQ": "FREQ", "FUNC:SQU:DCYC": "DUTY", "VOLT:HIGH": "HIGH", "VOLT:LOW": "LOW"}[key]] = (
        v / 100.0 if key == "FUNC:SQU:DCYC" else v
    )


def _row(host: float, device: str | None, kind: str, text: str) -> dict:
    return {"host_time": repr(float(host)), "device_time_us": "", "device": device, "kind": kind, "text": text}


def neutral_rows(rows: list[dict]) -> list[dict]:
    """The neutral rows (``wave_start``, ``wave_stop``, ``clock``) an old log's wire text
    implies, in the order of the waves. ValueError when the last wave's frequency was never
    logged (an earlier one's is left out)."""
    devices = list(dict.fromkeys(r.get("device") for r in rows))
    box = {d: _is_box(rows, d) for d in devices}
    # (a row without a device, a short CSV line, is the device None's: as the log has it)
    settings: dict[str | None, dict[str, Any]] = {
        d: {"FREQ": None, "DUTY": 0.5, "HIGH": None, "LOW": None} for d in devices
    }
    last_cmd: dict[str | None, str] = {}
    waves: list[dict] = []
    current: dict[str | None, dict | None] = {d: None for d in devices}
    for row in rows:
        dev = row.get("device")
        h = finite_float(row.get("host_time"))
        if dev not in box or h is None:
            continue
        kind, text = row.get("kind"), (row.get("text") or "").strip()
        up = text.upper()
        st, w = settings[dev], current[dev]
        if kind == "cmd":
            last_cmd[dev] = up
            if box[dev]:
                key, _, value = up.partition(" ")
                if key in ("FREQ", "DUTY") and finite_float(value) is not None:
                    st[key] = finite_float(value)
                elif up in ("*TRG", "OUTP ON"):
                    w = current[dev] = {
                        "start": h + (len(text) + 1) * _BOX_BYTE_S,
                        "mapped": False,
                        "stop_cmd": None,
                        "n": None,
                        "pulse": up == "*TRG",
                        "set": dict(st),
                        "device": dev,
                    }
                    waves.append(w)
                elif up in ("OUTP OFF", "*RST") and w is not None and w["stop_cmd"] is None:
                    w["stop_cmd"] = h
            else:
                m = _FG_CMD.match(text)
                if m:
                    _fg_set(st, m.group(1).upper(), m.group(2))
                m = _FG_OUTP.match(text)
                if m and m.group(1).upper() in ("1", "ON"):
                    w = current[dev] = {
                        "start": h,
                        "mapped": False,
                        "stop": None,
                        "pulse": False,
                        "set": dict(st),
                        "device": dev,
                    }
                    waves.append(w)
                elif m and w is not None and w["stop"] is None:
                    w["stop"] = h
        elif kind == "reply":
            cmd = last_cmd.get(dev, "")
            if box[dev]:
                if cmd in ("FREQ?", "DUTY?") and finite_float(text) is not None:
                    st[cmd[:4]] = finite_float(text)
                elif cmd == "EDGES?" and w is not None:
                    n = text.split(",")[0]
                    if n.isdigit():
                        w["n"] = int(n)
            else:
                m = _FG_QUERY.match(cmd)
                if m:
                    _fg_set(st, m.group(1).upper(), text)
            if w is not None and w["set"]["FREQ"] is None:  # read back after the start
                w["set"] = dict(st)
        elif kind == "event" and box[dev] and text.startswith("clock mapping:"):
            m = _DRIFT.search(text)
            if m and finite_float(m.group(1)) is not None:
                st["DRIFT"] = (h, finite_float(m.group(1)), finite_float(m.group(2)))
        elif (
            kind == "edge"
            and box[dev]
            and w is not None
            and text.startswith("first rising edge")
            and "mapped from the box clock" in text
        ):
            w["start"] = h
            w["mapped"] = True
    out: list[dict] = []
    for dev in devices:
        if "DRIFT" in settings[dev]:
            h, drift, se = settings[dev]["DRIFT"]
            out.append(
                _row(
                    h,
                    dev,
                    CLOCK,
                    clock_text(drift_ppm=drift, drift_se_ppm=se, residual_s=None, uncertainty_s=None, samples=None),
                )
            )
    for k, w in enumerate(waves):
        dev, freq, duty = w["device"], w["set"]["FREQ"], w["set"]["DUTY"]
        if not freq or freq <= 0 or not 0 < duty < 1:
            if k == len(waves) - 1:
                raise ValueError(f"the frequency or duty of {dev}'s square wave is not in the trigger log")
            continue
        period = 1.0 / freq
        if box[dev]:
            high, low = 5.0, 0.0
        else:
            high = w["set"]["HIGH"] if w["set"]["HIGH"] is not None else 0.05  # the 33500's *RST
            low = w["set"]["LOW"] if w["set"]["LOW"] is not None else -0.05
        time_source = DEVICE_CLOCK_MAPPED if w["mapped"] else HOST_WRITE
        out.append(
            _row(
                w["start"],
                dev,
                WAVE_START,
                wave_start_text(
                    period_s=period,
                    duty=duty,
                    high_v=high,
                    low_v=low,
                    start_pulse=w["pulse"],
                    time_source=time_source,
                    uncertainty_s=None,
                ),
            )
        )
        if box[dev] and w["stop_cmd"] is not None:
            # it finishes the period under way; the box's own count, read once it has
            # stopped, is exact (a count read before then is too low, hence the max)
            n = max(w["n"] or 0, math.ceil((w["stop_cmd"] - w["start"]) / period - 1e-9))
            out.append(
                _row(
                    w["start"] + n * period,
                    dev,
                    WAVE_STOP,
                    wave_stop_text(rising_edges=n, time_source=time_source, uncertainty_s=None),
                )
            )
        elif not box[dev] and w["stop"] is not None:
            out.append(
                _row(
                    w["stop"],
                    dev,
                    WAVE_STOP,
                    wave_stop_text(rising_edges=None, time_source=HOST_WRITE, uncertainty_s=None),
                )
            )
    return out
