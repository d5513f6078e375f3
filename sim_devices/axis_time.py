"""The simulated camera's clock, time zone and uptime, as the firmware of its profile answers them.

* ``POST /axis-cgi/time.cgi`` (current firmware, the Time API): ``getDateTimeInfo``,
  ``setTimeZone`` (an IANA name, refused with an error object when the firmware does not know
  it), ``setPosixTimeZone``; the zone set is the ``Time.TimeZone`` parameter too, as
  ``param.cgi`` then lists it.
* ``POST /axis-cgi/systemready.cgi`` (AXIS OS 9.50 and later, no authentication): ready, and
  the ``uptime`` in whole seconds.
* ``GET /axis-cgi/admin/serverreport.cgi`` (firmware 4.x) and ``/axis-cgi/serverreport.cgi``:
  a text report holding, among other lines, the busybox ``uptime`` line
  (`` 10:15:21 up 3 days,  2:01, load average: ...``), minutes resolution.

The camera started ``SimAxisCamera.booted_at`` (sim clock; a day before the camera was made,
unless ``uptime_s`` says otherwise; ``reboot()`` starts it now).
"""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import TYPE_CHECKING

from vts_hw.sim_devices.axis_params import _TZ_POSIX, valid_time_zone

if TYPE_CHECKING:
    from vts_hw.sim_devices.axis_http import Handler

NO_AUTH = frozenset({"/axis-cgi/systemready.cgi"})  # answered without credentials, as the firmware does


def time_api(h: Handler, method: str) -> None:
    request = h._json_request(method)
    if request is None:
        return
    name = request.get("method")
    given = request.get("params")
    params = given if isinstance(given, dict) else {}
    store = h.cam.params
    if name == "getDateTimeInfo":
        t = datetime.fromtimestamp(h.cam.camera_time(), UTC)
        iso = t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"
        h._json_reply(
            request,
            {
                "data": {
                    "dateTime": iso,
                    "localDateTime": iso,
                    "dstEnabled": store.find("Time.DST.Enabled") == "yes",
                    "timeZone": store.find("Time.TimeZone") or "Etc/UTC",
                    "posixTimeZone": store.find("Time.POSIXTimeZone") or "UTC0",
                }
            },
        )
    elif name == "setTimeZone":
        zone = params.get("timeZone")
        if not isinstance(zone, str) or "/" not in zone and zone != "UTC" or not valid_time_zone(zone):
            h._json_reply(request, _error(2002, f"Invalid time zone: {zone}"))
            return
        store.update([("Time.TimeZone", zone)])
        h._json_reply(request, {"data": {}})
    elif name == "setPosixTimeZone":
        zone = params.get("posixTimeZone")
        dst = params.get("dstEnabled", False)
        if not isinstance(zone, str) or not _TZ_POSIX.match(zone) or not isinstance(dst, bool):
            h._json_reply(request, _error(2002, f"Invalid POSIX time zone: {zone}"))
            return
        store.update([("Time.POSIXTimeZone", zone), ("Time.DST.Enabled", "yes" if dst else "no")])
        h._json_reply(request, {"data": {}})
    elif name == "getSupportedVersions":
        h._json_reply(request, {"data": {"apiVersions": ["1.0"]}})
    else:
        h._json_reply(request, _error(2004, f"Method not supported: {name}"))


def system_ready(h: Handler, method: str) -> None:
    request = h._json_request(method)
    if request is None:
        return
    if request.get("method") == "systemready":
        h._json_reply(
            request,
            {
                "data": {
                    "systemready": "yes",
                    "needsetup": "no",
                    "uptime": str(int(uptime_s(h))),
                    "bootid": str(uuid.UUID(int=int(h.cam.booted_at * 1000) & (2**128 - 1))),
                }
            },
        )
    elif request.get("method") == "getSupportedVersions":
        h._json_reply(request, {"data": {"apiVersions": ["1.4"]}})
    else:
        h._json_reply(request, _error(2004, f"Method not supported: {request.get('method')}"))


def server_report(h: Handler, method: str) -> None:
    p = h.cam.params
    now = datetime.fromtimestamp(h.cam.camera_time(), UTC)
    lines = [
        "----- Server Report Start -----",
        f"Product: {p.find('Brand.ProdFullName')}",
        f"Firmware version: {p.find('Properties.Firmware.Version')}",
        f"Serial number: {p.find('Properties.System.SerialNumber')}",
        "",
        "----- Uptime -----",
        f" {now:%H:%M:%S} up {busybox_uptime(uptime_s(h))}, load average: 0.08, 0.03, 0.01",
        "",
        "----- Server Report End -----",
    ]
    h.send(200, "\r\n".join(lines) + "\r\n")


def uptime_s(h: Handler) -> float:
    return max(0.0, h.cam.clock.now() - h.cam.booted_at)


def busybox_uptime(seconds: float) -> str:
    """``3 days,  2:01`` / ``12 min`` / ``1 day, 0 min``: how busybox's uptime says it."""
    days, rest = divmod(int(seconds), 86400)
    hours, minutes = rest // 3600, rest % 3600 // 60
    day_s = f"{days} day{'s' if days != 1 else ''}, " if days else ""
    return day_s + (f"{hours:2d}:{minutes:02d}" if hours else f"{minutes} min")


def _error(code: int, message: str) -> dict:
    return {"error": {"code": code, "message": message}}
