"""What a discovery search hears: one :class:`Announcement` per camera and protocol, and
:class:`DiscoveryFailed` when a search cannot run on this host.

The two searches (:mod:`.mdns`, :mod:`.ssdp`) make them and the package (:func:`search`,
:func:`merge`) gathers them; both import them from here, and the package re-exports them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from vts_hw.errors import DeviceError


@dataclass(frozen=True)
class Announcement:
    """One camera as one announcement told of it (``source``: ``mdns`` or ``ssdp``)."""

    source: str
    host: str
    port: int
    serial: str
    model: str = ""
    scheme: Literal["http", "https"] = "http"


class DiscoveryFailed(DeviceError):
    """A search could not run on this host (no such interface, socket refused)."""


__all__ = ["Announcement", "DiscoveryFailed"]
