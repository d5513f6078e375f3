"""The room as one object: ``Room.open(config)`` gives the rig's cameras, trigger, calibration,
VTS -> SPECT mapping and results store, each opened when first used and closed with the room
(vts_hw/room/room.py; docs/decisions/0099-the-room.md)."""

from vts_hw.room.room import Room

__all__ = ["Room"]
