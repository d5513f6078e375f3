"""Drift baselines live in the results store, as runs of procedure ``drift-baseline``.

Each baseline run holds, per camera, the number of markers (subject ``cam1``, metric
``baseline_markers``) and each marker's position (subject ``cam1/M1``, metrics
``baseline_x_px`` and ``baseline_y_px``). The latest finished baseline run that has a camera's
markers is that camera's baseline; setting a new one never changes the old runs.
"""

from __future__ import annotations

import time
from typing import Callable

from vts_hw.errors import VtsError
from vts_hw.procedures.drift import Baseline, BaselineMarker, acquire_led_frames

PROCEDURE = "drift-baseline"


class NoBaseline(VtsError):
    exit_code = 5


class NoMarkers(VtsError):
    """A camera showed no wall markers with the LED on: no baseline is set for any camera."""


def take_baseline(cam, frames: int = 5, clock: Callable[[], float] = time.time) -> Baseline:
    """LED on, ``frames`` snapshots of camera ``cam``, the wall markers seen in every one."""
    on, _ = acquire_led_frames(cam, frames)
    b = Baseline.from_frames(cam.name, [f.jpeg for f in on], clock())
    if not b.markers:
        raise NoMarkers(f"camera {cam.name}: no wall markers found with the LED on; baseline not set")
    return b


def set_baselines(store, cameras, *, frames: int = 5, clock: Callable[[], float] = time.time, rig: str = "",
                  operator: str = "", config_digest: str = "") -> tuple[int, list[Baseline]]:
    """The drift baseline of each of ``cameras`` (given, opened by the caller), stored as one
    run; returns (run id, baselines). A camera without markers stores nothing (NoMarkers)."""
    baselines = [take_baseline(cam, frames, clock) for cam in cameras]
    run_id = save_baselines(store, baselines, rig=rig, operator=operator, started=clock(),
                            config_digest=config_digest)
    return run_id, baselines


def save_baselines(store, baselines: list[Baseline], rig: str = "", operator: str = "", started=None,
                   config_digest: str = "") -> int:
    """One run holding the baselines of several cameras; returns its id."""
    with store.begin_run(PROCEDURE, rig=rig, operator=operator, started=started,
                         config_digest=config_digest) as h:
        for b in baselines:
            h.measure(b.camera, "baseline_markers", float(len(b.markers)), "markers", status="OK")
            for m in b.markers:
                h.measure(f"{b.camera}/{m.id}", "baseline_x_px", m.x, "px", status="OK")
                h.measure(f"{b.camera}/{m.id}", "baseline_y_px", m.y, "px", status="OK")
        finished = h.finish(status="OK", finished=started)
    return finished.id


def load_baseline(store, camera: str) -> Baseline:
    """The latest baseline of ``camera``; NoBaseline (one sentence) when there is none."""
    runs = [r for r in store.runs(procedure=PROCEDURE) if r.status == "OK"]
    for run in reversed(runs):
        rows = store.measurements(run_id=run.id)
        mine = [m for m in rows if m.subject.startswith(camera + "/")]
        if not any(m.subject == camera for m in rows):
            continue
        pos: dict[str, dict[str, float]] = {}
        for m in mine:
            pos.setdefault(m.subject.split("/", 1)[1], {})[m.metric] = m.value
        markers = tuple(BaselineMarker(mid, p["baseline_x_px"], p["baseline_y_px"])
                        for mid, p in sorted(pos.items(), key=lambda kv: int(kv[0][1:]) if kv[0][1:].isdigit() else 0)
                        if "baseline_x_px" in p and "baseline_y_px" in p)
        return Baseline(camera, markers, run.started, run.id)
    raise NoBaseline(f"camera {camera} has no drift baseline in the results store: "
                     f"run `vts qa drift --set-baseline` first")
