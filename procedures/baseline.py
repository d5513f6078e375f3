"""Setting the drift baselines: LED on, a few snapshots per camera, the wall markers seen.

The result (:class:`BaselineSet`) has the one QA result shape and is stored by the recorder
(vts_hw.store.recorder) as a run of ``drift-baseline`` (vts_hw.catalog.BASELINE): per camera
the number of markers (subject ``cam1``, metric ``baseline_markers``) and each marker's
position (subject ``cam1/M1``, metrics ``baseline_x_px`` and ``baseline_y_px``), all OK. The
store reads them back (vts_hw.store.baselines); setting a new one never changes the old runs.

Only wall markers make a baseline (vts_hw/vision/marker_roles.py): the frames are spread over
:data:`SPAN_S` (a breath moves a patient's markers), a marker that moved is the patient's, and a
still one that two calibrated cameras place inside the table-and-gantry volume (``room``: the
rig's calibration and VTS -> SPECT mapping, procedures/marker_room.py) is on the table. Each
camera also stores how many markers it left out (``baseline_not_wall``); the stored shape is
otherwise the one older versions wrote and read (docs/decisions/0086-marker-roles.md).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

from vts_hw.catalog import BASELINE
from vts_hw.errors import VtsError
from vts_hw.procedures.drift import SPAN_S, acquire_led_frames
from vts_hw.procedures.marker_room import room_geometry
from vts_hw.results import Measure
from vts_hw.tolerance import State
from vts_hw.vision.marker_roles import follow, roles_of_tracks
from vts_hw.vision.wall_baseline import Baseline, NoBaseline
from vts_hw.vision.wall_markers import baseline_of_tracks, frame_points

PROCEDURE = BASELINE.name
__all__ = ["BaselineSet", "NoBaseline", "NoMarkers", "take_baseline", "take_baselines", "PROCEDURE", "SPAN_S"]


class NoMarkers(VtsError):
    """A camera showed no wall markers with the LED on: no baseline is set for any camera (exit
    4: the camera, its LED ring or its view of the wall is not as a baseline needs it)."""

    exit_code = 4


def take_baseline(
    cam, frames: int = 5, clock: Callable[[], float] = time.time, on_frame=None, span_s: float = SPAN_S
) -> Baseline:
    """LED on, ``frames`` snapshots of camera ``cam`` over ``span_s``, its wall markers (by
    motion alone: ``room`` needs other cameras, :func:`take_baselines`).
    ``on_frame(camera, frame, taken, needed)``: as :func:`acquire_led_frames`'s, with the name."""
    return take_baselines([cam], frames=frames, clock=clock, on_frame=on_frame, span_s=span_s).baselines[0]


def _frames(cam, frames: int, on_frame, span_s: float):
    tell = None if on_frame is None else (lambda frame, led, taken, needed: on_frame(cam.name, frame, taken, needed))
    every = span_s / (frames - 1) if frames > 1 else 0.0
    on, _ = acquire_led_frames(cam, frames, on_frame=tell, every_s=every)
    return follow(frame_points([f.jpeg for f in on]))


@dataclass
class BaselineSet:
    """The baselines of several cameras, as one run to store (every measure OK: a record, not a check)."""

    baselines: list[Baseline]
    procedure: str = PROCEDURE
    room_why: str = ""  # why the markers were not placed in the room (no mapping...): "" when they were

    @property
    def measures(self) -> list[Measure]:
        out = []
        for b in self.baselines:
            out.append(Measure(b.camera, "baseline_markers", float(len(b.markers)), "markers", State.OK))
            out.append(Measure(b.camera, "baseline_not_wall", float(len(b.others)), "markers", State.OK))
            for m in b.markers:
                out.append(Measure(f"{b.camera}/{m.id}", "baseline_x_px", m.x, "px", State.OK))
                out.append(Measure(f"{b.camera}/{m.id}", "baseline_y_px", m.y, "px", State.OK))
        return out

    @property
    def state(self) -> State:
        return State.OK

    def results(self) -> str:
        lines = []
        for b in self.baselines:
            lines.append(f"{b.camera}: baseline of {len(b.markers)} markers")
            lines += [f"    left out ({x:.0f}, {y:.0f}) px: {r.role}, {r.reason}" for x, y, r in b.others]
        if self.room_why:
            lines.append(f"  where the still markers lie was not checked: {self.room_why}")
        return "\n".join(lines)

    def results_data(self) -> dict:
        return {
            "procedure": self.procedure,
            "room": self.room_why or "placed",
            "baselines": [
                {
                    "camera": b.camera,
                    "taken": b.taken,
                    "markers": [m.__dict__ for m in b.markers],
                    "not_wall": [{"x": x, "y": y, **r.to_dict()} for x, y, r in b.others],
                }
                for b in self.baselines
            ],
        }

    def plot(self, path=None) -> bytes:
        raise NotImplementedError("a baseline has no plot")


def take_baselines(
    cameras, *, frames: int = 5, clock: Callable[[], float] = time.time, on_frame=None, rig=None, span_s: float = SPAN_S
) -> BaselineSet:
    """The drift baseline of each of ``cameras`` (given, opened by the caller): each camera's
    frames spread over ``span_s``, its markers followed; those that moved left out; the still
    ones placed in the room of ``rig`` (its calibration and mapping: procedures/marker_room.py;
    None or no mapping: motion alone, said in ``room_why``) and those on the table left out. NoMarkers when a camera keeps no wall marker (then
    nothing is to be stored for any camera). ``on_frame``: see :func:`take_baseline`."""
    room, why = (
        room_geometry(rig)
        if len(cameras) > 1
        else (None, "one camera: where a marker lies is not known, judged by motion alone")
    )
    tracks = {cam.name: _frames(cam, frames, on_frame, span_s) for cam in cameras}
    # every marker goes to the room (one still here may have moved in another camera's frames);
    # only the still ones take its answer
    placed = room.place({n: [(t.x, t.y) for t in ts] for n, ts in tracks.items()}) if room is not None else {}
    out = []
    for n, ts in tracks.items():
        still = [r for r, rule1 in zip(placed.get(n, [None] * len(ts)), roles_of_tracks(ts)) if rule1 is None]
        b = baseline_of_tracks(n, ts, clock(), still)
        if not b.markers:
            left = f" ({len(b.others)} seen, none a wall marker: {b.others[0][2].reason})" if b.others else ""
            raise NoMarkers(f"camera {n}: no wall markers found with the LED on{left}; baseline not set")
        out.append(b)
    return BaselineSet(out, room_why=why)
