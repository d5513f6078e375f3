"""An Axis camera's clock: its offset from the host's, and how long it has run.

The offset comes from ``time.cgi`` where the firmware has it, else from the 10 ms stamps of
snapshots; the uptime from :mod:`.axis_uptime`. :class:`AxisClock` is the
:class:`~vts_hw.camera.CameraClock` and :class:`~vts_hw.camera.RunningTime` roles of an Axis
camera (over its parameters, with its frames).
"""

from __future__ import annotations

import statistics
from collections.abc import Callable
from datetime import UTC, datetime

from vts_hw.camera import ClockOffset, Frame, Uptime
from vts_hw.drivers.axis_errors import NOT_THE_JSON, BadReply, NotFound
from vts_hw.drivers.axis_params import AxisParameters
from vts_hw.drivers.axis_uptime import read_uptime


class AxisClock(AxisParameters):
    """``clock_offset()`` and ``uptime()``, over the camera's parameters (the VAPIX version tells
    where its server report is) and its snapshots (the stamps, on firmware without ``time.cgi``)."""

    snapshot: Callable[[], Frame]  # the camera's own (AxisCamera.snapshot)

    def uptime(self) -> Uptime:
        """How long the camera has run since it started (drivers/axis_uptime.py)."""
        return read_uptime(self)

    def clock_offset(self, samples: int = 5) -> ClockOffset:
        """Camera clock minus host clock.

        From ``time.cgi`` (ms resolution, midpoint of the round trip, best of ``samples``)
        where the camera has it, else from the 10 ms stamps of snapshots (each stamp is
        taken before the image is sent, so the offset is biased low by up to the exposure
        and encode time; the uncertainty says so).
        """
        if samples < 1:  # (a median of no snapshot: refused before anything is asked)
            raise ValueError(f"clock_offset takes one sample or more, not {samples}")
        best = None
        try:
            for _ in range(samples):
                t0 = self.clock()
                r = self.request(
                    "POST", "/axis-cgi/time.cgi", json_body={"apiVersion": "1.0", "method": "getDateTimeInfo"}
                )
                t1 = self.clock()
                cam = _parse_iso(r.json()["data"]["dateTime"])
                rtt = t1 - t0
                if best is None or rtt < best[1]:
                    best = (cam - (t0 + t1) / 2, rtt, (t0 + t1) / 2)
            if best is not None:  # (always, samples >= 1: said for the type checker)
                return ClockOffset(best[0], best[1] / 2 + 0.001, best[2], "time.cgi", samples)
        except NotFound:
            pass
        except NOT_THE_JSON:
            raise BadReply(
                self.name, f"camera {self.name} sent time.cgi JSON without a readable data.dateTime"
            ) from None
        offsets, rtts = [], []
        for _ in range(samples):
            t0 = self.clock()
            f = self.snapshot()
            if f.camera_time is None:
                raise BadReply(self.name, f"camera {self.name} sends JPEGs without the Axis time segment")
            offsets.append(f.camera_time - t0)
            rtts.append(f.host_time - t0)
        return ClockOffset(statistics.median(offsets), max(rtts) + 0.01, self.clock(), "snapshot", samples)


def _parse_iso(s: str) -> float:
    s = s.strip().replace("Z", "+00:00")
    dt = datetime.fromisoformat(s)
    if dt.tzinfo is None:
        dt = dt.replace(tzinfo=UTC)
    return dt.timestamp()


__all__ = ["AxisClock"]
