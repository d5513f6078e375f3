"""The request handler of a simulated Axis camera: VAPIX CGIs, authentication, control endpoint.

Which CGIs exist is the camera's model profile's business (:mod:`.axis_params`): a path the
firmware does not have is a 404, as on the real camera. Every byte of every response is written
here (or in :mod:`.axis_streaming` for images), so that faults can get the wire wrong on purpose.
"""

from __future__ import annotations

import hashlib
import json
import socket
from datetime import UTC, datetime
from email.utils import formatdate
from http.server import BaseHTTPRequestHandler
from ipaddress import ip_address
from typing import TYPE_CHECKING
from urllib.parse import parse_qs, parse_qsl, urlsplit

from vts_hw.sim_devices import axis_time
from vts_hw.sim_devices.axis_streaming import Reject, serve_snapshot, serve_stream, trickle

if TYPE_CHECKING:
    from vts_hw.sim_devices.axis_camera import SimAxisCamera, _Server

_MONTHS = ("Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec")
_HTML = (
    "<HTML><HEAD><TITLE>{code} {reason}</TITLE></HEAD>\r\n"
    "<BODY><H1>{code} {reason}</H1>\r\n{text}\r\n</BODY></HTML>\r\n"
)
_BODY_401 = _HTML.format(
    code=401, reason="Unauthorized", text="Your client does not have permission to get this URL from this server."
)
_BODY_404 = _HTML.format(code=404, reason="Not Found", text="The requested URL was not found on this server.")
_DEVICE_INFO = {  # basicdeviceinfo.cgi property -> parameter
    "Architecture": "Properties.System.Architecture",
    "Brand": "Brand.Brand",
    "BuildDate": "Properties.Firmware.BuildDate",
    "HardwareID": "Properties.System.HardwareID",
    "ProdFullName": "Brand.ProdFullName",
    "ProdNbr": "Brand.ProdNbr",
    "ProdShortName": "Brand.ProdShortName",
    "ProdType": "Brand.ProdType",
    "ProdVariant": "Brand.ProdVariant",
    "SerialNumber": "Properties.System.SerialNumber",
    "Soc": "Properties.System.Soc",
    "Version": "Properties.Firmware.Version",
    "WebURL": "Brand.WebURL",
}
_REASONS = {
    200: "OK",
    400: "Bad Request",
    401: "Unauthorized",
    403: "Forbidden",
    404: "Not Found",
    405: "Method Not Allowed",
    503: "Service Unavailable",
}
DESCRIPTION_PATH = "/rootdesc1.xml"  # the UPnP device description an SSDP answer points to
ROUTES = {  # path -> handler method; a path answers only when the model profile lists it
    "/axis-cgi/jpg/image.cgi": "snapshot",
    "/axis-cgi/mjpg/video.cgi": "stream",
    "/axis-cgi/param.cgi": "param_admin",
    "/axis-cgi/view/param.cgi": "param_view",
    "/axis-cgi/admin/param.cgi": "param_admin",
    "/axis-cgi/io/port.cgi": "io_port",
    "/axis-cgi/io/output.cgi": "io_output",
    "/axis-cgi/io/input.cgi": "io_input",
    "/axis-cgi/date.cgi": "date",
    "/axis-cgi/admin/date.cgi": "date",
    "/axis-cgi/time.cgi": "time_api",
    "/axis-cgi/basicdeviceinfo.cgi": "device_info",
    "/axis-cgi/apidiscovery.cgi": "api_discovery",
    "/axis-cgi/usergroup.cgi": "user_group",
    "/axis-cgi/systemready.cgi": "system_ready",
    "/axis-cgi/serverreport.cgi": "server_report",
    "/axis-cgi/admin/serverreport.cgi": "server_report",
}


class Handler(BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"
    timeout = 60
    server: _Server
    query: dict[str, str]
    query_pairs: list[tuple[str, str]]
    body: bytes

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
        self.cam.log.debug("%s %s", self.address_string(), format % args)

    def do_GET(self) -> None:
        self._dispatch("GET")

    def do_POST(self) -> None:
        self._dispatch("POST")

    def send(
        self, status: int, body: bytes | str, content_type: str = "text/plain", headers: tuple[str, ...] = ()
    ) -> None:
        """Write a whole response; an old web server (profile or fault) answers HTTP/1.0 and closes."""
        if isinstance(body, str):
            body = body.encode("utf-8")
        old = self.cam.faults.close_after_response or self.cam.profile.close_after_response
        close = self.close_connection or old
        lines = [
            f"{'HTTP/1.0' if old else 'HTTP/1.1'} {status} {_REASONS.get(status, '')}",
            f"Date: {formatdate(usegmt=True)}",
            f"Content-Type: {content_type}",
            f"Content-Length: {len(body)}",
            *headers,
        ]
        if close:
            lines.append("Connection: close")
        self.wfile.write(("\r\n".join(lines) + "\r\n\r\n").encode("latin-1") + body)
        self.close_connection = close

    def hang_up(self) -> None:
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
        self.query_pairs = parse_qsl(split.query, keep_blank_values=True)
        self.body = self._read_body()
        try:
            if path.startswith("/sim/"):
                self._control(method, path)
                return
            if path == DESCRIPTION_PATH and self.cam.announced:  # UPnP: no authentication
                self.send(200, self.cam.description_xml(self.headers.get("Host", "")), 'text/xml; charset="utf-8"')
                return
            if not path.startswith("/axis-cgi/"):
                self.send(404, _BODY_404, "text/html")
                return
            if self.cam.offline_now():
                self.hang_up()
                return
            self.cam.count("requests")
            if not (path in axis_time.NO_AUTH and path in self.cam.profile.cgis) and not self._authorized(method):
                return
            if self.cam.faults.trickle:
                trickle(self, path)
                return
            name = ROUTES.get(path) if path in self.cam.profile.cgis else None
            if name is None:
                self.send(404, _BODY_404, "text/html")
                return
            getattr(self, "_" + name)(method)
        except Reject as exc:
            self.send(400, f"Error: {exc}\r\n")

    def _authorized(self, method: str) -> bool:
        result = self.cam.auth.check(method, self.headers.get("Authorization"), self.path)
        if result.ok and not self.cam.faults.reject_auth:
            return True
        self.cam.count("auth_failures")
        challenge = self.cam.auth.challenge(stale=result.stale and not self.cam.faults.reject_auth)
        self.send(401, _BODY_401, "text/html", (f"WWW-Authenticate: {challenge}",))
        return False

    # --- images -----------------------------------------------------------------------
    def _snapshot(self, method: str) -> None:
        serve_snapshot(self)

    def _stream(self, method: str) -> None:
        serve_stream(self)

    # --- parameters -------------------------------------------------------------------
    def _param_view(self, method: str) -> None:
        self._param(method, writable=False)

    def _param_admin(self, method: str) -> None:
        self._param(method, writable=True)

    def _param(self, method: str, writable: bool) -> None:
        if method == "POST" and self.body:  # VAPIX also takes the arguments as a form body
            self.query_pairs += parse_qsl(self.body.decode("latin-1").strip(), keep_blank_values=True)
            self.query.update(dict(self.query_pairs))
        action = self.query.get("action", "")
        if action == "list":
            self.send(200, self.cam.params.list(self.query.get("group")))
        elif action == "update" and writable:
            changes = [(k, v) for k, v in self.query_pairs if k != "action"]
            self.send(200, self.cam.params.update(changes) if changes else "# Error: No parameters to update\r\n")
        elif action == "update":
            self.send(200, "# Error: update needs /axis-cgi/admin/param.cgi\r\n")
        else:
            self.send(200, f"# Error: Unknown action '{action}'\r\n")

    # --- I/O: port.cgi (VAPIX 3), output.cgi and input.cgi (VAPIX 2) -----------------------
    def _drive_output(self, action: str) -> str | None:
        """Apply ``<port>:<command>`` to the LED output (port 1); None, or the error text."""
        port, _, command = action.partition(":")
        if port != "1":
            return f"# Error: Invalid port '{port}': this camera has one output, port 1\r\n"
        if self.cam.faults.led_held and command and (command[0] in "/\\"):
            return None  # answered OK, and the output stays as it was (a rule on the camera holds it)
        if command == "/":
            self.cam.source.set_led(True)
        elif command == "\\":
            self.cam.source.set_led(False)
        elif len(command) > 2 and command[0] == "/" and command[-1] == "\\" and command[1:-1].isdigit():
            self.cam.source.pulse_led(int(command[1:-1]) / 1000.0)
        else:
            return f"# Error: Invalid action '{action}'\r\n"
        return None

    def _check(self, ports: str, line) -> None:
        """Answer a state query of ``ports`` (``1`` or ``1,2``): one ``line(port)`` each, as the firmware."""
        asked = ports.split(",")
        bad = next((p for p in asked if p not in ("1", "2")), None)
        if bad is not None:
            self.send(200, f"# Error: Invalid port '{bad}'\r\n")
            return
        self.send(200, "".join(line(p) + "\r\n" for p in asked))

    def _io_port(self, method: str) -> None:
        if "checkactive" in self.query:  # port 1: the LED's output; port 2: an input, open
            self._check(
                self.query["checkactive"],
                lambda p: f"port{p}=" + ("active" if p == "1" and self.cam.source.led_on() else "inactive"),
            )
            return
        error = self._drive_output(self.query.get("action", ""))
        self.send(200, error or "OK\r\n")

    def _io_output(self, method: str) -> None:
        if "check" in self.query:
            if self.query["check"] != "1":
                self.send(200, f"# Error: Invalid output '{self.query['check']}'\r\n")
                return
            self.send(200, f"output1={int(bool(self.cam.source.led_on()))}\r\n")
            return
        error = self._drive_output(self.query.get("action", ""))
        self.send(200, error or "OK\r\n")

    def _io_input(self, method: str) -> None:
        if self.query.get("check") != "1":
            self.send(200, f"# Error: Invalid input '{self.query.get('check', '')}'\r\n")
            return
        self.send(200, "input1=0\r\n")

    # --- identity, users, time -----------------------------------------------------------
    def _device_info(self, method: str) -> None:
        request = self._json_request(method)
        if request is None:
            return
        p = self.cam.params
        props = {key: p.find(name) or "" for key, name in _DEVICE_INFO.items()}
        serial = props["SerialNumber"]
        soc_serial = hashlib.sha256(serial.encode()).hexdigest()[:32].upper()
        props["SocSerialNumber"] = "-".join(soc_serial[i : i + 8] for i in range(0, 32, 8))
        method_name = request.get("method")
        if method_name in ("getAllProperties", "getAllUnrestrictedProperties"):
            self._json_reply(request, {"data": {"propertyList": props}})
        elif method_name == "getProperties":
            wanted = (request.get("params") or {}).get("propertyList") or []
            self._json_reply(request, {"data": {"propertyList": {k: props[k] for k in wanted if k in props}}})
        elif method_name == "getSupportedVersions":
            self._json_reply(request, {"data": {"apiVersions": ["1.0", "1.1"]}})
        else:
            self._json_reply(request, _unsupported(request))

    def _api_discovery(self, method: str) -> None:
        request = self._json_request(method)
        if request is None:
            return
        if request.get("method") == "getApiList":
            apis = [dict(api, status=api.get("status", "official")) for api in self.cam.profile.apis]
            self._json_reply(request, {"data": {"apiList": apis}})
        elif request.get("method") == "getSupportedVersions":
            self._json_reply(request, {"data": {"apiVersions": ["1.0"]}})
        else:
            self._json_reply(request, _unsupported(request))

    def _user_group(self, method: str) -> None:
        self.send(200, f"{self.cam.auth.user}\nadmin operator viewer\n")

    def _time_api(self, method: str) -> None:
        axis_time.time_api(self, method)

    def _system_ready(self, method: str) -> None:
        axis_time.system_ready(self, method)

    def _server_report(self, method: str) -> None:
        axis_time.server_report(self, method)

    def _date(self, method: str) -> None:
        if self.query.get("action") != "get":
            self.send(200, f"# Error: Unknown action '{self.query.get('action', '')}'\r\n")
            return
        t = datetime.fromtimestamp(self.cam.camera_time(), UTC)
        self.send(200, f"{_MONTHS[t.month - 1]} {t.day:02d}, {t.year} {t:%H:%M:%S}\r\n")

    def _json_request(self, method: str) -> dict | None:
        if method != "POST":
            self.send(405, "Error: use POST with a JSON body\r\n", headers=("Allow: POST",))
            return None
        try:
            request = json.loads(self.body or b"{}")
            if not isinstance(request, dict):
                raise ValueError("not an object")
        except ValueError:
            self.send(
                200,
                json.dumps({"apiVersion": "1.0", "error": {"code": 4000, "message": "Invalid JSON"}}),
                "application/json",
            )
            return None
        return request

    def _json_reply(self, request: dict, payload: dict) -> None:
        reply = {"apiVersion": request.get("apiVersion", "1.0")}
        if "context" in request:
            reply["context"] = request["context"]
        reply["method"] = request.get("method", "")
        reply.update(payload)
        self.send(200, json.dumps(reply), "application/json")

    # --- control endpoint (not VAPIX) ---------------------------------------------------
    def _control(self, method: str, path: str) -> None:
        if not ip_address(self.client_address[0]).is_loopback:
            self.send(403, "loopback only\r\n")
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
            elif path == "/sim/optics" and hasattr(self.cam.source, "set_optics"):
                reply = self._optics(method)  # focus and mount (sim_devices/optics.py)
            else:
                self.send(404, json.dumps({"error": f"no {method} {path}"}), "application/json")
                return
        except ValueError as exc:
            self.send(400, json.dumps({"error": str(exc)}), "application/json")
            return
        self.send(200, json.dumps(reply), "application/json")

    def _optics(self, method: str) -> dict:
        """GET: the camera's focus and mount; POST a JSON object of changes (``focus_blur_px``,
        ``yaw_deg``, ``pitch_deg``): all applied or none (400 saying why)."""
        if method == "GET":
            return self.cam.source.optics()
        changes = json.loads(self.body or b"{}")
        if not isinstance(changes, dict):
            raise ValueError("the body must be a JSON object of optics settings")
        return self.cam.source.set_optics(**changes)


def _unsupported(request: dict) -> dict:
    return {"error": {"code": 2004, "message": f"Method not supported: {request.get('method')}"}}
