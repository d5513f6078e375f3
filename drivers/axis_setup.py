"""Set an Axis camera up for the VTS and read back what it took (`vts camera setup`).

What is set (VAPIX parameters through ``param.cgi``, ``admin/param.cgi`` on VAPIX 2 firmware):

==========================================  ==================================================
``Image.I0.Appearance.Resolution``          the camera entry's resolution
``Image.I0.Stream.FPS``                     its frame rate (whole frames per second)
``Image.I0.Appearance.Compression``         its compression
``ImageSource.I0.Sensor.Exposure``          ``camera_setup.exposure`` (``hold``: shutter and gain held)
``ImageSource.I0.Sensor.WhiteBalance``      ``camera_setup.white_balance``
``...MaxExposureTime``, ``...MaxGain``      when given (else read and locked as they are, where they exist)
``Image.I0.Text.*Enabled``, ``Image.I0.Overlay.Enabled``   ``no``: nothing drawn into the image
``Time.SyncSource``, ``Time.NTP.Server``    ``NTP``, ``camera_setup.ntp_server`` (else the camera's, locked)
``Time.TimeZone``                           VAPIX 2: ``camera_setup.posix_time_zone`` as a parameter;
                                            current firmware: ``camera_setup.time_zone`` through the
                                            Time API (``time.cgi`` ``setTimeZone``), read back with
                                            ``getDateTimeInfo``
==========================================  ==================================================

The parameters go in one ``action=update`` (the firmware takes all or none); then every group is
listed again and each value compared. What was set and read back is the camera's
``locked_params`` (the daily QA checks exactly that). A value the camera refuses is
:class:`SetupRefused` naming the camera, the parameter, the value and the camera's own words.
"""

from __future__ import annotations

import re
from collections.abc import Callable

from vts_hw.camera import Refused as ContractRefused
from vts_hw.camera import SetupResult
from vts_hw.drivers.axis_errors import NOT_THE_JSON, AxisError, NotFound, Refused
from vts_hw.drivers.axis_params import AxisParameters

TIME_API = "/axis-cgi/time.cgi"
_ERROR_PARAM = re.compile(r"'(?:root\.)?([A-Za-z0-9_.]+)'")


class SetupRefused(AxisError, ContractRefused):
    """The camera refused a value (or lacks a parameter the VTS needs); exit 4."""

    retry = False


class AxisSetup(AxisParameters):
    """The :class:`~vts_hw.camera.Setup` role of an Axis camera: its parameters set for the VTS
    and read back (the functions below), a mixin of :class:`~vts_hw.drivers.axis.AxisCamera`."""

    device_info: Callable[[], dict[str, str]]  # the camera's own (AxisCamera.device_info)

    def setup_plan(self, cfg, setup) -> list[tuple[str, str, bool]]:
        return wanted(self, cfg, setup)

    def set_up(self, cfg, setup) -> SetupResult:
        return setup_camera(self, cfg, setup)


def wanted(cam: AxisSetup, cfg, setup) -> list[tuple[str, str, bool]]:
    """(parameter, value, required) to send, in order; ``cfg`` the camera entry, ``setup`` the
    rig's ``camera_setup``. A required parameter the firmware lacks is refused."""
    fps = cfg.fps
    out = [
        ("Image.I0.Appearance.Resolution", cfg.resolution_str, True),
        ("Image.I0.Stream.FPS", f"{fps:g}", True),
        ("Image.I0.Appearance.Compression", str(cfg.compression), True),
        ("ImageSource.I0.Sensor.Exposure", setup.exposure, True),
        ("ImageSource.I0.Sensor.WhiteBalance", setup.white_balance, True),
        ("Image.I0.Text.TextEnabled", "no", True),
        ("Image.I0.Text.ClockEnabled", "no", True),
        ("Image.I0.Text.DateEnabled", "no", True),
        ("Image.I0.Overlay.Enabled", "no", False),
        ("Time.SyncSource", "NTP", True),
    ]
    if setup.max_exposure_us is not None:
        out.append(("ImageSource.I0.Sensor.MaxExposureTime", str(setup.max_exposure_us), True))
    if setup.max_gain_db is not None:
        out.append(("ImageSource.I0.Sensor.MaxGain", str(setup.max_gain_db), True))
    if setup.ntp_server is not None:
        out.append(("Time.NTP.Server", setup.ntp_server, True))
    if cam.vapix_version == 2:
        out.append(("Time.TimeZone", setup.posix_time_zone, True))
    return out


#: locked as the camera has them when the setup does not set them (where the firmware has them)
LOCKED_AS_READ = ("ImageSource.I0.Sensor.MaxExposureTime", "ImageSource.I0.Sensor.MaxGain", "Time.NTP.Server")


def setup_camera(cam: AxisSetup, cfg, setup) -> SetupResult:
    """Set ``cam`` up (see the module docstring) and read everything back."""
    result = SetupResult(cam.name)
    groups = ("Image.I0", "ImageSource.I0", "Time")
    before = _tree(cam, groups)
    send: dict[str, str] = {}
    for name, value, required in wanted(cam, cfg, setup):
        if name not in before:
            if required:
                raise SetupRefused(
                    cam.name,
                    f"camera {cam.name} has no parameter {name}: its firmware "
                    f"({_firmware(cam)}) cannot be set to {name.rsplit('.', 1)[-1]}={value}",
                )
            result.notes.append(f"{name}: not on this firmware, nothing to switch off")
            continue
        send[name] = value
    try:
        cam.set_params(send)
    except Refused as exc:
        raise SetupRefused(cam.name, _refusal(cam.name, send, str(exc))) from None
    result.changed = [k for k, v in send.items() if before.get(k) != v]
    after = _tree(cam, groups)
    for name, value in send.items():
        got = after.get(name)
        if got != value:
            raise SetupRefused(cam.name, f"camera {cam.name} took {name}={value} but reads back {got!r}")
        result.locked[name] = value
    for name in LOCKED_AS_READ:
        if name not in result.locked and name in after:
            result.locked[name] = after[name]
            result.notes.append(f"{name}: left as the camera has it ({after[name] or 'empty'}), locked")
    if cam.vapix_version != 2:
        _time_zone(cam, setup.time_zone, result, before.get("Time.TimeZone"))
    return result


def _tree(cam: AxisSetup, groups) -> dict[str, str]:
    out: dict[str, str] = {}
    for g in groups:
        try:
            out.update(cam.get_params(g))
        except Refused:  # a group this firmware lacks: its parameters are missing, said per parameter
            pass
    return out


def _firmware(cam: AxisSetup) -> str:
    try:
        info = cam.device_info()
        return f"{info.get('ProdShortName', 'Axis')} {info.get('Version', '?')}"
    except AxisError:
        return "unknown"


def _refusal(camera: str, sent: dict[str, str], words: str) -> str:
    """One sentence: which parameter and value the camera refused, and its own words."""
    m = _ERROR_PARAM.search(words)
    name = m.group(1) if m and m.group(1) in sent else None
    said = words.split(": ", 2)[-1].strip().rstrip("!") or "no reason given"
    if name is None:
        return f"camera {camera} refused the setup ({said})"
    why = "it is not a value this firmware takes" if "setting" in words.lower() else "see the camera's words"
    return f"camera {camera} refused {name}={sent[name]}: {why} (the camera said: {said})"


def _time_zone(cam: AxisSetup, zone: str, result: SetupResult, before: str | None) -> None:
    """Current firmware: the IANA zone through the Time API, read back with getDateTimeInfo."""
    try:
        reply = cam.request(
            "POST", TIME_API, json_body={"apiVersion": "1.0", "method": "setTimeZone", "params": {"timeZone": zone}}
        ).json()
        if "error" in reply:
            msg = reply["error"].get("message") or f"error {reply['error'].get('code')}"
            raise SetupRefused(cam.name, f"camera {cam.name} refused time zone {zone} through the Time API: {msg}")
        info = cam.request("POST", TIME_API, json_body={"apiVersion": "1.0", "method": "getDateTimeInfo"}).json()
        got = info["data"]["timeZone"]
    except NotFound:
        raise SetupRefused(
            cam.name, f"camera {cam.name} has no Time API (time.cgi): its time zone cannot be set to {zone}"
        ) from None
    except NOT_THE_JSON:
        raise SetupRefused(cam.name, f"camera {cam.name} answered the Time API with JSON of another shape") from None
    if got != zone:
        raise SetupRefused(cam.name, f"camera {cam.name} took time zone {zone} but its Time API reads back {got!r}")
    params = _tree(cam, ("Time",))
    if params.get("Time.TimeZone") == zone:  # the parameter the daily QA can read back
        result.locked["Time.TimeZone"] = zone
    else:
        result.notes.append(
            f"time zone {zone} set through the Time API; param.cgi does not show it, so the daily QA cannot check it"
        )
    if before != zone:
        result.changed.append("Time.TimeZone")


__all__ = ["SetupRefused", "SetupResult", "setup_camera", "wanted", "LOCKED_AS_READ"]
