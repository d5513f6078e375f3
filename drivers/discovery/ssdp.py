"""SSDP (UPnP discovery): an ``M-SEARCH`` to 239.255.255.250:1900 and the answers it gets.

The request and the answers are SSDP messages of the ``ssdp`` package; the socket work is a
few lines here. Each answer's ``LOCATION`` is the camera's UPnP device description, read over
HTTP (at most :data:`MAX_DESCRIPTION` bytes, within the time left): its ``manufacturer`` says
whether it is an Axis camera, ``modelName`` and ``serialNumber`` what it is, and
``presentationURL`` where its web server (VAPIX) is. Anything else that answers is left out.
"""

from __future__ import annotations

import select
import socket
import time
import xml.etree.ElementTree as ET
from typing import Literal
from urllib.parse import urlsplit

import requests
from ssdp.messages import SSDPRequest, SSDPResponse

from vts_hw.drivers.discovery.announcement import Announcement, DiscoveryFailed

GROUP, PORT = "239.255.255.250", 1900
SEARCH_TARGET = "ssdp:all"
MAX_DESCRIPTION = 256 * 1024
_NS = "{urn:schemas-upnp-org:device-1-0}"


def all_ipv4() -> list[str]:
    """Every IPv4 address of this host (ifaddr: zeroconf's own dependency)."""
    import ifaddr

    return sorted(
        {
            ip.ip
            for adapter in ifaddr.get_adapters()
            for ip in adapter.ips
            if isinstance(ip.ip, str) and not ip.ip.startswith("169.254.")
        }
    )


def m_search(mx: int, port: int = PORT) -> bytes:
    """The request, byte for byte."""
    return bytes(
        SSDPRequest(
            "M-SEARCH",
            headers=[("HOST", f"{GROUP}:{port}"), ("MAN", '"ssdp:discover"'), ("MX", str(mx)), ("ST", SEARCH_TARGET)],
        )
    )


def search(timeout: float, interfaces: list[str] | None = None, *, port: int = PORT) -> list[Announcement]:
    """Send an M-SEARCH from each interface and collect the Axis cameras that answer within
    ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    socks = []
    try:
        for iface in interfaces or all_ipv4():
            s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
            socks.append(s)
            try:
                s.bind((iface, 0))
                s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(iface))
                s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 2)
                s.sendto(m_search(max(1, min(5, int(timeout / 2))), port), (GROUP, port))
            except OSError as exc:
                raise DiscoveryFailed(f"SSDP: cannot search from {iface} ({exc.strerror or exc})") from None
            s.setblocking(False)
        locations: dict[str, str] = {}
        while (left := deadline - time.monotonic()) > 0:
            ready, _, _ = select.select(socks, [], [], min(left, 0.2))
            for s in ready:
                try:
                    data, addr = s.recvfrom(8192)
                except OSError:
                    continue
                loc = location(data)
                if loc:
                    locations.setdefault(loc, addr[0])
    finally:
        for s in socks:
            s.close()
    out = []
    for loc in sorted(locations):
        found = describe(loc, timeout=max(1.0, min(3.0, timeout)))
        if found is not None:
            out.append(found)
    return out


def location(datagram: bytes) -> str | None:
    """The LOCATION of an SSDP answer (None for anything else: a request, garbage)."""
    try:
        reply = _reply(datagram)
    except (ValueError, IndexError):
        return None
    if reply is None or reply.status_code != 200:
        return None
    headers = {k.upper(): v.strip() for k, v in reply.headers}
    loc = headers.get("LOCATION", "")
    return loc if loc.lower().startswith(("http://", "https://")) else None


def _reply(datagram: bytes) -> SSDPResponse | None:
    text = datagram.decode("utf-8", "replace")
    return SSDPResponse.parse(text) if text.startswith("HTTP/") else None


def describe(loc: str, timeout: float = 3.0) -> Announcement | None:
    """The camera a UPnP description tells of (None: not an Axis camera, or unreadable)."""
    try:
        with requests.get(loc, timeout=timeout, stream=True) as r:
            if r.status_code != 200:
                return None
            body = r.raw.read(MAX_DESCRIPTION + 1, decode_content=True)
        if len(body) > MAX_DESCRIPTION:
            return None
        # a description from the LAN: at most MAX_DESCRIPTION bytes, and expat (>= 2.4) refuses entity
        # amplification and resolves no external entity: a hostile one is a ParseError, answered with None
        root = ET.fromstring(body)  # nosec B314: bounded, and expat refuses entity tricks (above)
    except (requests.RequestException, ET.ParseError, ValueError, OSError):
        return None
    dev = root.find(f"{_NS}device")
    if dev is None:
        return None

    def text(tag: str) -> str:
        return (dev.findtext(f"{_NS}{tag}") or "").strip()

    if "axis" not in text("manufacturer").lower():
        return None
    serial = "".join(ch for ch in text("serialNumber") if ch.isalnum()).upper()
    where = urlsplit(text("presentationURL") or loc)
    scheme: Literal["http", "https"] = "https" if where.scheme == "https" else "http"
    try:
        port = where.port or (443 if scheme == "https" else 80)
    except ValueError:
        return None
    host = where.hostname or urlsplit(loc).hostname or ""
    return Announcement("ssdp", host, port, serial, text("modelName"), scheme) if host else None
