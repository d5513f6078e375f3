"""Drift baselines read back from the results store: runs of the ``drift-baseline`` procedure
(vts_hw.catalog.BASELINE) stored by the recorder (procedures/baseline.py makes them).

Each baseline run holds, per camera, the number of markers (subject ``cam1``, metric
``baseline_markers``) and each marker's position (subject ``cam1/M1``, metrics
``baseline_x_px`` and ``baseline_y_px``). The latest finished baseline run that has a camera's
markers is that camera's baseline; setting a new one never changes the old runs.
"""

from __future__ import annotations

from vts_hw.catalog import BASELINE
from vts_hw.vision.wall_baseline import Baseline, BaselineMarker, NoBaseline


def load_baseline(store, camera: str, rig: str | None = None) -> Baseline:
    """The latest baseline of ``camera`` (of rig ``rig`` only, when given: another room's
    ``cam1`` is another camera; a baseline stored without a room's name, by an older version or
    through the API, is taken when the room has none of its own); NoBaseline (one sentence,
    exit 5) when there is none."""
    runs = [r for r in store.runs(procedure=BASELINE.stored_as) if r.status == "OK"]
    passes = [runs] if rig is None else [[r for r in runs if r.rig == rig], [r for r in runs if r.rig == ""]]
    for candidates in passes:
        found = _latest(store, camera, candidates)
        if found is not None:
            return found
    raise NoBaseline(
        f"camera {camera} has no drift baseline in the results store: run `vts qa drift --set-baseline` first"
    )


def _latest(store, camera: str, runs) -> Baseline | None:
    for run in reversed(runs):
        rows = store.measurements(run_id=run.id)
        mine = [m for m in rows if m.subject.startswith(camera + "/")]
        if not any(m.subject == camera for m in rows):
            continue
        pos: dict[str, dict[str, float]] = {}
        for m in mine:
            pos.setdefault(m.subject.split("/", 1)[1], {})[m.metric] = m.value
        markers = tuple(
            BaselineMarker(mid, p["baseline_x_px"], p["baseline_y_px"])
            for mid, p in sorted(pos.items(), key=lambda kv: int(kv[0][1:]) if kv[0][1:].isdigit() else 0)
            if "baseline_x_px" in p and "baseline_y_px" in p
        )
        return Baseline(camera, markers, run.started, run.id)
    return None


def load_baselines(store, cameras, rig: str | None = None) -> dict[str, Baseline]:
    """The latest baseline of each of ``cameras`` (of rig ``rig`` only, when given); NoBaseline
    for the first that has none."""
    return {name: load_baseline(store, name, rig) for name in cameras}
