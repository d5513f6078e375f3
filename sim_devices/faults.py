"""Switchable faults of a simulated Axis camera: the field failures a driver must survive.

One :class:`Faults` object belongs to each simulated camera. Tests change it at run time,
either directly (``cam.faults.drop_after_frames = 5``), with ``cam.set_faults(...)``, or over
the camera's control endpoint (``POST /sim/faults`` with a JSON object of the fields).
Stream handlers read the fields before every frame, so a change reaches running streams too.

Frame indices count from 0 within one stream. For snapshots, ``torn_jpeg_at`` counts the
snapshots served since the faults were last changed (so ``torn_jpeg_at=0`` tears the next
snapshot); :attr:`Faults.version` tells the server when that was.
"""

from __future__ import annotations

from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any

__all__ = ["Faults", "TORN_MODES"]

TORN_MODES = ("short", "cut")


@dataclass
class Faults:
    """What to get wrong. Every field's default means "behave like a healthy camera"."""

    drop_after_frames: int | None = None
    """Close the stream (no closing boundary, before the requested end) after N frames."""
    stall_after_frames: int | None = None
    """After N frames, send nothing for ``stall_s`` seconds; the connection stays open."""
    stall_s: float = 2.0
    too_many_viewers: bool = False
    """Answer new image and video requests with 503, as a camera whose viewers are used up."""
    max_viewers: int | None = None
    """Answer a new stream with 503 when this many streams are already running."""
    reject_auth: bool = False
    """Answer 401 even to valid credentials."""
    torn_jpeg_at: int | None = None
    """The frame (or snapshot) at this index lacks its second half (see ``torn_mode``)."""
    torn_mode: str = "short"
    """``short``: half the JPEG, and the headers state that short length; the stream goes on.
    ``cut``: the headers state the full length, half is sent, then the connection dies."""
    wrong_content_length_at: int | None = None
    """That part's Content-Length claims ``wrong_content_length_extra`` bytes more than sent."""
    wrong_content_length_extra: int = 100
    missing_content_length: bool = False
    """Stream parts without a Content-Length header (clients must scan for the boundary)."""
    close_after_response: bool = False
    """Old firmware: ``HTTP/1.0`` and ``Connection: close`` on every response."""
    no_axis_stamps: bool = False
    """JPEGs without the Axis comment segments (no time, no product): a plain MJPEG camera."""
    offline: bool = False
    """Off the network (cable pulled, camera rebooting): running streams are cut before their
    next frame and every new VAPIX request is hung up on unanswered. ``/sim/`` still answers."""
    version: int = field(default=0, compare=False, repr=False)
    """Bumped on every change of a fault field; not itself a fault."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name != "version" and name in _FIELD_TYPES:
            value = _coerce(name, value)
            object.__setattr__(self, "version", getattr(self, "version", 0) + 1)
        object.__setattr__(self, name, value)

    def to_dict(self) -> dict[str, Any]:
        """The fault fields as JSON-ready values (without ``version``)."""
        data = asdict(self)
        data.pop("version")
        return data

    def update(self, changes: dict[str, Any]) -> None:
        """Set several fields; a bad name or value raises ValueError and changes nothing."""
        unknown = sorted(set(changes) - set(_FIELD_TYPES))
        if unknown:
            raise ValueError(f"unknown fault(s): {', '.join(unknown)}; known: {', '.join(_FIELD_TYPES)}")
        checked = {k: _coerce(k, v) for k, v in changes.items()}
        for key, value in checked.items():
            setattr(self, key, value)

    def reset(self) -> None:
        """Back to a healthy camera."""
        for f in fields(self):
            if f.name != "version" and f.default is not MISSING:
                setattr(self, f.name, f.default)

    def active(self) -> dict[str, Any]:
        """Only the fields that differ from a healthy camera (for logs and /sim/state)."""
        healthy = Faults().to_dict()
        return {k: v for k, v in self.to_dict().items() if v != healthy[k]}


_FIELD_TYPES = {
    "drop_after_frames": "count?", "stall_after_frames": "count?", "stall_s": "seconds",
    "too_many_viewers": "bool", "max_viewers": "count?", "reject_auth": "bool",
    "torn_jpeg_at": "count?", "torn_mode": "mode", "wrong_content_length_at": "count?",
    "wrong_content_length_extra": "count", "missing_content_length": "bool",
    "close_after_response": "bool", "offline": "bool", "no_axis_stamps": "bool",
}


def _coerce(name: str, value: Any) -> Any:
    kind = _FIELD_TYPES[name]
    if kind.endswith("?") and value is None:
        return None
    if kind.startswith("count"):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            also = " or null" if kind.endswith("?") else ""
            raise ValueError(f"fault {name} must be a whole number >= 0{also}, not {value!r}")
        return value
    if kind == "seconds":
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value < 0:
            raise ValueError(f"fault {name} must be a number of seconds >= 0, not {value!r}")
        return float(value)
    if kind == "bool":
        if not isinstance(value, bool):
            raise ValueError(f"fault {name} must be true or false, not {value!r}")
        return value
    if value not in TORN_MODES:
        raise ValueError(f"fault {name} must be one of {', '.join(TORN_MODES)}, not {value!r}")
    return value
