"""Aim and focus of one camera (issue 24 §2): what its picture says, item by item, with a verdict.

:func:`assess` takes the camera's picture with its LED on and with it off (grey uint8 images)
and, when the camera is calibrated and the VTS -> SPECT mapping exists, a
:class:`~vts_hw.vision.aim_geometry.RoomView`. It measures

==========  ====================================================================================
focus       the markers' edge width (vts_hw/vision/focus.py), px, and as a share of their radius
size        the markers' diameter, px
contrast    LED on: the markers' grey levels over the local background
background  LED on: the picture's median grey level
led_off     LED off: what the markers keep of their LED-on contrast
aim         every marker inside the picture, ``edge_margin_px`` clear of its edges
fov         (mapping) the SPECT FOV's centre within ``fov_centre_max_deg`` of the optical axis
gantry      (mapping) how many markers are seen through the gantry's opening
==========  ====================================================================================

and gives each a :class:`Verdict`: ``good``, ``adjust`` (with how, in words: "turn the focus
ring: ...", "aim 2.1° left: ..."), or ``unknown`` (and why: "not known: no mapping"). The goals
are one :class:`~vts_hw.vision.aim_settings.AimSettings`. From two JPEGs with the rig's
calibration and mapping it is procedures/aim.py's ``check_pictures`` (the console's Room page
and `vts camera aim`). docs/decisions/0068-aim-and-focus.md.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace

import cv2
import numpy as np

from vts_hw.vision import aim_overlay
from vts_hw.vision.aim_settings import DEFAULT_AIM, AimSettings
from vts_hw.vision.aim_verdicts import (
    ADJUST,
    GOOD,
    UNKNOWN,
    Verdict,
    aim_verdict,
    fov_verdict,
    gantry_verdict,
    level_verdicts,
    marker_verdicts,
    picture_shift,
)
from vts_hw.vision.detect import DetectorSettings, detect
from vts_hw.vision.focus import edge_profile
from vts_hw.vision.marker_roles import roles_by_reference

__all__ = ["Marker", "AimReport", "assess", "decode_grey", "GOOD", "ADJUST", "UNKNOWN", "Verdict"]


@dataclass(frozen=True)
class Marker:
    """One marker in the LED-on picture: centre, diameter and edge width (px; None when its
    edge could not be read), contrast with the LED on and off (grey levels), and whether its
    line of sight passes through the gantry's opening (None: not known, no mapping). ``cut``:
    cut by the picture's border (only its rough position is known)."""

    x: float
    y: float
    diameter_px: float | None
    edge_width_px: float | None
    contrast: float
    contrast_off: float | None
    through_gantry: bool | None = None
    cut: bool = False
    role: str = ""  # vision/marker_roles.py against the reference ("": no reference, not known)


@dataclass
class AimReport:
    """The aim-and-focus check of one camera: its verdicts, its markers, what was drawn."""

    camera: str
    size: tuple[int, int]
    items: list[Verdict]
    markers: list[Marker]
    view: object | None = None  # the RoomView, when there is a mapping
    image: np.ndarray | None = field(default=None, repr=False)  # the LED-on picture
    settings: AimSettings = DEFAULT_AIM

    @property
    def state(self) -> str:
        """``adjust`` when any item needs adjusting, else ``good`` (unknown items do not count;
        :attr:`unknown` lists them)."""
        return ADJUST if any(v.state == ADJUST for v in self.items) else GOOD

    @property
    def unknown(self) -> list[str]:
        return [v.item for v in self.items if v.state == UNKNOWN]

    def item(self, name: str) -> Verdict:
        return next(v for v in self.items if v.item == name)

    def to_dict(self) -> dict:
        """JSON-able: camera, state, every item, every marker."""
        return {
            "camera": self.camera,
            "state": self.state,
            "unknown": self.unknown,
            "picture": {"width": self.size[0], "height": self.size[1]},
            "items": [v.to_dict() for v in self.items],
            "markers": [
                {k: (round(v, 3) if isinstance(v, float) else v) for k, v in asdict(m).items()} for m in self.markers
            ],
        }

    def overlay_png(self) -> bytes:
        """The LED-on picture with the markers, the FOV, the table and the gantry's opening drawn."""
        return aim_overlay.overlay_png(self)


def decode_grey(jpeg: bytes, what: str = "picture") -> np.ndarray:
    """A JPEG as a grey image; ValueError naming ``what`` when it does not decode."""
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE) if jpeg else None
    if img is None:
        raise ValueError(f"the {what} is not a decodable JPEG")
    return img


def _local_contrast(gray: np.ndarray, x: float, y: float, r: float) -> float:
    """Mean grey level within half the radius of ``(x, y)`` minus the median of a ring just
    outside the marker (grey levels)."""
    h, w = gray.shape
    R = int(math.ceil(r + 8))
    x0, x1, y0, y1 = max(int(x) - R, 0), min(int(x) + R + 1, w), max(int(y) - R, 0), min(int(y) + R + 1, h)
    patch = gray[y0:y1, x0:x1].astype(np.float64)
    yy, xx = np.mgrid[y0:y1, x0:x1]
    d = np.hypot(xx - x, yy - y)
    core, ring = patch[d <= max(r / 2, 1.0)], patch[(d >= r + 3) & (d <= r + 8)]
    if not core.size or not ring.size:
        return math.nan
    return float(core.mean() - np.median(ring))


def measure_markers(
    on: np.ndarray, off: np.ndarray | None, view=None, detector: DetectorSettings | None = None
) -> tuple[list[Marker], float]:
    """The markers of the LED-on picture (those cut by its border too), and its background."""
    found = detect(on, detector or DetectorSettings())
    out = []
    for b in found.blobs:
        r = math.sqrt(b.area / math.pi)
        e = edge_profile(on, b.x, b.y, r)
        radius = e.radius_px if e is not None else r
        off_c = _local_contrast(off, b.x, b.y, radius) if off is not None else None
        out.append(
            Marker(
                b.x, b.y, 2 * radius, None if e is None else e.width_px, _local_contrast(on, b.x, b.y, radius), off_c
            )
        )
    for b, why in found.rejected:
        if why == "border":
            out.append(Marker(b.x, b.y, None, None, float(b.peak), None, cut=True))
    if view is not None and out:
        inside = view.through_bore([(m.x, m.y) for m in out])
        out = [Marker(**{**asdict(m), "through_gantry": bool(t)}) for m, t in zip(out, inside)]
    return out, float(found.background)


def assess(
    camera: str,
    on: np.ndarray,
    off: np.ndarray | None,
    view=None,
    settings: AimSettings = DEFAULT_AIM,
    no_view: str = "no mapping",
    detector: DetectorSettings | None = None,
    reference=None,
    reference_name: str = "the drift baseline",
) -> AimReport:
    """The aim-and-focus check of ``camera`` from its LED-on picture ``on`` and LED-off picture
    ``off`` (None: the camera cannot switch its LED). ``view``: a RoomView (calibration and
    mapping), or None, and then ``no_view`` says why (``no mapping``, ``camera cam3 is not in
    the calibration``). ``reference``: where the markers were (px, the drift baseline's wall
    markers), so the aim can count markers gone out of the picture and say how far it turned."""
    for name, img in (("LED-on", on), ("LED-off", off)):
        if img is not None and (not isinstance(img, np.ndarray) or img.dtype != np.uint8 or img.ndim != 2):
            raise ValueError(f"the {name} picture must be a grey uint8 image")
    if off is not None and off.shape != on.shape:
        raise ValueError(
            f"the LED-on and LED-off pictures differ in size ({on.shape[1]}x{on.shape[0]} "
            f"and {off.shape[1]}x{off.shape[0]})"
        )
    size = (int(on.shape[1]), int(on.shape[0]))
    markers, background = measure_markers(on, off, view, detector)
    if reference is not None and len(np.asarray(reference, float).reshape(-1, 2)) and markers:
        shift = picture_shift(reference, markers)
        roles = roles_by_reference(reference, [(m.x, m.y) for m in markers], shift[:2] if shift else (0.0, 0.0))
        markers = [replace(m, role=r.role) for m, r in zip(markers, roles)]
    whole = [m for m in markers if not m.cut]
    focal = view.focal_px if view is not None else None
    items = marker_verdicts(whole, settings)
    items += level_verdicts(whole, background, off is not None, settings)
    items.append(aim_verdict(markers, size, focal, settings, reference, reference_name))
    items.append(fov_verdict(view, settings, no_view))
    items.append(gantry_verdict(markers, view, settings, no_view))
    return AimReport(camera, size, items, markers, view, on, settings)
