"""What an Axis camera's failures are: the typed errors of the VAPIX driver and what a reply
that is not the expected JSON raises.

Each error carries the camera's name and a sentence that says what to do; the driver
(:mod:`.axis`) raises them, and so do its helpers for streams (:mod:`.axis_stream`), uptime
(:mod:`.axis_uptime`) and setup (:mod:`.axis_setup`), which import them from here rather than
from the driver that imports them. ``vts_hw.drivers.axis`` re-exports every one.
"""

from __future__ import annotations

from vts_hw.camera import CameraError
from vts_hw.camera import Refused as ContractRefused


class AxisError(CameraError):
    """An Axis camera failed; ``camera`` names it."""


class CameraUnreachable(AxisError):
    """No connection, or a connection that timed out or was dropped."""


class CameraUnauthorized(AxisError):
    """The camera refused the credentials (HTTP 401 after answering the challenge)."""

    retry = False  # reconnecting with the same password cannot help


class TooManyViewers(AxisError):
    """HTTP 503: the camera is serving as many streams as it can."""


class BadReply(AxisError):
    """The camera answered, but not with what was asked for."""


class NotFound(BadReply):
    """HTTP 404: this firmware does not have that CGI (how VAPIX 2 and 3 are told apart)."""


class Refused(BadReply, ContractRefused):
    """HTTP 200 with a ``# Error:`` body: the camera refused the request (unknown group...)."""


#: what reading a JSON reply that is not the expected shape raises (RecursionError: nested too deeply)
NOT_THE_JSON = (ValueError, KeyError, TypeError, AttributeError, OverflowError, RecursionError)


__all__ = [
    "AxisError",
    "CameraUnreachable",
    "CameraUnauthorized",
    "TooManyViewers",
    "BadReply",
    "NotFound",
    "Refused",
    "NOT_THE_JSON",
]
