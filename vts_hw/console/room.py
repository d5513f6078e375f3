"""What the Room page says of each camera besides its picture: LED, clock offset, latest daily QA.

Every call here may wait on a device or the store, so the web layer runs them in threads
(``asyncio.to_thread``), never on its event loop. Control requests to one camera (LED, clock)
are made one at a time (a lock per camera); the picture's stream is a connection of its own.

* LED: the camera contract switches it (``led_on``/``led_off``) and reads nothing back, so the
  page says what was switched here and when, or that the state is not known.
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

from vts_hw.errors import VtsError

OFFSET_EVERY_S = 300.0
QA_EVERY_S = 30.0
OFFSET_SAMPLES = 3


@dataclass
class CameraFacts:
    led: str = "unknown"             # "on", "off", "unknown"
    led_at: float | None = None      # host epoch s it was switched here
    led_error: str = ""
    offset_s: float | None = None
    offset_unc_s: float | None = None
    offset_at: float | None = None
    offset_source: str = ""
    offset_error: str = ""
    qa_state: str | None = None      # OK / TOLERANCE / ACTION, None: no daily QA
    qa_at: float | None = None
    qa_run: int | None = None
    lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def as_dict(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "lock"}


class RoomFacts:
    """The facts of every camera of ``cameras`` (name -> open camera, or None), the rig's name
    ``rig`` and the store's ``open_store()`` (a callable returning a ResultsStore, or None)."""

    def __init__(self, cameras: dict, rig: str, open_store=None, clock=time.time):
        self.cameras = cameras
        self.rig = rig
        self.open_store = open_store
        self.clock = clock
        self.facts = {name: CameraFacts() for name in cameras}
        self.qa_note = "not read yet"         # why there is no daily QA state, in words
        self._qa_read_at: float | None = None
        self._offsets_at: float | None = None

    # -- LED ------------------------------------------------------------------------------------------
    def switch_led(self, name: str, on: bool) -> dict:
        """Switch the LED ring of ``name``; returns its facts. A device that fails is said in
        ``led_error`` (and the state becomes unknown: the switch may or may not have happened)."""
        cam, facts = self.cameras[name], self.facts[name]
        with facts.lock:
            try:
                cam.led_on() if on else cam.led_off()
            except VtsError as exc:
                facts.led, facts.led_at, facts.led_error = "unknown", self.clock(), str(exc)
            else:
                facts.led, facts.led_at, facts.led_error = ("on" if on else "off"), self.clock(), ""
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
        from vts_hw.report.drift import collect
        if self.open_store is None:
            self.qa_note = "no results store named"
            return
        try:
            store = self.open_store()
            try:
                report = collect(store, rig=self.rig)
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

    # -- the page's view ------------------------------------------------------------------------------
    def refresh_due(self) -> None:
        """Measure what is due (called from a thread every few seconds)."""
        now = time.monotonic()
        if self._qa_read_at is None or now - self._qa_read_at >= QA_EVERY_S:
            self._qa_read_at = now
            self.read_daily_qa()
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
