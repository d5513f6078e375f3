"""How long an Axis camera has been running: what the daily QA's warm-up check reads.

* Current firmware (AXIS OS 9.50 and later): ``POST /axis-cgi/systemready.cgi``
  ``{"method": "systemready"}`` answers ``data.uptime``, whole seconds as a string.
* Older firmware: the server report (``admin/serverreport.cgi`` on VAPIX 2, ``serverreport.cgi``
  on VAPIX 3) holds the output of busybox's ``uptime``: ``10:15:21 up 3 days,  2:01, load
  average ...`` (minutes resolution). The shape of that line is busybox's; a report without
  one says nothing of the uptime, and the uptime is then not known (never assumed).
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING

from vts_hw.camera import Uptime
from vts_hw.drivers.axis_errors import NOT_THE_JSON, BadReply, NotFound

if TYPE_CHECKING:
    from vts_hw.drivers.axis_clock import AxisClock

_UP = re.compile(r"\bup\s+(?:(\d+)\s+days?,\s*)?(?:(\d+):(\d{2})|(\d+)\s+min)")


class NoUptime(BadReply):
    """The camera does not tell its uptime (no API for it, or a report without it)."""

    retry = False


def read_uptime(cam: AxisClock) -> Uptime:
    try:
        r = cam.request("POST", "/axis-cgi/systemready.cgi", json_body={"apiVersion": "1.0", "method": "systemready"})
        try:
            return Uptime(float(int(r.json()["data"]["uptime"])), 1.0, "systemready.cgi")
        except NOT_THE_JSON:
            raise BadReply(
                cam.name, f"camera {cam.name} answered systemready.cgi without a readable data.uptime"
            ) from None
    except NotFound:
        pass
    path = "/axis-cgi/admin/serverreport.cgi" if cam.vapix_version == 2 else "/axis-cgi/serverreport.cgi"
    try:
        text = cam._text(path)
    except NotFound:
        raise NoUptime(
            cam.name, f"camera {cam.name} tells no uptime (neither systemready.cgi nor serverreport.cgi)"
        ) from None
    seconds = parse_busybox_uptime(text)
    if seconds is None:
        raise NoUptime(cam.name, f"camera {cam.name}'s server report has no uptime line")
    return Uptime(seconds, 60.0, path.rsplit("/", 1)[-1])


def parse_busybox_uptime(text: str) -> float | None:
    """Seconds from ``up 3 days,  2:01`` / ``up 12 min`` / ``up 1 day, 5 min`` (None: no such line)."""
    m = _UP.search(text)
    if not m:
        return None
    days = int(m.group(1) or 0)
    minutes = int(m.group(4)) if m.group(4) is not None else int(m.group(2)) * 60 + int(m.group(3))
    return float(days * 86400 + minutes * 60)


__all__ = ["NoUptime", "read_uptime", "parse_busybox_uptime"]
