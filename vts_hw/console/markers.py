"""The markers on the live pictures: detection on each watched camera's latest frame, a few times a second.

One worker thread for all cameras (detection costs a few ms to tens of ms a frame; the readers
never wait for it): every ``1 / rate_hz`` s it takes the latest frame of each watched camera
that it has not yet looked at and runs :func:`vts_hw.vision.detect.detect_jpeg` on it, the same
detection the procedures use. The page gets the positions in the frame's own pixels, with the
frame's ``seq``, and draws them over the picture (the JPEG is never decoded for the page or
re-encoded). A frame that does not decode is said so, never shown as "no markers". Each marker
is named where that is known (a wall marker, a phantom sphere, a band marker: :mod:`.names`),
with the legend of what named them; otherwise it is "unidentified" and numbered. About once a
second, after a round of the cameras, the phantom is looked for in the latest detections
(:mod:`.phantom`: the rig's calibration and the mapping's sphere centres); when its spheres are
named, the round's results are labelled again at once; never while a recording feeds the hub (a
scan's live path shares this process). A failure there is said in the phantom's ``why``, never
here.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, replace

import cv2
import numpy as np

from vts_hw.vision.detect import detect

RATE_HZ = 3.0


@dataclass(frozen=True)
class Found:
    """The markers found on one frame of one camera."""

    camera: str
    seq: int
    width: int
    height: int
    markers: tuple[dict, ...]
    problem: str = ""
    legend: tuple[dict, ...] = ()  # what named the markers (names.MarkerNames.label)
    t: float = 0.0  # host epoch s of the detection (which frames are of one instant)

    def as_dict(self) -> dict:
        return {
            "camera": self.camera,
            "seq": self.seq,
            "width": self.width,
            "height": self.height,
            "markers": list(self.markers),
            "problem": self.problem,
            "legend": list(self.legend),
        }


def find_markers(camera: str, seq: int, jpeg: bytes) -> Found:
    """The blobs of one JPEG as the page draws them: number (1.. in detect's order, top to
    bottom), centre and diameter in the frame's pixels."""
    gray = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    if gray is None:
        return Found(camera, seq, 0, 0, (), "the frame does not decode: markers not looked for", t=time.time())
    result = detect(gray)
    marks = tuple(
        {"n": i + 1, "x": round(b.x, 2), "y": round(b.y, 2), "d": round(2.0 * math.sqrt(max(b.area, 1) / math.pi), 1)}
        for i, b in enumerate(result.blobs)
    )
    return Found(camera, seq, int(gray.shape[1]), int(gray.shape[0]), marks, t=time.time())


class MarkerWorker:
    """Detect markers on ``hub``'s watched cameras at ``rate_hz``; :meth:`found` is the latest
    result of each camera, its markers named by ``names`` (a :class:`~.names.MarkerNames`);
    ``phantom`` (a :class:`~.phantom.PhantomNames`, optional) names the phantom's spheres."""

    def __init__(self, hub, rate_hz: float = RATE_HZ, names=None, phantom=None):
        self.hub = hub
        self.names = names
        self.phantom = phantom
        self.period = 1.0 / float(rate_hz)
        self._found: dict[str, Found] = {}
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.looked = 0  # frames looked at (all cameras)
        self._thread = threading.Thread(target=self._run, name="console-markers", daemon=True)
        self._thread.start()

    def found(self, camera: str) -> Found | None:
        with self._lock:
            return self._found.get(camera)

    def _run(self) -> None:
        while not self._stop.wait(self.period):
            self._round()
            # not while a recording feeds the hub: its live path shares this process (and a
            # patient, not the phantom, is on the table)
            if self.phantom is not None and self.names is not None and self.phantom.due() and not self._recording():
                self._look_for_phantom()

    def _recording(self) -> bool:
        """A recording feeds the hub: the phantom is not looked for."""
        return any(self.hub.source(n) == "fed" for n in self.hub.names)

    def phantom_said(self) -> str | None:
        """The phantom's state in words (None: the console does not look for one)."""
        if self.phantom is None:
            return None
        if self.phantom.locator is not None and self._recording():
            return "phantom not looked for while a recording feeds the cameras"
        return self.phantom.said()

    def _look_for_phantom(self) -> None:
        with self._lock:
            found = dict(self._found)
        try:
            changed = self.phantom.look(found)
        except Exception:  # PhantomNames keeps its own errors; nothing stops the markers
            return
        if not changed:
            return
        for name, got in found.items():  # this round's pictures named now, not a round later
            if got.problem:
                continue
            try:
                marks, legend = self.names.label(name, [{k: m[k] for k in ("n", "x", "y", "d")} for m in got.markers])
            except Exception:
                continue
            with self._lock:
                if self._found.get(name) is got:
                    self._found[name] = replace(got, markers=tuple(marks), legend=tuple(legend))

    def _round(self) -> None:
        for name in self.hub.names:
            if self._stop.is_set():
                return
            st = self.hub.status(name)
            if not st["viewers"]:
                continue
            latest = self.hub.latest(name)
            done = self.found(name)
            if latest is None or (done is not None and done.seq == latest.seq):
                continue
            try:
                got = find_markers(name, latest.seq, latest.frame.jpeg)
                if self.names is not None and not got.problem:
                    self.names.seen(name, [(m["x"], m["y"]) for m in got.markers])
                    marks, legend = self.names.label(name, list(got.markers))
                    got = replace(got, markers=tuple(marks), legend=tuple(legend))
            except Exception as exc:  # never let one odd frame stop the markers of every camera
                got = Found(name, latest.seq, 0, 0, (), f"detection failed: {type(exc).__name__}: {exc}")
            with self._lock:
                self._found[name] = got
                self.looked += 1

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5.0)


__all__ = ["MarkerWorker", "Found", "find_markers"]
