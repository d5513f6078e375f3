"""Instrument settings declared once, PyMeasure style: a descriptor and its validators.

A driver declares ``frequency_hz = Setting("FREQ {}", "FREQ?", in_range(...))``. Reading the
attribute asks the driver to query the device (``_read_setting``); assigning asks it to
validate and send (``_write_setting``). Validators raise :class:`OutOfRange` before anything
is sent.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

from vts_hw.drivers.trigger import OutOfRange


def in_range(low: float, high: float, what: str, unit: str = "", device: str = "the device") -> Callable[[Any], float]:
    """A validator: a finite real number (not a bool) within [low, high]."""
    unit_s = f" {unit}" if unit else ""

    def check(value: Any) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise OutOfRange(f"{what} must be a number{' of' + unit_s if unit else ''}, not {value!r}")
        v = float(value)
        if not math.isfinite(v) or not low <= v <= high:
            raise OutOfRange(f"{what} {value!r}{unit_s} is outside {device}'s range {low:g} to {high:g}{unit_s}")
        return v

    check.__doc__ = f"{what}: {low:g} to {high:g}{unit_s}"
    return check


def whole_in_range(low: int, high: int, what: str, unit: str) -> Callable[[Any], int]:
    """A validator: a whole number within [low, high] (5.0 is 5; 5.5 and True are refused)."""

    def check(value: Any) -> int:
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not math.isfinite(value)
            or value != int(value)
            or not low <= value <= high
        ):
            raise OutOfRange(f"{what} must be a whole number of {unit} from {low} to {high}, not {value!r}")
        return int(value)

    check.__doc__ = f"{what}: whole {unit} from {low} to {high}"
    return check


class Setting:
    """A device setting: set command, query, validator, reply parser and value formatter."""

    default_fmt: Callable[[Any], str] = staticmethod(str)

    def __init__(
        self,
        command: str,
        query: str,
        validator: Callable[[Any], Any],
        *,
        parse: Callable[[str], Any] = float,
        fmt: Callable[[Any], str] | None = None,
        doc: str = "",
    ):
        self.command = command
        self.query = query
        self.validator = validator
        self.parse = parse
        self.fmt = fmt or type(self).default_fmt
        self.name = ""
        self.__doc__ = f"{doc} ({validator.__doc__}); set with {command!r}, read with {query!r}"

    def __set_name__(self, owner, name: str) -> None:
        self.name = name

    def __get__(self, obj, objtype=None):
        if obj is None:
            return self
        return obj._read_setting(self)

    def __set__(self, obj, value) -> None:
        obj._write_setting(self, value)
