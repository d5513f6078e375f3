"""Setting the drift baselines: LED on, a few snapshots per camera, the wall markers seen.

The result (:class:`BaselineSet`) has the one QA result shape and is stored by the recorder
(vts_hw.store.recorder) as a run of ``drift-baseline`` (vts_hw.catalog.BASELINE): per camera
the number of markers (subject ``cam1``, metric ``baseline_markers``) and each marker's
position (subject ``cam1/M1``, metrics ``baseline_x_px`` and ``baseline_y_px``), all OK. The
store reads them back (vts_hw.store.baselines); setting a new one never changes the old runs.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

from vts_hw.catalog import BASELINE
from vts_hw.errors import VtsError
from vts_hw.results import Measure
from vts_hw.tolerance import State
from vts_hw.procedures.drift import acquire_led_frames
from vts_hw.vision.wall_baseline import Baseline, NoBaseline

PROCEDURE = BASELINE.name
__all__ = ["BaselineSet", "NoBaseline", "NoMarkers", "take_baseline", "take_baselines", "PROCEDURE"]


class NoMarkers(VtsError):
    """A camera showed no wall markers with the LED on: no baseline is set for any camera."""


def take_baseline(cam, frames: int = 5, clock: Callable[[], float] = time.time, on_frame=None) -> Baseline:
    """LED on, ``frames`` snapshots of camera ``cam``, the wall markers seen in every one.
    ``on_frame(camera, frame, taken, needed)``: as :func:`acquire_led_frames`'s, with the name."""
    tell = None if on_frame is None else (lambda frame, led, taken, needed: on_frame(cam.name, frame, taken, needed))
    on, _ = acquire_led_frames(cam, frames, on_frame=tell)
    b = Baseline.from_frames(cam.name, [f.jpeg for f in on], clock())
    if not b.markers:
        raise NoMarkers(f"camera {cam.name}: no wall markers found with the LED on; baseline not set")
    return b


@dataclass
class BaselineSet:
    """The baselines of several cameras, as one run to store (every measure OK: a record, not a check)."""

    baselines: list[Baseline]
    procedure: str = PROCEDURE

    @property
    def measures(self) -> list[Measure]:
        out = []
        for b in self.baselines:
            out.append(Measure(b.camera, "baseline_markers", float(len(b.markers)), "markers", State.OK))
            for m in b.markers:
                out.append(Measure(f"{b.camera}/{m.id}", "baseline_x_px", m.x, "px", State.OK))
                out.append(Measure(f"{b.camera}/{m.id}", "baseline_y_px", m.y, "px", State.OK))
        return out

    @property
    def state(self) -> State:
        return State.OK

    def results(self) -> str:
        return "\n".join(f"{b.camera}: baseline of {len(b.markers)} markers" for b in self.baselines)

    def results_data(self) -> dict:
        return {"procedure": self.procedure,
                "baselines": [{"camera": b.camera, "taken": b.taken, "markers": [m.__dict__ for m in b.markers]}
                              for b in self.baselines]}

    def plot(self, path=None) -> bytes:
        raise NotImplementedError("a baseline has no plot")


def take_baselines(cameras, *, frames: int = 5, clock: Callable[[], float] = time.time,
                   on_frame=None) -> BaselineSet:
    """The drift baseline of each of ``cameras`` (given, opened by the caller); NoMarkers when
    a camera shows none (then nothing is to be stored for any camera). ``on_frame``: see
    :func:`take_baseline`."""
    return BaselineSet([take_baseline(cam, frames, clock, on_frame) for cam in cameras])
