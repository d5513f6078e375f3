"""A camera's LED ring switched and read back: a switch has taken only when the camera says so.

A camera may answer a switch "OK" and leave its output as it was (an action rule on the camera
holding the port, the port wired to something else: the simulated camera's ``led_held``
fault). So after each switch the state is read back (``Camera.led_state()``) until the camera
says what was asked, or :data:`READ_BACK_S` has passed: then the switch did not take
(:class:`LedNotTaken`, a device failure: exit 4). A camera that cannot tell its LED's state
(``led_state()`` None), or has no LED to switch (not :class:`~vts_hw.camera.Illumination`: a
replay, an MJPEG camera without an I/O port; nothing is sent), is said to be not known, never OK. A pulse is confirmed when its end is read back (the output off again) and, for a
pulse long enough to be read during it (:data:`PULSE_SEEN_MS`), when it was seen on.
docs/decisions/0084-commissioning-honest-state.md.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from vts_hw.camera import Camera, CameraError, Illumination

READ_BACK_S = 1.0  # a switch the camera's output shows within this long has taken
PULSE_SEEN_MS = 1000  # a pulse at least this long must be seen on while it lasts
POLL_S = 0.1


class LedNotTaken(CameraError):
    """The camera accepted an LED switch and its output does not show it."""

    retry = False


@dataclass(frozen=True)
class LedReadBack:
    """What the camera says after a switch: ``state`` True (on), False (off), None (not known:
    the kind cannot tell); ``seen_on`` for a pulse: whether it was read on while it lasted."""

    state: bool | None
    seen_on: bool | None = None

    def words(self) -> str:
        return (
            "not known (this camera cannot tell its LED's state)"
            if self.state is None
            else ("on" if self.state else "off")
        )


def _read_until(
    cam: Illumination, want: bool, within_s: float, sleep: Callable[[float], None], clock: Callable[[], float]
) -> bool | None:
    end = clock() + within_s
    while True:
        state = cam.led_state()
        if state is None or state == want or clock() >= end:
            return state
        sleep(POLL_S)


def _where(cam) -> str:
    port = getattr(cam, "led_port", None)
    return f"its LED output (port {port})" if port is not None else "its LED output"


def switch_led(
    cam: Camera, on: bool, *, within_s: float = READ_BACK_S, sleep=time.sleep, clock=time.monotonic
) -> LedReadBack:
    """Switch ``cam``'s LED ring on or off and read it back; :class:`LedNotTaken` when the camera
    still says otherwise after ``within_s``; not known (nothing sent) for a camera without an LED."""
    if not isinstance(cam, Illumination):
        return LedReadBack(None)
    cam.led_on() if on else cam.led_off()
    state = _read_until(cam, on, within_s, sleep, clock)
    want = "on" if on else "off"
    if state is not None and state != on:
        raise LedNotTaken(
            cam.name,
            f"camera {cam.name} accepted the switch {want} but {_where(cam)} still reads "
            f"{'on' if state else 'off'} after {within_s:g} s: the switch did not take (an "
            f"action rule on the camera may hold the port)",
        )
    return LedReadBack(state)


def light(cam: Camera) -> str:
    """Switch ``cam``'s LED ring on where it has one (the markers are retro-reflective: bright only
    with it on); what was done, in words: ``on``, or ``none (...)`` for a camera without an LED
    (not :class:`~vts_hw.camera.Illumination`: a replay), which is left as it is."""
    if not isinstance(cam, Illumination):
        return "none (this kind of camera cannot switch an LED)"
    cam.led_on()
    return "on"


def pulse_led(
    cam: Camera, ms: int, *, within_s: float = READ_BACK_S, sleep=time.sleep, clock=time.monotonic
) -> LedReadBack:
    """Pulse ``cam``'s LED ring for ``ms`` and read it back: seen on while it lasts (required for
    a pulse of :data:`PULSE_SEEN_MS` or more), off once it has ended; :class:`LedNotTaken` else;
    not known (nothing sent) for a camera without an LED."""
    if not isinstance(cam, Illumination):
        return LedReadBack(None)
    started = clock()
    cam.led_pulse(ms)
    seen = _read_until(cam, True, min(ms / 1000.0, within_s), sleep, clock)
    if seen is None:
        return LedReadBack(None)
    sleep(max(0.0, ms / 1000.0 - (clock() - started)))  # its end, then read
    end = _read_until(cam, False, within_s, sleep, clock)
    if end:
        raise LedNotTaken(
            cam.name,
            f"camera {cam.name} accepted a pulse of {ms} ms but {_where(cam)} still reads on "
            f"{within_s:g} s after its end: the pulse did not take (an action rule on the "
            f"camera may hold the port)",
        )
    if not seen and ms >= PULSE_SEEN_MS:
        raise LedNotTaken(
            cam.name,
            f"camera {cam.name} accepted a pulse of {ms} ms but {_where(cam)} never read on "
            f"while it lasted: the pulse did not take (an action rule on the camera may hold "
            f"the port)",
        )
    return LedReadBack(end, seen)


__all__ = ["LedNotTaken", "LedReadBack", "light", "switch_led", "pulse_led", "READ_BACK_S", "PULSE_SEEN_MS"]
