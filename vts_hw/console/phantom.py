"""The phantom's spheres named on the Room page: the marker worker's detections handed to the
phantom locator (:mod:`vts_hw.vision.phantom_locator`) about once a second, its names given to
the marker names (:mod:`.names`, kind ``phantom``, ``S1``..``S7``).

The locator is built once from the rig config (``calibration.cameras`` and ``calibration.mapping``,
relative paths from the rig.yaml's folder); without them, or with a mapping that keeps no sphere
centres, nothing is located and :attr:`PhantomNames.why` says why. Each look takes the latest
detections of every camera made within :data:`FRESH_S` of each other (a phantom on the table is
still; one moving fits badly and names nothing). A good fit names its spheres on each camera for
:data:`HOLD_S`; a look that is not confident clears them at once: never a wrong name. Any error
in a look is kept in ``why`` and never reaches the worker, the hub or the live path.
docs/decisions/0073-phantom-names.md.
"""

from __future__ import annotations

import threading
import time

import numpy as np

from vts_hw.errors import VtsError
from vts_hw.vision.phantom_locator import PhantomLocator

EVERY_S = 1.0  # one look a second at most (the shape search costs a few ms to tens of ms)
FRESH_S = 1.0  # detections older than this (host s) than the newest are left out
HOLD_S = 3.0  # names given hold this long unless a later look clears or replaces them


def locator_for(rig):
    """``(PhantomLocator, "")`` from the rig config's calibration and mapping, or ``(None, why)``."""
    if rig is None:
        return None, "the console was started without a rig config"
    cal, mapping = rig.calibration.cameras, rig.calibration.mapping
    if cal is None:
        return None, "no camera calibration (calibration.cameras in rig.yaml)"
    if mapping is None:
        return None, "no VTS → SPECT mapping (calibration.mapping in rig.yaml): it keeps the phantom's shape"
    try:
        return PhantomLocator.from_files(cal, mapping, [c.name for c in rig.cameras]), ""
    except (VtsError, OSError) as exc:
        return None, str(exc)


class PhantomNames:
    """Feed ``names`` (a :class:`~.names.MarkerNames`) the spheres ``locator`` finds (None: ``why``)."""

    def __init__(
        self,
        names,
        locator=None,
        why: str = "",
        *,
        every_s: float = EVERY_S,
        hold_s: float = HOLD_S,
        clock=time.monotonic,
    ):
        self.names = names
        self.locator = locator
        self.why = why if locator is None else ""
        self.every_s, self.hold_s, self.clock = float(every_s), float(hold_s), clock
        self.looks = 0  # looks made
        self.last = None  # the last PhantomSeen
        self._named: set[str] = set()
        self._at: float | None = None
        self._lock = threading.Lock()

    @classmethod
    def for_rig(cls, names, rig, **kw) -> PhantomNames:
        locator, why = locator_for(rig)
        return cls(names, locator, why, **kw)

    def said(self) -> str:
        """Where the phantom stands, in words for the Room page: named (the fit), not named and
        why, not looked for and why, or not looked at yet."""
        with self._lock:
            if self.locator is None:
                return f"phantom not looked for: {self.why}"
            if self.why:
                return f"phantom not named: {self.why}"
            if self.last is None:
                return "looking for the phantom"
            return self.last.source

    def due(self) -> bool:
        return self.locator is not None and (self._at is None or self.clock() - self._at >= self.every_s)

    def look(self, found: dict) -> bool:
        """One look at the latest ``found`` (camera -> markers.Found, with ``t``); True when the
        names changed (the caller labels its frames again)."""
        with self._lock:
            self._at = self.clock()
            self.looks += 1
            try:
                seen = self.locator.locate(_detections(found))
            except Exception as exc:  # never into the worker: the page shows no sphere, the reason is kept
                self.why, self.last = f"the locator failed: {type(exc).__name__}: {exc}", None
                return self._clear()
            self.last = seen
            if seen.why:
                self.why = seen.why
                return self._clear()
            self.why = ""
            for cam, pts in seen.names.items():
                if pts:
                    self.names.set(cam, "phantom", pts, source=seen.source, hold_s=self.hold_s)
            now_named = {c for c, p in seen.names.items() if p}
            for cam in self._named - now_named:
                self.names.clear(cam, "phantom")
            self._named = now_named
            return True

    def _clear(self) -> bool:
        changed = bool(self._named)
        for cam in self._named:
            self.names.clear(cam, "phantom")
        self._named = set()
        return changed


def _detections(found: dict) -> dict:
    """Each camera's detections (N×2 px) of about one instant: within FRESH_S of the newest."""
    ok = {n: f for n, f in found.items() if f is not None and not f.problem and f.markers}
    if not ok:
        return {}
    newest = max(f.t for f in ok.values())
    return {n: np.array([(m["x"], m["y"]) for m in f.markers], float) for n, f in ok.items() if newest - f.t <= FRESH_S}


__all__ = ["PhantomNames", "locator_for", "EVERY_S", "HOLD_S", "FRESH_S"]
