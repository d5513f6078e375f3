"""Switchable faults of a simulated Axis camera: the field failures a driver must survive.

One :class:`Faults` object belongs to each simulated camera. Tests change it at run time,
either directly (``cam.faults.drop_after_frames = 5``), with ``cam.set_faults(...)``, or over
the camera's control endpoint (``POST /sim/faults`` with a JSON object of the fields).
Stream handlers read the fields before every frame, so a change reaches running streams too.

Frame indices count from 0 within one stream. For snapshots, ``torn_jpeg_at`` counts the
snapshots served since the faults were last changed (so ``torn_jpeg_at=0`` tears the next
snapshot); :attr:`Faults.version` tells the server when that was.

Frame loss (``lose_*``), the offline stretch (``offline_from``/``offline_until``) and the clock
jumps (``clock_jump_*``) are functions of the simulated world's time (host UTC epoch seconds of
the camera's clock object, ``SimClock.now()``) and of the frame's place on the sensor's grid
(multiples of the frame period), never of when a stream happened to start: the same frames are
lost on every run, and cameras given the same burst lose their frames at the same moments, as
cameras behind one congested switch do. A lost frame is not sent: the client sees a gap in the
frames' times, as with a real camera that skipped them (``docs/decisions/0047-sim-frame-loss.md``).
"""

from __future__ import annotations

import math
import random
from dataclasses import MISSING, asdict, dataclass, field, fields
from typing import Any

__all__ = ["Faults", "TORN_MODES", "LATE_LIMIT_S"]

TORN_MODES = ("short", "cut")
# A healthy simulated camera whose stream falls behind its frame grid (this host was busy: the
# frames were made late) sends its frames late, each stamped with its capture time, up to this
# far behind; further behind it skips to the live frame (the frames between are lost). The
# ``skip_when_late_s`` fault makes that bound a real camera's (about a second).
LATE_LIMIT_S = 10.0


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
    offline_from: float | None = None
    """Offline (as ``offline``) from this time (host epoch s on the camera's clock object) ..."""
    offline_until: float | None = None
    """... until this one, then back (either alone: from that time on / from now until then)."""
    lose_p: float = 0.0
    """Each frame of a stream is lost (not sent) with this probability, drawn from
    ``lose_seed``, the camera's name and the frame's place on the grid: the same frames each run."""
    lose_seed: int = 0
    lose_burst_frames: int = 0
    """Bursts of loss: the first N frames of every ``lose_burst_every_s`` seconds of the clock
    (grid times ``t`` with ``t mod M < N / fps``) are lost."""
    lose_burst_every_s: float = 0.0
    clock_jump_s: float = 0.0
    """The camera's clock jumps by this many seconds (negative: back) at ``clock_jump_at``
    (host epoch s) and, with ``clock_jump_every_s``, again every that many seconds: the frames'
    stamps and ``date.cgi``/``time.cgi`` follow it, as after an NTP step."""
    clock_jump_at: float | None = None
    clock_jump_every_s: float | None = None
    skip_when_late_s: float | None = None
    """A stream further behind its frame grid than this skips to the live frame and the frames
    between are lost, as a real camera's are when it cannot keep up (about 1 s); default: they
    are sent late, up to ``LATE_LIMIT_S`` behind."""
    trickle: bool = False
    """Answer every VAPIX request (snapshot, stream, parameters, info, time) with its status and
    headers at once, then its body one byte every ``trickle_s`` seconds: a sick network stack or
    a throttling proxy. A client that only times each read waits for ever."""
    trickle_s: float = 1.0
    led_held: bool = False
    """The LED's output does not follow ``port.cgi``/``output.cgi`` actions: each is answered
    ``OK`` and the output stays as it was, as when an action rule on the camera holds the port
    (or the port is wired to something else). The state queries tell the truth."""
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

    # --- what the stream and the handlers ask -------------------------------------------
    def offline_at(self, t: float) -> bool:
        """Off the network at time ``t`` (``offline``, or inside the offline stretch)."""
        if self.offline:
            return True
        start, end = self.offline_from, self.offline_until
        if start is None and end is None:
            return False
        return (start is None or t >= start) and (end is None or t < end)

    def lost(self, camera: str, grid_index: int, t: float, period: float) -> bool:
        """Whether the frame at grid time ``t`` (``grid_index`` periods since the epoch) of
        ``camera`` is lost: in a burst, or drawn with probability ``lose_p``."""
        n, every = self.lose_burst_frames, self.lose_burst_every_s
        if n and every > 0 and math.fmod(t + period / 2, every) < n * period:  # a frame's slot, centred
            return True
        p = self.lose_p
        return p > 0 and (p >= 1 or random.Random(f"{self.lose_seed}:{camera}:{grid_index}").random() < p)

    def clock_offset(self, t: float) -> float:
        """How far the camera's clock has jumped by time ``t`` (s)."""
        at, jump = self.clock_jump_at, self.clock_jump_s
        if at is None or not jump or t < at:
            return 0.0
        every = self.clock_jump_every_s
        return jump * (1 + math.floor((t - at) / every)) if every else jump

    def late_limit(self) -> float:
        """How far behind its grid a stream may fall before it skips to the live frame."""
        return LATE_LIMIT_S if self.skip_when_late_s is None else self.skip_when_late_s

    def active(self) -> dict[str, Any]:
        """Only the fields that differ from a healthy camera (for logs and /sim/state)."""
        healthy = Faults().to_dict()
        return {k: v for k, v in self.to_dict().items() if v != healthy[k]}


_FIELD_TYPES = {
    "drop_after_frames": "count?",
    "stall_after_frames": "count?",
    "stall_s": "seconds",
    "too_many_viewers": "bool",
    "max_viewers": "count?",
    "reject_auth": "bool",
    "torn_jpeg_at": "count?",
    "torn_mode": "mode",
    "wrong_content_length_at": "count?",
    "wrong_content_length_extra": "count",
    "missing_content_length": "bool",
    "close_after_response": "bool",
    "offline": "bool",
    "no_axis_stamps": "bool",
    "offline_from": "time?",
    "offline_until": "time?",
    "lose_p": "probability",
    "lose_seed": "count",
    "lose_burst_frames": "count",
    "lose_burst_every_s": "seconds",
    "clock_jump_s": "signed seconds",
    "clock_jump_at": "time?",
    "clock_jump_every_s": "period?",
    "skip_when_late_s": "seconds?",
    "trickle": "bool",
    "trickle_s": "seconds",
    "led_held": "bool",
}


# number kinds: (what it must be, lowest allowed, lowest excluded)
_NUMBERS = {
    "seconds": ("a number of seconds >= 0", 0.0, False),
    "signed seconds": ("a number of seconds", -math.inf, False),
    "time": ("a time (host epoch s) >= 0", 0.0, False),
    "period": ("a number of seconds > 0", 0.0, True),
    "probability": ("a probability from 0 to 1", 0.0, False),
}


def _coerce(name: str, value: Any) -> Any:
    kind = _FIELD_TYPES[name]
    nullable = kind.endswith("?")
    base = kind.rstrip("?")
    if nullable and value is None:
        return None
    also = " or null" if nullable else ""
    if base == "count":
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise ValueError(f"fault {name} must be a whole number >= 0{also}, not {value!r}")
        return value
    if base in _NUMBERS:
        what, low, open_low = _NUMBERS[base]
        ok = (
            not isinstance(value, bool)
            and isinstance(value, (int, float))
            and math.isfinite(value)
            and (value > low if open_low else value >= low)
            and (base != "probability" or value <= 1)
        )
        if not ok:
            raise ValueError(f"fault {name} must be {what}{also}, not {value!r}")
        return float(value)
    if base == "bool":
        if not isinstance(value, bool):
            raise ValueError(f"fault {name} must be true or false, not {value!r}")
        return value
    if value not in TORN_MODES:
        raise ValueError(f"fault {name} must be one of {', '.join(TORN_MODES)}, not {value!r}")
    return value
