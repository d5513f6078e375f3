"""rig.yaml's ``camera_setup:`` section: what `vts camera setup` sets on every Axis camera
beyond its own entry's resolution, frame rate and compression (drivers/axis_setup.py).

Every key has the value a VTS wants by default: exposure and white balance held (the LED ring
on retro-reflective markers must look the same every morning), no text overlay (always), the
camera clock on NTP in UTC. A key left empty (``max_exposure_us``, ``max_gain_db``,
``ntp_server``) is not changed: its current value is read and locked as it is.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from vts_hw.config_base import Strict

EXPOSURES = ("hold", "auto", "flickerfree50", "flickerfree60")
WHITE_BALANCES = ("hold", "auto", "fixed_indoor", "fixed_outdoor1", "fixed_outdoor2", "fixed_fluor1", "fixed_fluor2")


class CameraSetupConfig(Strict):
    exposure: Literal[EXPOSURES] = Field(  # type: ignore[valid-type]
        default="hold", description="ImageSource.I0.Sensor.Exposure: hold keeps shutter and gain where they are"
    )
    white_balance: Literal[WHITE_BALANCES] = Field(  # type: ignore[valid-type]
        default="hold", description="ImageSource.I0.Sensor.WhiteBalance"
    )
    max_exposure_us: int | None = Field(
        default=None,
        ge=100,
        le=1_000_000,
        description="ImageSource.I0.Sensor.MaxExposureTime in microseconds (firmware that has it)",
    )
    max_gain_db: int | None = Field(
        default=None, ge=0, le=48, description="ImageSource.I0.Sensor.MaxGain in dB (firmware that has it)"
    )
    ntp_server: str | None = Field(
        default=None,
        min_length=1,
        max_length=253,
        pattern=r"^[A-Za-z0-9.:-]+$",
        description="Time.NTP.Server (the clock is always set to sync from NTP)",
    )
    time_zone: str = Field(
        default="Etc/UTC",
        min_length=1,
        max_length=64,
        pattern=r"^[A-Za-z0-9_+./-]+$",
        description="IANA time zone, set through the Time API (current firmware)",
    )
    posix_time_zone: str = Field(
        default="UTC0",
        min_length=1,
        max_length=64,
        pattern=r"^[A-Za-z0-9+,./:<>-]+$",
        description="POSIX TZ string: the Time.TimeZone parameter of VAPIX 2 firmware",
    )
