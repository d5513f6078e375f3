"""Aim and focus of one camera of the rig (issue 24 §2): take its pictures, find its place in the
room, judge (vts_hw/vision/aim.py).

* :func:`room_view` -- the camera's :class:`~vts_hw.vision.aim_geometry.RoomView` from the rig's
  calibration and VTS -> SPECT mapping (``calibration.cameras`` / ``calibration.mapping`` of
  rig.yaml), or why there is none ("no mapping", "no calibration", "camera cam3 is not in the
  calibration ...", "the mapping ... cannot be read: ..."): a missing mapping is an item not
  known, never an error.
* :func:`check` -- LED on, one picture; LED off, one picture; the LED left on (as the drift QA
  does, procedures/drift.py); the :class:`~vts_hw.vision.aim.AimReport`.
* :func:`aim_page` -- the same for a page: the verdicts as a JSON-able dict and the overlay as
  PNG bytes.
* :func:`check_pictures` / :func:`aim_page_of` -- the same from two pictures already taken (the
  console's Room page takes them from the frames it already receives: it never opens a second
  stream nor a snapshot of a camera, docs/decisions/0071-console-aim.md).
"""

from __future__ import annotations

from vts_hw.camera import check_whole
from vts_hw.errors import VtsError
from vts_hw.procedures.drift import acquire_led_frames
from vts_hw.vision.aim import AimReport, assess, decode_grey
from vts_hw.vision.aim_geometry import RoomView
from vts_hw.vision.aim_settings import DEFAULT_AIM, AimSettings
from vts_hw.vision.camera_set import in_rig_names, load_cameras
from vts_hw.vision.registration import read_mapping

__all__ = ["room_view", "check", "check_pictures", "aim_page", "aim_page_of", "acquire_pictures"]


def room_view(
    rig, name: str, size: tuple[int, int], settings: AimSettings | None = None
) -> tuple[RoomView | None, str]:
    """``(view, "")`` for camera ``name`` of ``rig``, or ``(None, why)``."""
    settings = settings or rig.aim
    cal = rig.calibration
    if cal.mapping is None:
        return None, "no mapping"
    if cal.cameras is None:
        return None, "no calibration (the mapping needs one)"
    try:
        mapping = read_mapping(cal.mapping)
    except (VtsError, OSError) as exc:
        return None, f"the mapping {cal.mapping} cannot be read ({exc})"
    try:
        cams = load_cameras(cal.cameras)
    except (VtsError, OSError) as exc:
        return None, f"the calibration {cal.cameras} cannot be read ({exc})"
    cams = in_rig_names(cams, [c.name for c in rig.cameras])
    if name not in cams:
        return None, f"camera {name} is not in the calibration {cal.cameras}"
    return RoomView(cams[name], mapping, size, settings), ""


def acquire_pictures(cam):
    """LED on, one picture; LED off, one picture (None when the camera cannot switch its LED);
    the LED is left on. Both whole JPEGs (a torn one: NotWhole, naming the camera)."""
    on, off = acquire_led_frames(cam, n_frames=1)
    for frame in [on[0]] + ([off] if off is not None else []):
        check_whole(frame, cam.name)
    return on[0].jpeg, None if off is None else off.jpeg


def check_pictures(
    name: str,
    rig,
    on_jpeg: bytes,
    off_jpeg: bytes | None,
    reference=None,
    reference_name: str = "the drift baseline",
    settings: AimSettings | None = None,
) -> AimReport:
    """The aim-and-focus check of camera ``name`` of ``rig`` (a RigConfig; None: the default goals
    and no mapping) from its picture with the LED on and with it off (None: the LED could not be
    switched). Opens nothing. ``reference``: where its markers were (px), or None; ``settings``:
    the goals (default: the rig's ``aim:``)."""
    settings = settings or (rig.aim if rig is not None else DEFAULT_AIM)
    on = decode_grey(on_jpeg, f"LED-on picture of {name}")
    off = None if off_jpeg is None else decode_grey(off_jpeg, f"LED-off picture of {name}")
    if rig is None:
        view, why = None, "no mapping (no rig configuration given)"
    else:
        view, why = room_view(rig, name, (on.shape[1], on.shape[0]), settings)
    return assess(
        name, on, off, view, settings, why or "no mapping", reference=reference, reference_name=reference_name
    )


def check(
    cam, rig, settings: AimSettings | None = None, reference=None, reference_name: str = "the drift baseline"
) -> AimReport:
    """The aim-and-focus check of ``cam`` (an open camera of ``rig``): LED on, one picture; LED
    off, one picture (the LED left on), judged by :func:`check_pictures`. ``reference``: where
    its markers were (px; the drift baseline's wall markers), or None."""
    on_jpeg, off_jpeg = acquire_pictures(cam)
    return check_pictures(cam.name, rig, on_jpeg, off_jpeg, reference, reference_name, settings)


def aim_page(cam, rig, reference=None) -> tuple[dict, bytes]:
    """For a page: the verdicts (JSON-able dict) and the overlay (PNG bytes) of ``cam``."""
    on_jpeg, off_jpeg = acquire_pictures(cam)
    return aim_page_of(cam.name, rig, on_jpeg, off_jpeg, reference)


def aim_page_of(
    name: str, rig, on_jpeg: bytes, off_jpeg: bytes | None, reference=None, reference_name: str = "the drift baseline"
) -> tuple[dict, bytes]:
    """:func:`aim_page` from two pictures already taken (:func:`check_pictures`): opens nothing."""
    report = check_pictures(name, rig, on_jpeg, off_jpeg, reference, reference_name)
    return report.to_dict(), report.overlay_png()
