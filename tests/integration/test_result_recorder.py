"""The one recorder (vts_hw.store.recorder): every result stored the same way — the running
row first, windows synced, the store judging where a window gives the state (its id kept),
one transaction, one unsaved format that imports as the run it would have been."""

from __future__ import annotations

import json

import pytest

from test_steps_analysis import labels, positions
from vts_hw.procedures.baseline import BaselineSet
from vts_hw.procedures.steps_analysis import StepAnalysis
from vts_hw.results import Measure, overall_state
from vts_hw.store import ResultsStore
from vts_hw.store.recorder import ResultRecorder, import_unsaved, record
from vts_hw.tolerance import State, Window
from vts_hw.vision.wall_baseline import Baseline, BaselineMarker


class Verdict:
    """A sync-like result: one figure its window judges (TOLERANCE), one its own rule judges."""

    procedure = "sync"

    @property
    def measures(self):
        return [
            Measure.judged("vts-spect", "sync_max_abs_dt_ms", 35.0, "ms", Window(tolerance_high=20, action_high=100)),
            Measure("vts-spect", "sync_events_both", 3.0, "events", State.TOLERANCE),
        ]  # not its window's state

    @property
    def state(self):
        return overall_state(self.measures)

    def results(self):
        return ""

    def results_data(self):
        return {"summary": {"state": str(self.state)}}

    def plot(self, path=None):
        return b""


def _rows(store, run_id):
    return {m.metric: (m.status, m.tolerance_id is not None) for m in store.measurements(run_id=run_id)}


def test_a_sync_check_in_tolerance_keeps_its_window_as_a_step_test_does(tmp_path):
    url = f"sqlite:///{tmp_path / 'r.sqlite'}"
    steps = StepAnalysis(labels(len(positions())), positions() + [0.0, 0.0, 0.8], positions()).analyze()
    with ResultsStore(url) as store:
        sync = record(store, Verdict(), rig="r", started=1000.0)
        step = record(store, steps, rig="r", started=1000.0)
        assert _rows(store, sync.run_id) == {
            "sync_max_abs_dt_ms": (State.TOLERANCE, True),
            "sync_events_both": (State.TOLERANCE, False),
        }
        assert store.run(sync.run_id).status == "TOLERANCE"
        got = store.measurements(run_id=step.run_id)
        assert store.run(step.run_id).status == "TOLERANCE" == str(steps.state)
        assert all(m.tolerance_id is not None for m in got)  # every steps figure has a window
        assert [str(m.status) for m in got] == [str(m.state) for m in steps.measures]


def test_an_exception_while_measuring_aborts_the_running_run(tmp_path):
    with ResultsStore(tmp_path / "r.sqlite") as store:
        with pytest.raises(RuntimeError):
            with ResultRecorder(store, "daily", rig="r", started=5.0) as rec:
                assert store.run(rec.run_id).status == "running"  # the row is there before the work
                raise RuntimeError("camera on fire")
        run = store.run(rec.run_id)
        assert run.status == "aborted" and "camera on fire" in run.notes and store.measurements(run_id=run.id) == []


@pytest.mark.parametrize("what", ["steps", "baseline"])
def test_a_full_disk_keeps_a_step_test_or_a_baseline_and_imports_it_with_its_windows(tmp_path, small_disk, what):
    disk = small_disk(512)
    url = f"sqlite:///{disk.path / 'r.sqlite'}"
    with ResultsStore(url):
        pass
    if what == "steps":
        result = StepAnalysis(labels(len(positions())), positions() + [0.0, 0.0, 0.8], positions()).analyze()
    else:
        result = BaselineSet([Baseline("cam1", (BaselineMarker("M1", 10.5, 20.25),), 7000.0)])
    disk.fill()
    stored = record(url, result, rig="room1", started=7000.0)
    assert not stored.ok and "cannot" in stored.error and stored.unsaved is not None
    doc = json.loads(stored.unsaved.read_text())
    assert doc["procedure"] == result.procedure and doc["state"] == str(result.state) and doc["tolerances"]
    with ResultsStore(tmp_path / "later.sqlite") as store:
        run_id = import_unsaved(store, stored.unsaved)
        rows = store.measurements(run_id=run_id)
        assert [(m.subject, m.metric, m.value, str(m.status)) for m in rows] == [
            (m.subject, m.metric, m.value, str(m.state)) for m in result.measures
        ]
        windowed = [m.tolerance_id is not None for m in rows]
        assert all(windowed) if what == "steps" else not any(windowed)  # baselines have no window
        assert store.run(run_id).started == 7000.0
