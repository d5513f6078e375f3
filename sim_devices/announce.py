"""Simulated cameras announce themselves as real Axis cameras do, on loopback only.

* DNS-SD over mDNS: each camera registers ``<ProdShortName> - <serial>._axis-video._tcp.local.``
  (TXT ``macaddress=<serial>``, the serial number being the MAC) with its address 127.0.0.1 and
  its HTTP port, through zeroconf told to use the interface 127.0.0.1 only: the group is joined
  on ``lo`` and every answer leaves from 127.0.0.1.
* SSDP: one responder for all the cameras answers an ``M-SEARCH`` for ``ssdp:all``,
  ``upnp:rootdevice``, the Basic device or Axis' own ``urn:axis-com:service:BasicService:1``
  with one unicast answer per camera, whose ``LOCATION`` is the camera's UPnP description
  (``/rootdesc1.xml`` on its HTTP port; a real camera serves it on a port of its own). Its
  socket is bound to the SSDP group address and joins the group on 127.0.0.1 only, so it hears
  loopback multicast and nothing from the network.

Multicast over ``lo`` works on Linux although ``lo`` has no MULTICAST flag: a socket that sets
``IP_MULTICAST_IF`` to 127.0.0.1 sends to the group on ``lo`` and every member there hears it
(docs/decisions/0067-discover-and-setup.md).
"""

from __future__ import annotations

import logging
import socket
import struct
import threading
from typing import TYPE_CHECKING

from ssdp.messages import SSDPRequest, SSDPResponse

if TYPE_CHECKING:
    from zeroconf import Zeroconf

log = logging.getLogger(__name__)

MDNS_TYPE = "_axis-video._tcp.local."
SSDP_GROUP, SSDP_PORT = "239.255.255.250", 1900
AXIS_ST = "urn:axis-com:service:BasicService:1"
_TARGETS = ("ssdp:all", "upnp:rootdevice", "urn:schemas-upnp-org:device:Basic:1", AXIS_ST)
LOOPBACK = "127.0.0.1"


class Announcer:
    """Announce ``cameras`` (started :class:`~vts_hw.sim_devices.axis_camera.SimAxisCamera`) over
    mDNS and SSDP until :meth:`stop`. ``mdns`` / ``ssdp``: which of the two (both by default)."""

    def __init__(self, cameras, *, mdns: bool = True, ssdp: bool = True, ssdp_port: int = SSDP_PORT):
        self.cameras = list(cameras)
        self.mdns, self.ssdp, self.ssdp_port = mdns, ssdp, ssdp_port
        self._zc: Zeroconf | None = None
        self._infos: list = []
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.searches = 0  # M-SEARCH requests answered (tests)

    def start(self) -> Announcer:
        for cam in self.cameras:
            cam.announced = True
        if self.mdns:
            self._start_mdns()
        if self.ssdp:
            self._start_ssdp()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._zc is not None:
            try:
                for info in self._infos:
                    self._zc.unregister_service(info)
            finally:
                self._zc.close()
                self._zc = None
        if self._sock is not None:
            self._sock.close()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None
        for cam in self.cameras:
            cam.announced = False

    def __enter__(self) -> Announcer:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- mDNS / DNS-SD ---------------------------------------------------------------------
    def _start_mdns(self) -> None:
        from zeroconf import IPVersion, ServiceInfo, Zeroconf

        self._zc = zc = Zeroconf(interfaces=[LOOPBACK], ip_version=IPVersion.V4Only)
        for cam in self.cameras:
            info = ServiceInfo(
                MDNS_TYPE,
                f"{cam.friendly_name}.{MDNS_TYPE}",
                port=cam.port,
                properties={"macaddress": cam.serial},
                server=f"axis-{cam.serial.lower()}.local.",
                parsed_addresses=[LOOPBACK],
            )
            # the serial is in the name: a name already taken is another camera's (never renamed)
            zc.register_service(info, allow_name_change=False)
            self._infos.append(info)

    # -- SSDP ---------------------------------------------------------------------------------
    def _start_ssdp(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if hasattr(socket, "SO_REUSEPORT"):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
        sock.bind((SSDP_GROUP, self.ssdp_port))  # hears datagrams to the group only
        sock.setsockopt(
            socket.IPPROTO_IP,
            socket.IP_ADD_MEMBERSHIP,
            struct.pack("4s4s", socket.inet_aton(SSDP_GROUP), socket.inet_aton(LOOPBACK)),
        )
        sock.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(LOOPBACK))
        sock.settimeout(0.2)
        self._sock = sock
        self._thread = threading.Thread(target=self._serve, args=(sock,), name="sim-ssdp", daemon=True)
        self._thread.start()

    def _serve(self, sock: socket.socket) -> None:
        while not self._stop.is_set():
            try:
                data, addr = sock.recvfrom(8192)
            except TimeoutError:
                continue
            except OSError:
                return  # closed by stop()
            if not addr[0].startswith("127."):
                continue  # loopback only (the membership is on lo; this is belt and braces)
            try:
                request = SSDPRequest.parse(data.decode("utf-8", "replace"))
            except ValueError:
                continue  # not an SSDP request: a real camera ignores it too
            headers = {k.upper(): v.strip() for k, v in request.headers}
            if request.method != "M-SEARCH" or headers.get("MAN", "").strip('"') != "ssdp:discover":
                continue
            target = headers.get("ST", "")
            if target not in _TARGETS:
                continue
            self.searches += 1
            for cam in self.cameras:
                self._answer(sock, cam, target, addr)

    def _answer(self, sock: socket.socket, cam, target: str, addr) -> None:
        st = AXIS_ST if target == "ssdp:all" else target
        usn = f"uuid:Upnp-BasicDevice-1_0-{cam.serial}" + ("" if st.startswith("uuid:") else f"::{st}")
        reply = SSDPResponse(
            200,
            "OK",
            headers=[
                ("CACHE-CONTROL", "max-age=1800"),
                ("EXT", ""),
                ("LOCATION", f"{cam.scheme}://{LOOPBACK}:{cam.port}/rootdesc1.xml"),
                ("SERVER", "Linux/4.9, UPnP/1.0, Portable SDK for UPnP devices/1.6.18"),
                ("ST", st),
                ("USN", usn),
            ],
        )
        try:
            sock.sendto(bytes(reply), addr)
        except OSError as exc:
            log.debug("SSDP answer to %s not sent: %s", addr, exc)
