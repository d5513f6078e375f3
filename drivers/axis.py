"""Axis network camera over VAPIX: the ``axis`` kind, composed of one module per job.

:class:`AxisCamera` is the HTTP client (:mod:`.axis_client`: session, authentication, timeouts,
typed errors) with every role of :mod:`vts_hw.camera`: frames (snapshots here, the stream in
:mod:`.axis_stream`), device information (here), parameters (:mod:`.axis_params`), the LED on
the I/O port (:mod:`.axis_io`), the clock and uptime (:mod:`.axis_clock`); its set-up is
:mod:`.axis_setup`. The typed errors of :mod:`.axis_errors` are re-exported here.

Old firmware (VAPIX 2, e.g. an AXIS 211 on 4.4x) is told apart by a 404 on ``param.cgi`` and is
answered on its own paths: ``view/`` and ``admin/param.cgi``, ``io/output.cgi`` for the LED (and its state),
the Brand and Properties parameters for the device info, the JPEG stamps for the clock.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from vts_hw.camera import ClockOffset, Frame, check_whole, kind_settings
from vts_hw.drivers.axis_clock import AxisClock
from vts_hw.drivers.axis_errors import (
    NOT_THE_JSON,
    AxisError,
    BadReply,
    CameraUnauthorized,
    CameraUnreachable,
    NotFound,
    Refused,
    TooManyViewers,
)
from vts_hw.drivers.axis_io import AxisIOPort
from vts_hw.drivers.axis_setup import AxisSetup
from vts_hw.drivers.axis_stream import HTTP_KEYS, HttpCamera
from vts_hw.recording.axis_jpeg import inspect_jpeg

if TYPE_CHECKING:
    pass

AxisSettings = kind_settings(
    "AxisSettings",
    "An Axis camera over VAPIX (the default kind): its address, credentials (the password "
    "from the environment variable `password_env` names), the I/O port of its LED ring, its image; no "
    "`options:`.",
    HTTP_KEYS,
    required=("host",),
)


def frame_from_bytes(seq: int, jpeg: bytes, host_time: float, problems=()) -> Frame:
    """A Frame with the camera time read from the JPEG's Axis segment (None if absent)."""
    probs = list(problems)
    cam_t = None
    try:
        info = inspect_jpeg(jpeg)
        cam_t = info.timestamp
        probs += [p for p in info.problems if p not in probs and "product" not in p]
    except Exception as exc:  # not a JPEG at all
        probs.append(str(exc))
    return Frame(seq, jpeg, cam_t, host_time, tuple(probs))


class AxisCamera(HttpCamera, AxisClock, AxisIOPort, AxisSetup):
    """One Axis camera: the ``axis`` kind, with every role of :mod:`vts_hw.camera` (the HTTP camera
    of :mod:`.axis_stream`, its parameters, clock, I/O port and setup are the mixins over its client).

    ``AxisCamera.from_config(cfg)`` takes a rig.yaml camera entry and its password from the
    environment variable that entry names (``vts_hw.drivers.registry.open_camera`` calls it).
    """

    settings = AxisSettings

    # -- frames (the stream: HttpCamera's) ------------------------------------------
    def snapshot(self, compression: int | None = None) -> Frame:
        """One JPEG from ``jpg/image.cgi``, with its camera time and host receive time.

        ``compression`` (0-100, VAPIX) overrides the configured one for this request only: the
        camera's own settings, and so its stream, are left as they are."""
        comp = self.compression if compression is None else int(compression)
        if not 0 <= comp <= 100:
            raise ValueError(f"compression must be 0-100, not {comp}")
        r = self.request("GET", "/axis-cgi/jpg/image.cgi", params={"resolution": self.resolution, "compression": comp})
        data = r.content
        host_t = self.clock()
        ctype = r.headers.get("content-type", "")
        if not data.startswith(b"\xff\xd8"):
            raise BadReply(self.name, f"camera {self.name} sent {ctype or 'data'} instead of a JPEG")
        frame = frame_from_bytes(0, data, host_t)
        check_whole(frame, self.name)
        return frame

    def make_frame(self, seq: int, jpeg: bytes, host_time: float, problems=()) -> Frame:
        """A received JPEG as a Frame, timed by its Axis stamp."""
        return frame_from_bytes(seq, jpeg, host_time, problems)

    # -- device information -------------------------------------------------------------
    def device_info(self) -> dict[str, str]:
        """Brand, product, serial number and firmware: basicdeviceinfo.cgi, else param groups."""
        try:
            r = self.request(
                "POST", "/axis-cgi/basicdeviceinfo.cgi", json_body={"apiVersion": "1.0", "method": "getAllProperties"}
            )
            props = r.json()["data"]["propertyList"]
            return {k: str(v) for k, v in props.items()}
        except NotFound:
            pass
        except NOT_THE_JSON:
            raise BadReply(self.name, f"camera {self.name} sent device info that is not the expected JSON") from None
        info = {k.removeprefix("Brand."): v for k, v in self.get_params("Brand").items()}
        props = self.get_params("Properties")
        for key, name in _DEVICE_INFO_PARAMS.items():
            if name in props:
                info[key] = props[name]
        return info


_DEVICE_INFO_PARAMS = {  # basicdeviceinfo.cgi property -> parameter, for firmware without it
    "Version": "Properties.Firmware.Version",
    "BuildDate": "Properties.Firmware.BuildDate",
    "SerialNumber": "Properties.System.SerialNumber",
    "HardwareID": "Properties.System.HardwareID",
    "Architecture": "Properties.System.Architecture",
    "Soc": "Properties.System.Soc",
}


__all__ = [
    "AxisCamera",
    "AxisSettings",
    "HTTP_KEYS",
    "AxisError",
    "CameraUnreachable",
    "CameraUnauthorized",
    "TooManyViewers",
    "BadReply",
    "NotFound",
    "Refused",
    "Frame",
    "ClockOffset",
    "frame_from_bytes",
]
