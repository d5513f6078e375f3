"""A simulated Axis network camera: an HTTP(S) server on 127.0.0.1 that answers the VAPIX subset.

One :class:`SimAxisCamera` per camera, one port each. It serves the frames of a camera
source (``SimCameraSource`` or anything with the same interface: ``name``, ``width``,
``height``, ``product``, ``camera_time()``, ``set_led()``, ``pulse_led()``, ``led_on()``,
``jpeg(quality)``) and answers like the real firmware of its model profile
(:mod:`.axis_params`: ``p1375``, current firmware, the default; ``axis211``, firmware 4.47),
byte for byte where it matters:

==============================================  ==============================================
``GET /axis-cgi/jpg/image.cgi``                 one JPEG (``resolution``, ``compression``)
``GET /axis-cgi/mjpg/video.cgi``                ``multipart/x-mixed-replace; boundary=myboundary``
                                                (``resolution``, ``fps``, ``duration``,
                                                ``nbrofframes``, ``compression``)
``GET|POST /axis-cgi/param.cgi``                ``action=list&group=..`` / ``action=update&K=V``,
                                                in the query or a form body (VAPIX 2:
                                                ``view/param.cgi``, ``admin/param.cgi``)
``GET /axis-cgi/io/port.cgi``                   ``action=1:/``, ``1:\\``, ``1:/300\\``;
                                                ``checkactive=1`` -> ``port1=active``/``inactive``
                                                (VAPIX 2: ``io/output.cgi``, ``check=1`` ->
                                                ``output1=1``/``0``; ``io/input.cgi?check=1``)
``POST /axis-cgi/basicdeviceinfo.cgi``          JSON device info (current firmware)
``POST /axis-cgi/apidiscovery.cgi``             JSON list of the camera's APIs (current firmware)
``GET /axis-cgi/usergroup.cgi``                 the user's groups (current firmware)
``GET /axis-cgi/admin/date.cgi?action=get``     camera clock as ``Nov 21, 2026 23:59:59``
``POST /axis-cgi/time.cgi``                     JSON ``getDateTimeInfo``, ``setTimeZone`` ... (current
                                                firmware; :mod:`.axis_time`)
``POST /axis-cgi/systemready.cgi``              JSON: ready, and the uptime (current firmware)
``GET /axis-cgi/admin/serverreport.cgi``        text report with the uptime (both models)
``GET /rootdesc1.xml``                          UPnP description, once announced (:mod:`.announce`)
``GET|POST /sim/faults``, ``GET /sim/state``    control endpoint for tests (no auth, loopback)
==============================================  ==============================================

Every ``/axis-cgi/`` request needs credentials: HTTP digest (:mod:`.digest`), or basic when
``auth="basic"``. With ``tls=(certfile, keyfile)`` the camera speaks HTTPS only. Faults
(:mod:`.faults`) are switched at run time through :attr:`SimAxisCamera.faults`,
:meth:`SimAxisCamera.set_faults` or ``POST /sim/faults``. The design choices are in
``docs/decisions/0003-sim-axis-camera.md`` and ``0020-sim-axis-profiles.md``.
"""

from __future__ import annotations

import logging
import socket
import ssl
import sys
import threading
from http.server import ThreadingHTTPServer
from ipaddress import ip_address
from typing import Any, Self

import cv2
import numpy as np

from vts_hw.sim_devices.axis_http import Handler
from vts_hw.sim_devices.axis_params import DEFAULT_MODEL, ParamStore, Profile, describe
from vts_hw.sim_devices.axis_streaming import BOUNDARY, restamp, unstamped
from vts_hw.sim_devices.clock import RealClock
from vts_hw.sim_devices.digest import BasicAuth, DigestAuth
from vts_hw.sim_devices.faults import Faults

__all__ = ["SimAxisCamera", "ParamStore", "BOUNDARY"]

log = logging.getLogger(__name__)
AUTH_SCHEMES = ("digest", "basic")


# --------------------------------------------------------------------------------------
# The camera
# --------------------------------------------------------------------------------------
class SimAxisCamera:
    """One simulated Axis camera on ``host:port`` (loopback only; port 0 picks a free one).

    ``source`` gives frames, LED and camera clock; ``user``/``password`` are the credentials,
    checked by ``auth`` (``"digest"``, or ``"basic"``); ``model`` names the profile: what the
    camera is and which firmware it runs (``"p1375"``, ``"axis211"``; the former
    ``"vapix3"``/``"vapix2"`` name them too); ``tls=(certfile, keyfile)`` makes it an HTTPS
    camera; ``clock`` (a ``SimClock``, default ``RealClock``) paces streams. Change
    :attr:`faults` at any time. ``start()``/``stop()`` or use it as a context manager.
    """

    def __init__(
        self,
        source,
        user: str = "root",
        password: str = "pass",
        host: str = "127.0.0.1",
        port: int = 0,
        model: str = DEFAULT_MODEL,
        clock=None,
        *,
        auth: str = "digest",
        tls: tuple[str, str] | None = None,
        firmware: str | None = None,
        uptime_s: float = 86400.0,
    ):
        if firmware is not None:  # the former name of the argument
            model = firmware
        if not ip_address(host).is_loopback:
            raise ValueError(f"a simulated camera binds to loopback only, not {host}")
        if auth not in AUTH_SCHEMES:
            raise ValueError(f"auth must be one of {', '.join(AUTH_SCHEMES)}, not {auth!r}")
        self.profile = Profile.load(model)
        self.source = source
        self.host, self._requested_port = host, port
        self.clock = clock or RealClock()
        self.log = log
        self.faults = Faults()
        self.product = self.profile.product(source.product)
        self.resolutions = [f"{source.width // d}x{source.height // d}" for d in (1, 2, 4)]
        self.params = ParamStore(self.profile.params(self.product, source.name, self.resolutions), self.resolutions)
        realm = f"AXIS_{self.product.mac.hex().upper()}"
        self.auth = DigestAuth(realm, user, password) if auth == "digest" else BasicAuth(realm, user, password)
        self.ssl_context = None
        if tls is not None:
            self.ssl_context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
            self.ssl_context.load_cert_chain(*tls)
        self._lock = threading.Lock()
        self._source_lock = threading.Lock()
        # frames_lost: not sent (the loss faults); frames_skipped: not sent because the stream fell
        # further behind than its late limit; frames_late: sent more than a frame period late
        self._counters = dict(
            frames_served=0,
            snapshots_served=0,
            active_streams=0,
            connections=0,
            requests=0,
            auth_failures=0,
            frames_lost=0,
            frames_skipped=0,
            frames_late=0,
        )
        self._snapshot = (-1, 0)  # (faults.version seen, snapshots since)
        self._sockets: set[socket.socket] = set()
        self._stopping = threading.Event()
        self.booted_at = self.clock.now() - uptime_s  # when the camera started (sim clock): its uptime
        self._tell_started()
        self.announced = False  # announced on the network (sim_devices/announce.py): serves its UPnP description
        self._httpd: _Server | None = None
        self._thread: threading.Thread | None = None

    @property
    def model(self) -> str:
        return self.profile.model

    @property
    def firmware(self) -> str:
        """``vapix3`` or ``vapix2``: the generation of the camera's HTTP API."""
        return f"vapix{self.profile.vapix}"

    # --- life cycle --------------------------------------------------------------------
    def start(self) -> SimAxisCamera:
        if self._httpd is not None:
            return self
        self._stopping.clear()
        self._httpd = _Server((self.host, self._requested_port), Handler)
        self._httpd.camera = self
        self._httpd.ssl_context = self.ssl_context
        self._thread = threading.Thread(
            target=self._httpd.serve_forever,
            kwargs={"poll_interval": 0.1},
            name=f"sim-axis-{self.source.name}",
            daemon=True,
        )
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop serving, end running streams and close every connection."""
        if self._httpd is None:
            return
        self._stopping.set()
        self._httpd.shutdown()
        self._httpd.server_close()
        with self._lock:
            for sock in list(self._sockets):
                try:
                    sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
        if self._thread:
            self._thread.join(timeout=5)
        self._httpd = self._thread = None

    def __enter__(self) -> SimAxisCamera:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def port(self) -> int:
        if self._httpd is None:
            raise RuntimeError("the simulated camera is not started")
        return self._httpd.server_address[1]

    @property
    def scheme(self) -> str:
        return "https" if self.ssl_context is not None else "http"

    @property
    def url(self) -> str:
        return f"{self.scheme}://{self.host}:{self.port}"

    # --- control ----------------------------------------------------------------------
    def set_faults(self, reset: bool = False, **changes: Any) -> Faults:
        """Change faults (all or nothing); ``reset=True`` first restores a healthy camera."""
        if reset:
            self.faults.reset()
        self.faults.update(changes)
        return self.faults

    def reboot(self) -> None:
        """The camera restarts now: its uptime starts again from zero (its parameters are kept)."""
        self.booted_at = self.clock.now()
        self._tell_started()

    def _tell_started(self) -> None:
        """The source hears when the camera started (its warm-up drift counts from then)."""
        started = getattr(self.source, "started", None)
        if started is not None:
            started(self.booted_at)

    @property
    def serial(self) -> str:
        return self.params.get("Properties.System.SerialNumber")

    @property
    def friendly_name(self) -> str:
        """How the camera names itself when it announces itself: ``AXIS P1375 - ACCC8E012345``."""
        return f"{self.params.get('Brand.ProdShortName')} - {self.serial}"

    def description_xml(self, host: str = "") -> str:
        """The UPnP device description (what an SSDP answer's LOCATION points to)."""
        from xml.sax.saxutils import escape

        p = self.params
        fields = [
            ("deviceType", "urn:schemas-upnp-org:device:Basic:1"),
            ("friendlyName", self.friendly_name),
            ("manufacturer", "AXIS"),
            ("manufacturerURL", "http://www.axis.com/"),
            ("modelDescription", p.get("Brand.ProdFullName")),
            ("modelName", p.get("Brand.ProdShortName")),
            ("modelNumber", p.get("Brand.ProdNbr")),
            ("serialNumber", self.serial),
            ("UDN", f"uuid:Upnp-BasicDevice-1_0-{self.serial}"),
            ("presentationURL", f"{self.scheme}://{self.host}:{self.port}/"),
        ]
        body = "".join(f"<{k}>{escape(v)}</{k}>" for k, v in fields)
        return (
            '<?xml version="1.0"?>\r\n<root xmlns="urn:schemas-upnp-org:device-1-0">'
            "<specVersion><major>1</major><minor>0</minor></specVersion>"
            f"<device>{body}</device></root>\r\n"
        )

    def go_offline(self, seconds: float) -> threading.Timer:
        """Drop off the network for ``seconds`` (the ``offline`` fault, cleared by a timer)."""
        self.faults.offline = True
        timer = threading.Timer(seconds, setattr, (self.faults, "offline", False))
        timer.daemon = True
        timer.start()
        return timer

    def state(self) -> dict[str, Any]:
        with self._lock:
            counters = dict(self._counters)
        return dict(
            name=self.source.name,
            firmware=self.firmware,
            **describe(self.profile),
            port=self.port,
            camera_time=self.camera_time(),
            led_on=bool(self.source.led_on()),
            faults=self.faults.active(),
            **counters,
        )

    # --- used by the request handler ---------------------------------------------------
    def camera_time(self, host_t: float | None = None) -> float:
        """The camera's clock at host time ``host_t`` (default now), its jumps (fault) included."""
        t = self.clock.now() if host_t is None else host_t
        return self.source.camera_time(t) + self.faults.clock_offset(t)

    def offline_now(self) -> bool:
        """Off the network now (the ``offline`` fault or its stretch)."""
        return self.faults.offline_at(self.clock.now())

    def count(self, name: str, delta: int = 1) -> None:
        with self._lock:
            self._counters[name] += delta

    def counter(self, name: str) -> int:
        with self._lock:
            return self._counters[name]

    def track(self, sock: socket.socket, add: bool) -> None:
        with self._lock:
            if add:
                self._sockets.add(sock)
                self._counters["connections"] += 1
            else:
                self._sockets.discard(sock)
                self._counters["connections"] -= 1

    def next_snapshot_index(self) -> int:
        """The index that ``torn_jpeg_at`` is compared with for a snapshot."""
        with self._lock:
            version, n = self._snapshot
            if version != self.faults.version:
                version, n = self.faults.version, 0
            self._snapshot = (version, n + 1)
            return n

    def frame(self, width: int, height: int, quality: int, host_t: float | None = None) -> bytes:
        """One JPEG from the source (captured at host time ``host_t``, default now), scaled
        when a lower resolution was asked, with the Axis segments this model's firmware
        writes (its product id, its layout)."""
        with self._source_lock:
            jpeg, epoch = self.source.jpeg(quality, host_t)
        epoch += self.faults.clock_offset(self.clock.now() if host_t is None else host_t)
        if (width, height) != (self.source.width, self.source.height):
            image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_UNCHANGED)
            if image is None:  # the scene's own JPEG: always decodable
                raise RuntimeError("the simulated camera's source gave a JPEG OpenCV cannot read")
            small = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
            _, enc = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, quality])
            jpeg = enc.tobytes()
        if self.faults.no_axis_stamps:
            return unstamped(jpeg)
        return restamp(jpeg, epoch, self.product, self.profile.jpeg_layout, self.profile.time_extra_zero)

    def sleep_until(self, target: float) -> bool:
        """Sleep on the clock until ``target``; False if the camera stops meanwhile."""
        while not self._stopping.is_set():
            left = target - self.clock.now()
            if left <= 0:
                return True
            self.clock.sleep(min(left, 0.05))
        return False


class _Server(ThreadingHTTPServer):
    daemon_threads = True
    block_on_close = False
    camera: SimAxisCamera
    ssl_context: ssl.SSLContext | None = None

    def finish_request(self: Self, request, client_address) -> None:
        """HTTPS: the TLS handshake happens here, in the connection's own thread, so that a
        slow or broken client never holds up the others."""
        if self.ssl_context is None:
            super().finish_request(request, client_address)
            return
        request.settimeout(10)
        try:
            tls = self.ssl_context.wrap_socket(request, server_side=True)
        except OSError as exc:  # ssl.SSLError too: a client that does not speak TLS, or gives up
            log.debug("TLS handshake with %s failed: %s", client_address, exc)
            return
        try:
            self.RequestHandlerClass(tls, client_address, self)
        finally:
            tls.close()

    def handle_error(self, request, client_address) -> None:
        exc = sys.exc_info()[1]
        if isinstance(exc, OSError):  # client went away, socket shut down by stop(): quiet
            log.debug("connection from %s ended: %s", client_address, exc)
            return
        log.exception("simulated camera: error while handling a request from %s", client_address)
