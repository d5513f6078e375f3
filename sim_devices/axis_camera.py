"""A simulated Axis network camera: an HTTP server on 127.0.0.1 that answers the VAPIX subset.

One :class:`SimAxisCamera` per camera, one port each. It serves the frames of a camera
source (``SimCameraSource`` or anything with the same interface: ``name``, ``width``,
``height``, ``product``, ``camera_time()``, ``set_led()``, ``pulse_led()``, ``led_on()``,
``jpeg(quality)``) and answers like real firmware, byte for byte where it matters:

==============================================  ==============================================
``GET /axis-cgi/jpg/image.cgi``                 one JPEG (``resolution``, ``compression``)
``GET /axis-cgi/mjpg/video.cgi``                ``multipart/x-mixed-replace; boundary=myboundary``
                                                (``resolution``, ``fps``, ``duration``,
                                                ``nbrofframes``, ``compression``)
``GET /axis-cgi/param.cgi``                     ``action=list&group=..`` / ``action=update&K=V``
                                                (VAPIX 2: ``view/param.cgi``, ``admin/param.cgi``)
``GET /axis-cgi/io/port.cgi``                   ``action=1:/``, ``1:\\``, ``1:/300\\``;
                                                ``checkactive=1``
``POST /axis-cgi/basicdeviceinfo.cgi``          JSON device info (VAPIX 3 only)
``GET /axis-cgi/date.cgi?action=get``           camera clock as ``Nov 21, 2026 23:59:59``
``POST /axis-cgi/time.cgi``                     JSON ``getDateTimeInfo`` (VAPIX 3 only)
``GET|POST /sim/faults``, ``GET /sim/state``    control endpoint for tests (no auth, loopback)
==============================================  ==============================================

Every ``/axis-cgi/`` request needs HTTP digest credentials (see :mod:`.digest`). Faults
(:mod:`.faults`) are switched at run time through :attr:`SimAxisCamera.faults`,
:meth:`SimAxisCamera.set_faults` or ``POST /sim/faults``. The design choices are in
``docs/decisions/0003-sim-axis-camera.md``.
"""

from __future__ import annotations

import json
import logging
import math
import socket
import sys
import threading
from datetime import datetime, timezone
from email.utils import formatdate
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from ipaddress import ip_address
from typing import Any
from urllib.parse import parse_qs, parse_qsl, urlsplit

import cv2
import numpy as np

from vts_hw.axis_jpeg import stamp_jpeg

from .clock import RealClock
from .digest import DigestAuth
from .faults import Faults
from .axis_params import (DEFAULT_FPS, MAX_FPS, ParamStore,
                          default_params)

__all__ = ["SimAxisCamera", "ParamStore", "BOUNDARY"]

log = logging.getLogger(__name__)

BOUNDARY = "myboundary"
_MONTHS = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")
_STREAM_HEADER = (
    "HTTP/1.0 200 OK\r\n"
    "Cache-Control: no-cache\r\n"
    "Pragma: no-cache\r\n"
    "Expires: Thu, 01 Dec 1994 16:00:00 GMT\r\n"
    "Connection: close\r\n"
    f"Content-Type: multipart/x-mixed-replace; boundary={BOUNDARY}\r\n"
    "\r\n"
).encode("ascii")
_HTML = ("<HTML><HEAD><TITLE>{code} {reason}</TITLE></HEAD>\r\n"
         "<BODY><H1>{code} {reason}</H1>\r\n{text}\r\n</BODY></HTML>\r\n")
_BODY_401 = _HTML.format(code=401, reason="Unauthorized",
                         text="Your client does not have permission to get this URL from this server.")
_BODY_503 = _HTML.format(code=503, reason="Service Unavailable",
                         text="Too many viewers: the maximum number of clients is already connected.")
_BODY_404 = _HTML.format(code=404, reason="Not Found", text="The requested URL was not found on this server.")
_DEVICE_INFO = {  # basicdeviceinfo.cgi property -> parameter
    "Brand": "Brand.Brand", "BuildDate": "Properties.Firmware.BuildDate",
    "HardwareID": "Properties.System.HardwareID", "ProdFullName": "Brand.ProdFullName",
    "ProdNbr": "Brand.ProdNbr", "ProdShortName": "Brand.ProdShortName", "ProdType": "Brand.ProdType",
    "ProdVariant": "Brand.ProdVariant", "SerialNumber": "Properties.System.SerialNumber",
    "Version": "Properties.Firmware.Version", "WebURL": "Brand.WebURL",
}
_REASONS = {200: "OK", 400: "Bad Request", 401: "Unauthorized", 403: "Forbidden", 404: "Not Found",
            405: "Method Not Allowed", 503: "Service Unavailable"}


class _Reject(Exception):
    """A request argument the camera refuses (answered 400 with ``Error: <message>``)."""


# --------------------------------------------------------------------------------------
# The camera
# --------------------------------------------------------------------------------------
class SimAxisCamera:
    """One simulated Axis camera on ``host:port`` (loopback only; port 0 picks a free one).

    ``source`` gives frames, LED and camera clock; ``user``/``password`` are the digest
    credentials; ``firmware`` is ``"vapix3"`` (new and old paths) or ``"vapix2"`` (old paths
    only); ``clock`` (a ``SimClock``, default ``RealClock``) paces streams. Change
    :attr:`faults` at any time. ``start()``/``stop()`` or use it as a context manager.
    """

    def __init__(self, source, user: str = "root", password: str = "pass", host: str = "127.0.0.1",
                 port: int = 0, firmware: str = "vapix3", clock=None):
        if firmware not in ("vapix3", "vapix2"):
            raise ValueError(f"firmware must be 'vapix3' or 'vapix2', not {firmware!r}")
        if not ip_address(host).is_loopback:
            raise ValueError(f"a simulated camera binds to loopback only, not {host}")
        self.source = source
        self.firmware = firmware
        self.host, self._requested_port = host, port
        self.clock = clock or RealClock()
        self.faults = Faults()
        self.resolutions = [f"{source.width // d}x{source.height // d}" for d in (1, 2, 4)]
        self.params = ParamStore(default_params(source, firmware, self.resolutions), self.resolutions)
        self.auth = DigestAuth(f"AXIS_{source.product.mac.hex().upper()}", user, password)
        self._lock = threading.Lock()
        self._source_lock = threading.Lock()
        self._counters = dict(frames_served=0, snapshots_served=0, active_streams=0, connections=0,
                              requests=0, auth_failures=0)
        self._snapshot = (-1, 0)  # (faults.version seen, snapshots since)
        self._sockets: set[socket.socket] = set()
        self._stopping = threading.Event()
        self._httpd: _Server | None = None
        self._thread: threading.Thread | None = None

    # --- life cycle --------------------------------------------------------------------
    def start(self) -> "SimAxisCamera":
        if self._httpd is not None:
            return self
        self._stopping.clear()
        self._httpd = _Server((self.host, self._requested_port), _Handler)
        self._httpd.camera = self
        self._thread = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.1},
                                        name=f"sim-axis-{self.source.name}", daemon=True)
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

    def __enter__(self) -> "SimAxisCamera":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    @property
    def port(self) -> int:
        if self._httpd is None:
            raise RuntimeError("the simulated camera is not started")
        return self._httpd.server_address[1]

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    # --- control ----------------------------------------------------------------------
    def set_faults(self, reset: bool = False, **changes: Any) -> Faults:
        """Change faults (all or nothing); ``reset=True`` first restores a healthy camera."""
        if reset:
            self.faults.reset()
        self.faults.update(changes)
        return self.faults

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
        return dict(name=self.source.name, firmware=self.firmware, port=self.port,
                    camera_time=self.source.camera_time(), led_on=bool(self.source.led_on()),
                    faults=self.faults.active(), **counters)

    # --- used by the request handler ---------------------------------------------------
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

    def frame(self, width: int, height: int, quality: int) -> bytes:
        """One stamped JPEG from the source, scaled when a lower resolution was asked."""
        with self._source_lock:
            jpeg, epoch = self.source.jpeg(quality)
        if (width, height) == (self.source.width, self.source.height):
            return jpeg
        image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_UNCHANGED)
        small = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
        _, enc = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, quality])
        return stamp_jpeg(enc.tobytes(), epoch, self.source.product)

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

    def handle_error(self, request, client_address) -> None:
        exc = sys.exc_info()[1]
        if isinstance(exc, OSError):  # client went away, socket shut down by stop(): quiet
            log.debug("connection from %s ended: %s", client_address, exc)
            return
        log.exception("simulated camera: error while handling a request from %s", client_address)


# --------------------------------------------------------------------------------------
# Requests
# --------------------------------------------------------------------------------------
class _Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    timeout = 60
    server: _Server

    ROUTES_COMMON = {
        "/axis-cgi/jpg/image.cgi": "snapshot",
        "/axis-cgi/mjpg/video.cgi": "stream",
        "/axis-cgi/io/port.cgi": "io_port",
        "/axis-cgi/date.cgi": "date",
        "/axis-cgi/view/param.cgi": "param_view",
        "/axis-cgi/admin/param.cgi": "param_admin",
    }
    ROUTES_VAPIX3 = {
        "/axis-cgi/param.cgi": "param_admin",
        "/axis-cgi/basicdeviceinfo.cgi": "device_info",
        "/axis-cgi/time.cgi": "time_api",
    }

    # --- plumbing ---------------------------------------------------------------------
    @property
    def cam(self) -> SimAxisCamera:
        return self.server.camera

    def setup(self) -> None:
        super().setup()
        self.cam.track(self.connection, True)

    def finish(self) -> None:
        try:
            super().finish()
        finally:
            self.cam.track(self.connection, False)

    def log_message(self, format: str, *args) -> None:  # noqa: A002 - stdlib signature
        log.debug("%s %s", self.address_string(), format % args)

    def do_GET(self) -> None:
        self._dispatch("GET")

    def do_POST(self) -> None:
        self._dispatch("POST")

    def _send(self, status: int, body: bytes | str, content_type: str = "text/plain",
              headers: tuple[str, ...] = ()) -> None:
        """Write a whole response; old-firmware mode answers HTTP/1.0 and closes."""
        if isinstance(body, str):
            body = body.encode("utf-8")
        old = self.cam.faults.close_after_response
        close = self.close_connection or old
        lines = [f"{'HTTP/1.0' if old else 'HTTP/1.1'} {status} {_REASONS.get(status, '')}",
                 f"Date: {formatdate(usegmt=True)}", f"Content-Type: {content_type}",
                 f"Content-Length: {len(body)}", *headers]
        if close:
            lines.append("Connection: close")
        self.wfile.write(("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + body)
        self.close_connection = close

    def _hang_up(self) -> None:
        """Close the connection without another byte (FIN: data already sent is delivered)."""
        self.close_connection = True
        try:
            self.wfile.flush()
            self.connection.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass

    def _read_body(self) -> bytes:
        try:
            length = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            length = 0
        return self.rfile.read(min(length, 1 << 20)) if length > 0 else b""

    def _dispatch(self, method: str) -> None:
        split = urlsplit(self.path)
        path = split.path
        self.query = {k: v[-1] for k, v in parse_qs(split.query, keep_blank_values=True).items()}
        self.query_pairs = _pairs(split.query)
        self.body = self._read_body()
        try:
            if path.startswith("/sim/"):
                self._control(method, path)
                return
            if not path.startswith("/axis-cgi/"):
                self._send(404, _BODY_404, "text/html")
                return
            if self.cam.faults.offline:
                self._hang_up()
                return
            self.cam.count("requests")
            if not self._authorized(method):
                return
            routes = dict(self.ROUTES_COMMON)
            if self.cam.firmware == "vapix3":
                routes.update(self.ROUTES_VAPIX3)
            name = routes.get(path)
            if name is None:
                self._send(404, _BODY_404, "text/html")
                return
            getattr(self, "_" + name)(method)
        except _Reject as exc:
            self._send(400, f"Error: {exc}\r\n")

    def _authorized(self, method: str) -> bool:
        result = self.cam.auth.check(method, self.headers.get("Authorization"), self.path)
        if result.ok and not self.cam.faults.reject_auth:
            return True
        self.cam.count("auth_failures")
        challenge = self.cam.auth.challenge(stale=result.stale and not self.cam.faults.reject_auth)
        self._send(401, _BODY_401, "text/html", (f"WWW-Authenticate: {challenge}",))
        return False

    # --- images -----------------------------------------------------------------------
    def _image_args(self) -> tuple[int, int, int]:
        """(width, height, JPEG quality) from resolution= and compression=."""
        res = self.query.get("resolution") or self.cam.params.get("Image.I0.Appearance.Resolution")
        if res.lower() not in self.cam.resolutions:
            raise _Reject(f"resolution {res} is not supported; supported: {','.join(self.cam.resolutions)}")
        width, height = (int(v) for v in res.lower().split("x"))
        comp = self.query.get("compression") or self.cam.params.get("Image.I0.Appearance.Compression")
        if not comp.isdigit() or int(comp) > 100:
            raise _Reject(f"compression must be 0-100, not {comp}")
        return width, height, 100 - int(comp)

    def _snapshot(self, method: str) -> None:
        width, height, quality = self._image_args()
        faults = self.cam.faults
        if faults.too_many_viewers:
            self._send(503, _BODY_503, "text/html")
            return
        index = self.cam.next_snapshot_index()
        jpeg = self.cam.frame(width, height, quality)
        self.cam.count("frames_served")
        self.cam.count("snapshots_served")
        if faults.torn_jpeg_at != index:
            self._send(200, jpeg, "image/jpeg")
        elif faults.torn_mode == "short":
            self._send(200, jpeg[: len(jpeg) // 2], "image/jpeg")
        else:  # cut: announce the whole JPEG, send half, die
            head = (f"HTTP/1.1 200 OK\r\nDate: {formatdate(usegmt=True)}\r\nContent-Type: image/jpeg\r\n"
                    f"Content-Length: {len(jpeg)}\r\nConnection: close\r\n\r\n").encode("latin-1")
            self.wfile.write(head + jpeg[: len(jpeg) // 2])
            self._hang_up()

    def _stream(self, method: str) -> None:
        width, height, quality = self._image_args()
        fps = _number(self.query.get("fps") or self.cam.params.get("Image.I0.Stream.FPS"), "fps")
        fps = min(fps, MAX_FPS) if fps > 0 else DEFAULT_FPS
        duration = _number(self.query.get("duration", "0"), "duration")
        nbr = _number(self.query.get("nbrofframes", "0"), "nbrofframes")
        faults = self.cam.faults
        if faults.too_many_viewers or (faults.max_viewers is not None
                                       and self.cam.counter("active_streams") >= faults.max_viewers):
            self._send(503, _BODY_503, "text/html")
            return
        self.cam.count("active_streams")
        try:
            self.close_connection = True
            self.wfile.write(_STREAM_HEADER)
            _StreamWriter(self, width, height, quality, fps, duration, int(nbr)).run()
        finally:
            self.cam.count("active_streams", -1)

    # --- parameters, I/O, device info, time ---------------------------------------------
    def _param_view(self, method: str) -> None:
        self._param(method, writable=False)

    def _param_admin(self, method: str) -> None:
        self._param(method, writable=True)

    def _param(self, method: str, writable: bool) -> None:
        if method == "POST" and self.body:  # VAPIX also takes the arguments as a form body
            self.query_pairs += _pairs(self.body.decode("latin-1"))
            self.query.update(dict(self.query_pairs))
        action = self.query.get("action", "")
        if action == "list":
            self._send(200, self.cam.params.list(self.query.get("group")))
        elif action == "update" and writable:
            changes = [(k, v) for k, v in self.query_pairs if k != "action"]
            self._send(200, self.cam.params.update(changes) if changes else "# Error: No parameters to update\r\n")
        elif action == "update":
            self._send(200, "# Error: update needs /axis-cgi/admin/param.cgi\r\n")
        else:
            self._send(200, f"# Error: Unknown action '{action}'\r\n")

    def _io_port(self, method: str) -> None:
        if "checkactive" in self.query:
            state = "active" if self.cam.source.led_on() else "inactive"
            self._send(200, f"port1={state}\r\n")
            return
        action = self.query.get("action", "")
        port, _, command = action.partition(":")
        if port != "1":
            self._send(200, f"# Error: Invalid port '{port}': this camera has one output, port 1\r\n")
            return
        if command == "/":
            self.cam.source.set_led(True)
        elif command == "\\":
            self.cam.source.set_led(False)
        elif len(command) > 2 and command[0] == "/" and command[-1] == "\\" and command[1:-1].isdigit():
            self.cam.source.pulse_led(int(command[1:-1]) / 1000.0)
        else:
            self._send(200, f"# Error: Invalid action '{action}'\r\n")
            return
        self._send(200, "OK\r\n")

    def _device_info(self, method: str) -> None:
        request = self._json_request(method)
        if request is None:
            return
        p = self.cam.params
        props = {key: p.get(name) for key, name in _DEVICE_INFO.items()}
        props["Architecture"] = "armv7hf"
        method_name = request.get("method")
        if method_name in ("getAllProperties", "getAllUnrestrictedProperties"):
            self._json_reply(request, {"data": {"propertyList": props}})
        elif method_name == "getProperties":
            wanted = (request.get("params") or {}).get("propertyList") or []
            self._json_reply(request, {"data": {"propertyList": {k: props[k] for k in wanted if k in props}}})
        elif method_name == "getSupportedVersions":
            self._json_reply(request, {"data": {"apiVersions": ["1.0"]}})
        else:
            self._json_reply(request, _unsupported(request))

    def _time_api(self, method: str) -> None:
        request = self._json_request(method)
        if request is None:
            return
        if request.get("method") == "getDateTimeInfo":
            t = datetime.fromtimestamp(self.cam.source.camera_time(), timezone.utc)
            iso = t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"
            self._json_reply(request, {"data": {"dateTime": iso, "localDateTime": iso, "dstEnabled": False,
                                                "timeZone": "Etc/UTC", "posixTimeZone": "UTC0"}})
        elif request.get("method") == "getSupportedVersions":
            self._json_reply(request, {"data": {"apiVersions": ["1.0"]}})
        else:
            self._json_reply(request, _unsupported(request))

    def _date(self, method: str) -> None:
        if self.query.get("action") != "get":
            self._send(200, f"# Error: Unknown action '{self.query.get('action', '')}'\r\n")
            return
        t = datetime.fromtimestamp(self.cam.source.camera_time(), timezone.utc)
        self._send(200, f"{_MONTHS[t.month - 1]} {t.day:02d}, {t.year} {t:%H:%M:%S}\r\n")

    def _json_request(self, method: str) -> dict | None:
        if method != "POST":
            self._send(405, "Error: use POST with a JSON body\r\n", headers=("Allow: POST",))
            return None
        try:
            request = json.loads(self.body or b"{}")
            if not isinstance(request, dict):
                raise ValueError("not an object")
        except ValueError:
            self._send(200, json.dumps({"apiVersion": "1.0", "error": {"code": 4002, "message": "Invalid JSON"}}),
                       "application/json")
            return None
        return request

    def _json_reply(self, request: dict, payload: dict) -> None:
        reply = {"apiVersion": request.get("apiVersion", "1.0")}
        if "context" in request:
            reply["context"] = request["context"]
        reply.update(payload)
        self._send(200, json.dumps(reply), "application/json")

    # --- control endpoint (not VAPIX) ---------------------------------------------------
    def _control(self, method: str, path: str) -> None:
        if not ip_address(self.client_address[0]).is_loopback:
            self._send(403, "loopback only\r\n")
            return
        try:
            if path == "/sim/faults" and method == "GET":
                reply = self.cam.faults.to_dict()
            elif path == "/sim/faults" and method == "POST":
                changes = json.loads(self.body or b"{}")
                if not isinstance(changes, dict):
                    raise ValueError("the body must be a JSON object of fault fields")
                self.cam.set_faults(reset=self.query.get("reset") in ("1", "true"), **changes)
                reply = self.cam.faults.to_dict()
            elif path == "/sim/state" and method == "GET":
                reply = self.cam.state()
            else:
                self._send(404, json.dumps({"error": f"no {method} {path}"}), "application/json")
                return
        except ValueError as exc:
            self._send(400, json.dumps({"error": str(exc)}), "application/json")
            return
        self._send(200, json.dumps(reply), "application/json")


class _StreamWriter:
    """Sends the parts of one MJPEG stream, paced on the camera clock, applying the faults."""

    def __init__(self, handler: _Handler, width: int, height: int, quality: int, fps: float,
                 duration: float, nbrofframes: int):
        self.h, self.cam = handler, handler.cam
        self.size, self.quality = (width, height), quality
        self.period, self.duration, self.nbr = 1.0 / fps, duration, nbrofframes

    def run(self) -> None:
        faults, clock = self.cam.faults, self.cam.clock
        start = clock.now()
        t0 = self._next_tick(start)
        stalled = False
        k = 0
        while not self.nbr or k < self.nbr:
            target = t0 + k * self.period
            if self.duration and target - start >= self.duration:
                return
            if not self.cam.sleep_until(target):
                return
            if clock.now() - target > self.period:  # fell behind (stall, slow client): go on live
                t0 = self._next_tick(clock.now()) - k * self.period
                continue
            if faults.offline or (faults.drop_after_frames is not None and k >= faults.drop_after_frames):
                self.h._hang_up()
                return
            if not stalled and faults.stall_after_frames is not None and k >= faults.stall_after_frames:
                stalled = True
                if not self.cam.sleep_until(clock.now() + faults.stall_s):
                    return
                continue
            if not self._send_part(k):
                return
            k += 1

    def _next_tick(self, t: float) -> float:
        """The first frame time at or after ``t`` on the sensor's grid (multiples of the
        period), so that frames of successive streams share one time grid, as a camera's do."""
        return math.ceil(t / self.period) * self.period

    def _send_part(self, k: int) -> bool:
        """Write part ``k``; False when the connection was deliberately cut."""
        faults = self.cam.faults
        jpeg = self.cam.frame(*self.size, self.quality)
        body, stated, cut = jpeg, len(jpeg), False
        if faults.torn_jpeg_at == k:
            body = jpeg[: len(jpeg) // 2]
            cut = faults.torn_mode == "cut"
            stated = len(jpeg) if cut else len(body)
        if faults.wrong_content_length_at == k:
            stated += faults.wrong_content_length_extra
        head = f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
        if not faults.missing_content_length:
            head += f"Content-Length: {stated}\r\n"
        data = head.encode("ascii") + b"\r\n" + body + (b"" if cut else b"\r\n")
        self.h.wfile.write(data)
        self.cam.count("frames_served")
        if cut:
            self.h._hang_up()
            return False
        return True


def _unsupported(request: dict) -> dict:
    return {"error": {"code": 2002, "message": f"Method not supported: {request.get('method')}"}}


def _number(text: str, name: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise _Reject(f"{name} must be a number, not {text}") from None
    if value < 0:
        raise _Reject(f"{name} must not be negative")
    return value


def _pairs(query: str) -> list[tuple[str, str]]:
    """Query pairs in order (param.cgi updates are applied in the order given)."""
    return parse_qsl(query, keep_blank_values=True)
