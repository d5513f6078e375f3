"""The daily QA and the drift baselines as `vts qa` runs them, for tests that call the API:
the procedure measures, the one recorder stores (vts_hw.store.qa_record.record_qa, as `vts qa` and the console)."""

from __future__ import annotations

import time

from vts_hw.store.recorder import record


def save_baselines(store, baselines, rig: str = "", started: float | None = None) -> int:
    """Store ``baselines`` (procedures.drift.Baseline) as one baseline run; its id."""
    from vts_hw.procedures.baseline import BaselineSet

    started = time.time() if started is None else started
    stored = record(store, BaselineSet(list(baselines)), rig=rig, started=started, finished=started)
    assert stored.ok, stored.error
    return stored.run_id


def baselines_now(rig, store, frames: int = 2) -> int:
    """Each camera of ``rig`` (a RigConfig) seen now, LED on, ``frames`` snapshots, stored as one
    baseline run of the rig (as `vts qa drift --set-baseline` takes them); its id."""
    from vts_hw.drivers.registry import open_camera
    from vts_hw.procedures.drift import acquire_led_frames
    from vts_hw.vision.wall_markers import baseline_from_frames

    bs = []
    for c in rig.cameras:
        with open_camera(c) as cam:
            on, _ = acquire_led_frames(cam, frames)
        bs.append(baseline_from_frames(c.name, [s.jpeg for s in on], time.time()))
    return save_baselines(store, bs, rig=rig.rig)


def run_qa(rig, store, **kw):
    """A QARun(rig, **kw) recorded in ``store``; the QAResult (run_id, store_error set)."""
    from vts_hw.procedures.daily import QARun
    from vts_hw.store.qa_record import record_qa

    return record_qa(store, QARun(rig, **kw), rig)[0]
