"""Aim and focus on the Room page: each camera switched to it is checked every few seconds, from
the frames the console already receives (issue 24 §2, docs/decisions/0071-console-aim.md).

The check needs a picture with the LED ring on and one with it off. It never opens anything of
its own (no second stream, no snapshot: cameras limit their viewers): the pictures are the
hub's frames. One check of camera ``cam1``:

1. refused, in one sentence, while a recording (a scan, the daily QA) feeds the hub (its source
   is ``fed``: the recording owns the camera and its LED), or while the console leaves the
   camera alone (``off``);
2. the LED's state read from the camera (``RoomFacts.read_led``, as the page shows it); not
   known: not checked (the LED could not be put back as it was);
3. a frame *taken after* that (its camera stamp through the measured clock offset, else its
   arrival and two more frames): the picture in the state found;
4. the LED switched to the other state through the page's own path (``RoomFacts.switch_led``:
   switched, then read back until the camera says so), and a frame taken after the camera said
   so: the other picture;
5. the LED switched back to the state found, whatever happened (unless a recording took the
   camera meanwhile: then the LED is the recording's, and the check says it stopped);
6. :func:`vts_hw.procedures.aim.aim_page_of` on the two pictures, with the rig's calibration
   and mapping (``console.rig_config``) and the drift baseline's wall markers (the names the
   page already holds) as the aim's reference.

One worker thread for every camera switched on (it ends when none is), never the event loop.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from vts_hw.camera import NotWhole, check_whole
from vts_hw.errors import VtsError
from vts_hw.procedures.aim import aim_page_of

EVERY_S = 2.0  # pause between two rounds of checks
FRAME_WAIT_S = 6.0  # a camera that gives no new frame for this long: not checked, and why
AFTER_S = 0.15  # a frame counts as taken after an instant when stamped this long after it
FRESH_FRAMES = 2  # ... or, with no camera stamp / offset, this many frames arrived after it and AFTER_S


class NotChecked(Exception):
    """The check could not be made: its message is the one sentence the page shows."""


@dataclass
class AimState:
    """What the page shows of one camera's aim check. ``version`` changes with every change."""

    on: bool = False
    busy: bool = False
    n: int = 0  # checks done since the console started
    at: float | None = None  # host epoch s of the last check's pictures
    verdicts: dict | None = None  # the last check's (procedures.aim.aim_page_of)
    png: bytes | None = None  # its overlay
    problem: str = ""  # why the last round made no check ("" when it did)
    led_found: str = ""  # the LED's state found (and left) by the last check
    by: str = ""  # who switched it on
    version: int = 0

    def as_dict(self, camera: str) -> dict:
        return {
            "camera": camera,
            "on": self.on,
            "busy": self.busy,
            "n": self.n,
            "at": self.at,
            "verdicts": self.verdicts,
            "problem": self.problem,
            "led_found": self.led_found,
            "by": self.by,
            "version": self.version,
        }


class AimChecks:
    """The aim checks of ``console`` (its hub, facts, marker names and ``rig_config``)."""

    def __init__(self, console, every_s: float = EVERY_S):
        self.console = console
        self.every_s = float(every_s)
        self._lock = threading.Lock()
        self._state = {name: AimState() for name in (console.hub.names if console.hub is not None else [])}
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._wake = threading.Event()

    # -- what the page asks ------------------------------------------------------------------------
    def view(self, name: str) -> dict:
        with self._lock:
            return self._state[name].as_dict(name)

    def version(self, name: str) -> int:
        with self._lock:
            return self._state[name].version

    def overlay(self, name: str) -> tuple[bytes | None, int]:
        with self._lock:
            st = self._state[name]
            return st.png, st.n

    def refusal(self, name: str) -> str:
        """Why camera ``name`` cannot be checked now (one sentence), or ''."""
        src = self.console.hub.source(name)
        if src == "fed":
            return (
                f"not checked: {name} is recording (a scan or the daily QA has its frames and its LED); "
                f"the check goes on when that is done"
            )
        if src == "off" or self.console.facts.cameras.get(name) is None:
            return f"not checked: the console leaves {name} alone (no stream of it here)"
        return ""

    def switch(self, name: str, on: bool, user: str = "") -> dict:
        """Switch the check of ``name`` on or off; returns its view."""
        with self._lock:
            st = self._state[name]
            st.on = bool(on)
            st.by = user if on else st.by
            if not on:
                st.problem = ""
            st.version += 1
            if on and (self._thread is None or not self._thread.is_alive()) and not self._stop.is_set():
                self._thread = threading.Thread(target=self._run, name="console-aim", daemon=True)
                self._thread.start()
        self._wake.set()
        return self.view(name)

    def close(self) -> None:
        self._stop.set()
        self._wake.set()
        t = self._thread
        if t is not None:
            t.join(FRAME_WAIT_S * 2 + 5)

    # -- the worker --------------------------------------------------------------------------------
    def _update(self, name: str, **change) -> None:
        with self._lock:
            st = self._state[name]
            for k, v in change.items():
                setattr(st, k, v)
            st.version += 1

    def _run(self) -> None:
        while not self._stop.is_set():
            with self._lock:
                wanted = [n for n, st in self._state.items() if st.on]
                if not wanted:
                    self._thread = None
                    return
            for name in wanted:
                if self._stop.is_set():
                    return
                with self._lock:
                    if not self._state[name].on:
                        continue
                self._update(name, busy=True)
                try:
                    verdicts, png, at, found = self.check(name)
                except NotChecked as exc:
                    self._update(name, busy=False, problem=str(exc))
                except Exception as exc:  # one odd picture never stops the checks of every camera
                    self._update(name, busy=False, problem=f"not checked: {type(exc).__name__}: {exc}")
                else:
                    with self._lock:
                        n = self._state[name].n + 1
                    self._update(name, busy=False, problem="", verdicts=verdicts, png=png, at=at, n=n, led_found=found)
            self._wake.clear()
            self._wake.wait(self.every_s)

    def check(self, name: str):
        """One aim check of ``name`` (see the module docstring): (verdicts, overlay PNG, when, LED found)."""
        why = self.refusal(name)
        if why:
            raise NotChecked(why)
        hub = self.console.hub
        hub.watch(name)
        try:
            on_jpeg, off_jpeg, at, found = self._pictures(name)
        finally:
            hub.unwatch(name)
        verdicts, png = aim_page_of(name, self.console.rig_config, on_jpeg, off_jpeg, self._reference(name))
        return verdicts, png, at, found

    def _pictures(self, name: str):
        """(LED-on JPEG, LED-off JPEG, when, the LED's state found): the LED left as found."""
        facts = self.console.facts
        facts.read_led(name)
        cf = facts.facts[name]
        found, why = cf.led, cf.led_why
        if found not in ("on", "off"):
            raise NotChecked(
                f"not checked: the LED state of {name} is not known ({why or 'not read'}), "
                f"so it could not be put back as it was"
            )
        first = self._frame_after(name, time.time())
        other = found != "on"
        result = facts.switch_led(name, other)
        try:
            if result["led_error"]:
                raise NotChecked(f"not checked: {result['led_error']}")
            second = self._frame_after(name, time.time())
        finally:
            if self.console.hub.source(name) != "fed":  # fed: the recording's LED now
                back = facts.switch_led(name, found == "on")
                if back["led_error"]:
                    raise NotChecked(f"the LED of {name} could not be put back {found}: {back['led_error']}")
        on, off = (first, second) if found == "on" else (second, first)
        return on.jpeg, off.jpeg, first.host_time, found

    def _frame_after(self, name: str, t: float):
        """The first whole frame of ``name`` in the hub taken after host time ``t``: by its camera
        stamp through the measured clock offset when both are known, else arrived ``AFTER_S``
        after ``t`` with ``FRESH_FRAMES`` frames since. NotChecked when a recording takes the
        camera or no such frame comes within ``FRAME_WAIT_S``."""
        hub = self.console.hub
        offset = self.console.facts.facts[name].offset_s
        start = hub.latest(name)
        start_seq = start.seq if start is not None else 0
        end = time.monotonic() + FRAME_WAIT_S
        while time.monotonic() < end and not self._stop.is_set():
            why = self.refusal(name)
            if why:
                raise NotChecked(f"stopped: a recording took {name} during the check; its LED is left to it")
            lt = hub.latest(name)
            if lt is not None:
                fr = lt.frame
                if fr.camera_time is not None and offset is not None:
                    after = fr.camera_time - offset > t + AFTER_S
                else:
                    after = lt.arrival > t + AFTER_S and lt.seq >= start_seq + FRESH_FRAMES
                if after:
                    try:
                        check_whole(fr, name)
                        return fr
                    except (NotWhole, VtsError):
                        pass  # a torn picture: the next one
            time.sleep(0.03)
        st = hub.status(name)
        raise NotChecked(
            f"not checked: no new picture from {name} within {FRAME_WAIT_S:g} s"
            + (f" ({st['why']})" if st.get("why") else "")
        )

    def _reference(self, name: str):
        """The drift baseline's wall markers of ``name`` (the names the page holds), or None."""
        names = getattr(self.console, "names", None)
        wall = names.current(name).get("wall") if names is not None else None
        return [(x, y) for _, x, y in wall.points] if wall is not None and wall.points else None


__all__ = ["AimChecks", "AimState", "NotChecked", "EVERY_S"]
