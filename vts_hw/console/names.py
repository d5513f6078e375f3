"""What each marker on a live picture is, where that is known: a wall marker, a phantom sphere, a
patient band marker; otherwise "unidentified" (and its number).

A camera's *named points* are pixel positions with a name, of one *kind*, given by a *source*:

* ``wall``: the camera's drift baseline in the results store (the daily QA's wall markers,
  ``M1``..., :func:`vts_hw.store.baselines.load_baseline`), read with the daily QA state
  (:meth:`vts_hw.console.room.RoomFacts.read_daily_qa`); they hold until the next read.
* ``band``: the live tracker's marker identities while a scan runs; the Scan page gives them
  (:meth:`MarkerNames.set` with ``hold_s``: a band marker moves with the breath, so a position
  given a second ago says nothing now).
* ``phantom``: the 7-sphere phantom's spheres (``S1``..``S7``, numbered as the VTS → SPECT
  mapping numbers them), given by the marker worker about once a second when the phantom's shape
  (kept in the mapping file) fits what the calibrated cameras see (:mod:`.phantom`,
  :mod:`vts_hw.vision.phantom_locator`); a look that is not confident clears them.

A detection takes the name of the nearest named point of its camera within ``gate_px``, one to
one (Hungarian on the distance: :func:`vts_hw.vision.marker_roles.match_markers`, the drift
QA's own matching and gate), the live kinds first (band, phantom), then the wall. docs/decisions/
0066-room-led-and-names.md says why.

A detection none of them names, that moved over the camera's last :data:`HISTORY` pictures
(:meth:`MarkerNames.seen`), is the patient's as the daily QA and the baseline call it (rule 1 of
:mod:`vts_hw.vision.marker_roles`, the same rule and floor): kind ``band``, name ``patient``.
docs/decisions/0086-marker-roles.md.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from vts_hw.vision.marker_roles import GATE_PX, PATIENT, follow, match_markers, roles_of_tracks

KINDS = ("band", "phantom", "wall")  # the order detections are matched in
UNIDENTIFIED = "unidentified"
HISTORY = 9  # pictures a camera's markers are followed over: about 3 s at the marker worker's 3 a second
MOVED = "moved over the camera's last pictures: breathing or a body (as the daily QA tells them)"


@dataclass(frozen=True)
class NamedPoints:
    """Named pixel positions of one kind on one camera: ``points`` is ``((name, x, y), ...)``;
    ``source`` says where they come from (shown in the legend); they hold until ``until``
    (host epoch s; None: until replaced)."""

    kind: str
    points: tuple[tuple[str, float, float], ...]
    source: str
    given_at: float
    until: float | None = None


class MarkerNames:
    """The named points of each camera, by kind; :meth:`label` names a frame's detections.
    Thread-safe: the Scan page's tracker thread, the facts thread and the marker thread share it."""

    def __init__(self, *, gate_px: float = GATE_PX, clock=time.time):
        self.gate_px = float(gate_px)
        self.clock = clock
        self._lock = threading.Lock()
        self._named: dict[str, dict[str, NamedPoints]] = {}
        self._seen: dict[str, deque] = {}

    def seen(self, camera: str, points) -> None:
        """The centres (px) of every marker of ``camera``'s latest picture, for telling which move."""
        pts = np.asarray([(float(x), float(y)) for x, y in points], float).reshape(-1, 2)
        with self._lock:
            self._seen.setdefault(camera, deque(maxlen=HISTORY)).append(pts)

    def _moving(self, camera: str, pts: np.ndarray) -> list[bool]:
        """Whether each of ``pts`` (the latest picture's) moved over the pictures seen."""
        with self._lock:
            history = list(self._seen.get(camera, ()))
        out = [False] * len(pts)
        if len(history) < 2 or not len(pts):
            return out
        tracks = follow(history)
        moved = np.array(
            [
                t.points[-1]
                for t, r in zip(tracks, roles_of_tracks(tracks))
                if r is not None and r.role == PATIENT and len(t.points) >= 2
            ]
        ).reshape(-1, 2)
        for i, p in enumerate(pts):
            out[i] = bool(len(moved)) and float(np.min(np.hypot(*(moved - p).T))) < 0.5
        return out

    def set(self, camera: str, kind: str, points, *, source: str, hold_s: float | None = None) -> None:
        """Name ``points`` (``(name, x_px, y_px)`` each) on ``camera`` as ``kind`` (one of
        :data:`KINDS`), replacing that kind's earlier ones; ``hold_s``: they expire after that
        many seconds (None: until replaced or cleared)."""
        if kind not in KINDS:
            raise ValueError(f"marker kind must be one of {', '.join(KINDS)}, not {kind!r}")
        now = self.clock()
        pts = tuple((str(n), float(x), float(y)) for n, x, y in points)
        with self._lock:
            self._named.setdefault(camera, {})[kind] = NamedPoints(
                kind, pts, source, now, None if hold_s is None else now + float(hold_s)
            )

    def clear(self, camera: str, kind: str) -> None:
        with self._lock:
            self._named.get(camera, {}).pop(kind, None)

    def current(self, camera: str) -> dict[str, NamedPoints]:
        """The kinds that hold now on ``camera``."""
        now = self.clock()
        with self._lock:
            held = dict(self._named.get(camera, {}))
        return {k: v for k, v in held.items() if v.until is None or now <= v.until}

    def label(self, camera: str, marks: list[dict]) -> tuple[list[dict], list[dict]]:
        """``marks`` (dicts with ``x``, ``y``, ``n``) each with its ``name`` and ``kind``
        (``unidentified``: the number ``n`` is its only name), and the legend: one entry per
        kind that holds (kind, source, how many named here of how many known)."""
        held = self.current(camera)
        out = [dict(m, kind=UNIDENTIFIED, name=str(m["n"])) for m in marks]
        free = list(range(len(out)))
        legend: list[dict[str, Any]] = []
        for kind in KINDS:
            named = held.get(kind)
            if named is None:
                continue
            found = 0
            if named.points and free:
                ref = np.array([(x, y) for _, x, y in named.points])
                pts = np.array([(out[i]["x"], out[i]["y"]) for i in free])
                taken = set()
                for r, j in match_markers(ref, pts, self.gate_px):
                    out[free[j]].update(kind=kind, name=named.points[r][0])
                    taken.add(free[j])
                    found += 1
                free = [i for i in free if i not in taken]
            legend.append({"kind": kind, "source": named.source, "known": len(named.points), "found": found})
        if free:
            moving = self._moving(camera, np.array([(out[i]["x"], out[i]["y"]) for i in free]))
            n_moved = sum(moving)
            for i, m in zip(free, moving):
                if m:
                    out[i].update(kind="band", name=PATIENT)
            if n_moved:
                band = next((e for e in legend if e["kind"] == "band"), None)
                if band is None:
                    legend.insert(0, {"kind": "band", "source": MOVED, "known": n_moved, "found": n_moved})
                else:
                    band.update(
                        known=band["known"] + n_moved,
                        found=band["found"] + n_moved,
                        source=f"{band['source']}; {n_moved} more {MOVED}",
                    )
        return out, legend


def wall_points(baseline) -> list[tuple[str, float, float]]:
    """A drift baseline's markers as named points."""
    return [(m.id, m.x, m.y) for m in baseline.markers]


__all__ = ["MarkerNames", "NamedPoints", "KINDS", "UNIDENTIFIED", "wall_points"]
