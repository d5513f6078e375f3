"""What "aimed and focused" means: every goal of `vts camera aim` in one place, validated.

One :class:`AimSettings` (pydantic, frozen, unknown keys refused) holds the goals each item of
the aim check is judged against (vts_hw/vision/aim.py) and the room geometry it draws (the SPECT
field of view, the table, the gantry's opening, all in the SPECT frame). The defaults suit the
reference rig of docs/design.md; rig.yaml's ``aim:`` section overrides any of them, and a bad
value ends in one sentence naming the key (``aim.edge_width_max_px``).
docs/decisions/0068-aim-and-focus.md says why each default is what it is.
"""

from __future__ import annotations

from pydantic import Field, model_validator

from vts_hw.config_base import Strict

__all__ = ["AimSettings", "DEFAULT_AIM"]


class AimSettings(Strict):
    """Goals and room geometry of the aim-and-focus check (see the module docstring)."""

    # focus: the markers' edge, 10-90 % rise width along radial profiles (vts_hw/vision/focus.py)
    edge_width_max_px: float = Field(
        default=2.0, gt=0, le=20, description="focus: the markers' 10-90 % edge width at most this (px)"
    )
    edge_ratio_max: float = Field(
        default=0.5, gt=0, le=2, description="focus: ... and at most this share of the marker's radius"
    )
    # size of the markers in the picture
    marker_diameter_min_px: float = Field(
        default=6.0,
        gt=0,
        le=500,
        description="markers at least this wide (px): smaller ones lose centroid precision; zoom in",
    )
    marker_diameter_max_px: float = Field(
        default=40.0,
        gt=0,
        le=500,
        description="markers at most this wide (px): larger ones mean a narrow view; zoom out",
    )
    # brightness, LED on and off
    contrast_min: float = Field(
        default=80.0, gt=0, le=255, description="LED on: markers at least this many grey levels over the background"
    )
    background_max: float = Field(
        default=60.0, gt=0, le=255, description="LED on: the picture's background (median) at most this grey level"
    )
    led_off_share_max: float = Field(
        default=0.25,
        ge=0,
        le=1,
        description="LED off: markers keep at most this share of their LED-on "
        "contrast (else room light, not the LED, lights them)",
    )
    # aim: every marker this far inside the picture's edges
    edge_margin_px: float = Field(
        default=24.0, ge=0, le=200, description="aim: every marker at least this far inside the picture (px)"
    )
    reference_shift_max_px: float = Field(
        default=5.0,
        gt=0,
        le=500,
        description="aim (with a drift baseline): the picture within this of where the baseline saw it (px)",
    )
    fov_centre_max_deg: float = Field(
        default=3.0,
        gt=0,
        le=45,
        description="aim (with a mapping): the SPECT FOV centre within this angle of the picture's centre",
    )
    nominal_focal_px: float = Field(
        default=3370.0,
        gt=0,
        le=100000,
        description="the lens's focal length (px) for advice in degrees when the "
        "camera has no calibration (the reference rig's zoom lens)",
    )
    min_wall_markers: int = Field(
        default=4, ge=0, le=100, description="at least this many markers seen through the gantry's opening"
    )
    # room geometry in the SPECT frame (mm), drawn into the picture
    fov_diameter_mm: float = Field(
        default=540.0, gt=0, le=2000, description="SPECT field of view: transaxial diameter (the heads' face width)"
    )
    fov_length_mm: float = Field(
        default=400.0, gt=0, le=2000, description="SPECT field of view: axial length (the heads' face height)"
    )
    bore_diameter_mm: float = Field(default=700.0, gt=0, le=3000, description="the gantry's opening: diameter")
    bore_depth_mm: float = Field(
        default=400.0, gt=0, le=3000, description="the gantry's opening: depth along the axis, centred on the FOV"
    )
    table_width_mm: float = Field(default=450.0, gt=0, le=2000, description="the table top's width")
    table_top_y_mm: float = Field(
        default=-80.0,
        ge=-1000,
        le=1000,
        description="the table top's height in the SPECT frame (Y up; at its nominal position)",
    )
    table_z_mm: tuple[float, float] = Field(
        default=(-1200.0, 900.0), description="the table top's extent along Z (head end, foot end)"
    )

    @model_validator(mode="after")
    def _consistent(self):
        if self.marker_diameter_min_px >= self.marker_diameter_max_px:
            raise ValueError("marker_diameter_min_px must be below marker_diameter_max_px")
        if self.table_z_mm[0] >= self.table_z_mm[1]:
            raise ValueError("table_z_mm must be (head end, foot end) with the head end first (smaller Z)")
        if self.bore_diameter_mm < self.fov_diameter_mm:
            raise ValueError("bore_diameter_mm must be at least fov_diameter_mm (the FOV lies in the opening)")
        return self


DEFAULT_AIM = AimSettings()
