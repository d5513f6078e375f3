"""DNS-SD over mDNS: Axis cameras announce ``_axis-video._tcp.local.`` (zeroconf).

A camera's service instance is named ``<model> - <serial>`` (``AXIS P1375 - ACCC8E012345``)
and its TXT record carries ``macaddress=<serial>``; its SRV and A records give the port and
address of its web server. The browser listens for ``timeout`` seconds on the given IPv4
interfaces (all of them when none are given), then resolves every instance it heard of.
"""

from __future__ import annotations

import threading

from vts_hw.drivers.discovery.announcement import Announcement, DiscoveryFailed

SERVICE = "_axis-video._tcp.local."
RESOLVE_MS = 2000


def browse(timeout: float, interfaces: list[str] | None = None) -> list[Announcement]:
    """Every ``_axis-video._tcp`` instance heard within ``timeout`` seconds."""
    from zeroconf import (
        DNSQuestionType,
        InterfaceChoice,
        IPVersion,
        ServiceBrowser,
        ServiceInfo,
        ServiceStateChange,
        Zeroconf,
    )

    names: set[str] = set()
    lock = threading.Lock()

    def on_change(zeroconf, service_type, name, state_change):
        if state_change in (ServiceStateChange.Added, ServiceStateChange.Updated):
            with lock:
                names.add(name)

    try:
        zc = Zeroconf(interfaces=list(interfaces) if interfaces else InterfaceChoice.All, ip_version=IPVersion.V4Only)
    except (OSError, ValueError) as exc:
        where = ", ".join(interfaces) if interfaces else "every interface"
        raise DiscoveryFailed(f"mDNS: cannot listen on {where} ({exc})") from None
    try:
        # QM: answers multicast, so that every listener hears them (a unicast answer to port 5353 goes
        # to one socket of those bound to it, which on one host may be the camera's own)
        browser = ServiceBrowser(zc, SERVICE, handlers=[on_change], question_type=DNSQuestionType.QM)
        threading.Event().wait(timeout)
        browser.cancel()
        with lock:
            heard = sorted(names)
        out = []
        for name in heard:
            info = ServiceInfo(SERVICE, name)
            if not info.request(zc, RESOLVE_MS, question_type=DNSQuestionType.QM):
                continue  # gone between its announcement and now: not a camera to set up
            found = from_info(name, info)
            if found is not None:
                out.append(found)
        return out
    finally:
        zc.close()


def from_info(name: str, info) -> Announcement | None:
    """An announcement from a resolved service (None without an IPv4 address or a port)."""
    from zeroconf import IPVersion

    addresses = info.parsed_addresses(IPVersion.V4Only)
    if not addresses or not info.port:
        return None
    instance = name[: -len(SERVICE) - 1] if name.endswith("." + SERVICE) else name
    model, sep, tail = instance.rpartition(" - ")
    props = {
        (k.decode("utf-8", "replace") if isinstance(k, bytes) else str(k)).lower(): (
            v.decode("utf-8", "replace") if isinstance(v, bytes) else (v or "")
        )
        for k, v in (info.properties or {}).items()
    }
    serial = props.get("macaddress", "") or (tail if sep else "")
    serial = "".join(ch for ch in serial if ch.isalnum()).upper()
    return Announcement("mdns", addresses[0], int(info.port), serial, model.strip() if sep else instance)
