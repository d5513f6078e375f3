"""What the Room page says of each camera besides its picture: LED, clock offset, latest daily QA.

Every call here may wait on a device or the store, so the web layer runs them in threads
(``asyncio.to_thread``), never on its event loop. Control requests to one camera (LED, clock)
are made one at a time (a lock per camera); the picture's stream is a connection of its own.

* LED: read back from the camera (``camera.led_state()``: the output port's state, VAPIX
  ``port.cgi?checkactive``) every ``LED_EVERY_S`` and right after a switch; a switch the camera
  does not show within ``camera_led.READ_BACK_S`` "did not take" and the page says so. A kind that cannot
  tell (a replay) is "not known", never "off".
* Marker names: the wall markers of each camera's drift baseline (the store), read with the
  daily QA and handed to the marker names (:mod:`.names`).
* Clock offset: ``camera.clock_offset`` measured when the console starts and every
  ``OFFSET_EVERY_S`` (and when asked); its age is shown, and a camera that did not answer
  says so instead of an old figure.
* Daily QA: each camera's latest daily (or drift) QA of this rig in the store, read as the
  drift and rooms reports read it (:func:`vts_hw.report.drift.collect`), again every
  ``QA_EVERY_S``; a store that cannot be read is said so, never "OK".
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

from vts_hw.camera import Illumination
from vts_hw.camera_led import READ_BACK_S, LedNotTaken, switch_led
from vts_hw.console.names import wall_points
from vts_hw.errors import VtsError
from vts_hw.report.drift import collect
from vts_hw.store.baselines import load_baseline
from vts_hw.vision.wall_baseline import NoBaseline

OFFSET_EVERY_S = 300.0
QA_EVERY_S = 30.0
LED_EVERY_S = 5.0
OFFSET_SAMPLES = 3


@dataclass
class CameraFacts:
    led: str = "unknown"  # "on", "off" (as the camera says), "unknown"
    led_at: float | None = None  # host epoch s the camera said so
    led_why: str = ""  # why the state is not known
    led_asked: str | None = None  # "on"/"off": the last switch asked here ...
    led_asked_at: float | None = None
    led_error: str = ""  # ... and why it failed or did not take ("" when it did)
    offset_s: float | None = None
    offset_unc_s: float | None = None
    offset_at: float | None = None
    offset_source: str = ""
    offset_error: str = ""
    qa_state: str | None = None  # OK / TOLERANCE / ACTION, None: no daily QA
    qa_at: float | None = None
    qa_run: int | None = None
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "lock"}


class RoomFacts:
    """The facts of every camera of ``cameras`` (name -> open camera, or None), the rig's name
    ``rig`` and the store's ``open_store()`` (a callable returning a ResultsStore, or None)."""

    def __init__(self, cameras: dict, rig: str, open_store=None, clock=time.time, names=None):
        self.cameras = cameras
        self.rig = rig
        self.open_store = open_store
        self.clock = clock
        self.names = names  # names.MarkerNames: the wall markers go there
        self._led_read_at: float | None = None
        self.facts = {name: CameraFacts() for name in cameras}
        self.qa_note = "not read yet"  # why there is no daily QA state, in words
        self._qa_read_at: float | None = None
        self._offsets_at: float | None = None

    # -- LED ------------------------------------------------------------------------------------------
    def _read_led(self, cam, facts: CameraFacts) -> None:
        """The LED's state as the camera says it (under ``facts.lock``)."""
        try:
            state = cam.led_state() if isinstance(cam, Illumination) else None  # no LED: cannot tell
        except VtsError as exc:
            facts.led, facts.led_at, facts.led_why = "unknown", self.clock(), f"the camera did not say ({exc})"
            return
        if state is None:
            facts.led, facts.led_at = "unknown", self.clock()
            facts.led_why = "this camera cannot tell (no output port it reports)"
        else:
            facts.led, facts.led_at, facts.led_why = ("on" if state else "off"), self.clock(), ""

    def read_led(self, name: str) -> None:
        cam, facts = self.cameras[name], self.facts[name]
        if cam is None:
            return
        with facts.lock:
            self._read_led(cam, facts)

    def switch_led(self, name: str, on: bool, settle_s: float = READ_BACK_S) -> dict:
        """Switch the LED ring of ``name`` and read its state back (camera_led.switch_led, as `vts
        camera led` does); returns its facts. A device that fails, or a switch the camera does not
        show within ``settle_s``, is said in ``led_error``; the state shown is always the one read."""
        cam, facts = self.cameras[name], self.facts[name]
        want = "on" if on else "off"
        with facts.lock:
            facts.led_asked, facts.led_asked_at, facts.led_error = want, self.clock(), ""
            try:
                switch_led(cam, on, within_s=settle_s)
            except LedNotTaken:
                facts.led_error = ""  # worded below from the state read
            except VtsError as exc:
                facts.led_error = f"switching it {want} failed: {exc}"
            self._read_led(cam, facts)
            if not facts.led_error and facts.led not in (want, "unknown"):
                facts.led_error = (
                    f"switched {want} here, but the camera says its LED output is {facts.led}: the switch did not take"
                )
            return facts.as_dict()

    # -- clock offsets --------------------------------------------------------------------------------
    def measure_offset(self, name: str) -> None:
        cam, facts = self.cameras[name], self.facts[name]
        if cam is None:
            return
        with facts.lock:
            try:
                off = cam.clock_offset(OFFSET_SAMPLES)
            except VtsError as exc:
                facts.offset_error, facts.offset_at = str(exc), self.clock()
                facts.offset_s = facts.offset_unc_s = None
            else:
                facts.offset_s, facts.offset_unc_s = off.offset_s, off.uncertainty_s
                facts.offset_at, facts.offset_source, facts.offset_error = self.clock(), off.source, ""

    # -- daily QA -------------------------------------------------------------------------------------
    def read_daily_qa(self) -> None:
        """Each camera's latest daily QA state of this rig, from the store."""
        if self.open_store is None:
            self.qa_note = "no results store named"
            return
        try:
            store = self.open_store()
            try:
                report = collect(store, rig=self.rig)
                self._read_walls(store)
            finally:
                store.close()
        except VtsError as exc:
            self.qa_note = f"the results store could not be read ({exc})"
            for f in self.facts.values():
                f.qa_state = f.qa_at = f.qa_run = None
            return
        seen = 0
        for name, f in self.facts.items():
            cam = report.cameras.get(name)
            latest = cam.latest if cam is not None else None
            if latest is None:
                f.qa_state = f.qa_at = f.qa_run = None
            else:
                f.qa_state, f.qa_at, f.qa_run = str(latest.state), latest.t, latest.run_id
                seen += 1
        self.qa_note = "" if seen else f"no daily QA of rig {self.rig!r} in the store yet"

    def _read_walls(self, store) -> None:
        """Each camera's drift baseline as its wall markers' names (none: no wall names)."""
        if self.names is None:
            return
        for name in self.cameras:
            try:
                b = load_baseline(store, name, rig=self.rig)
            except NoBaseline:
                self.names.clear(name, "wall")
                continue
            when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime(b.taken))
            self.names.set(name, "wall", wall_points(b), source=f"drift baseline run {b.run_id} ({when})")

    # -- the page's view ------------------------------------------------------------------------------
    def refresh_due(self) -> None:
        """Measure what is due (called from a thread every few seconds)."""
        now = time.monotonic()
        if self._qa_read_at is None or now - self._qa_read_at >= QA_EVERY_S:
            self._qa_read_at = now
            self.read_daily_qa()
        if self._led_read_at is None or now - self._led_read_at >= LED_EVERY_S:
            self._led_read_at = now
            for name in self.cameras:
                self.read_led(name)
        if self._offsets_at is None or now - self._offsets_at >= OFFSET_EVERY_S:
            self._offsets_at = now
            for name in self.cameras:
                self.measure_offset(name)

    def view(self, name: str) -> dict:
        out = self.facts[name].as_dict()
        if out["qa_state"] is None:
            out["qa_note"] = self.qa_note or "no daily QA of this camera in the store"
        return out


__all__ = ["RoomFacts", "CameraFacts"]
