"""The rig's room for telling markers apart (vts_hw/vision/marker_roles.py, rule 2): its calibrated
cameras (``calibration.cameras``), its VTS -> SPECT mapping (``calibration.mapping``), the
table-and-gantry volume from rig.yaml's ``aim:`` room geometry, and the phantom's shape when the
mapping keeps it. Without a mapping or a calibration there is no room, and the reason says so:
the markers are then told apart by motion alone (docs/decisions/0086-marker-roles.md).
"""

from __future__ import annotations

from vts_hw.errors import VtsError
from vts_hw.vision.camera_set import in_rig_names, load_cameras
from vts_hw.vision.marker_roles import RoomGeometry, TableSpace
from vts_hw.vision.phantom_locator import PhantomLocator, phantom_template
from vts_hw.vision.registration import read_mapping

__all__ = ["room_geometry", "NO_ROOM"]

NO_ROOM = "judged by motion alone"


def room_geometry(rig) -> tuple[RoomGeometry | None, str]:
    """``(RoomGeometry, "")`` for ``rig`` (a RigConfig), or ``(None, why)``: no mapping, no calibration,
    a file that cannot be read (said, never raised: the QA still runs, by motion alone)."""
    if rig is None:
        return None, f"no rig configuration: {NO_ROOM}"
    cal = rig.calibration
    if cal.mapping is None:
        return None, f"no VTS -> SPECT mapping (calibration.mapping in rig.yaml): {NO_ROOM}"
    if cal.cameras is None:
        return None, f"no camera calibration (calibration.cameras in rig.yaml): {NO_ROOM}"
    try:
        mapping = read_mapping(cal.mapping)
    except (VtsError, OSError) as exc:
        return None, f"the mapping {cal.mapping} cannot be read ({exc}): {NO_ROOM}"
    try:
        cams = in_rig_names(load_cameras(cal.cameras), [c.name for c in rig.cameras])
    except (VtsError, OSError) as exc:
        return None, f"the calibration {cal.cameras} cannot be read ({exc}): {NO_ROOM}"
    try:
        locator = PhantomLocator(cams, phantom_template(mapping))
    except VtsError:  # a mapping made before it kept the spheres: still a room, no sphere named
        locator = None
    return RoomGeometry(cams, mapping, TableSpace.from_settings(rig.aim, mapping), locator), ""
