"""Whose drift baseline the daily QA compares with, in a store shared by rooms: the room's own
(the latest), never another room's ``cam1``; a baseline stored without a room's name (an older
version, the API) only when the room has none of its own."""

from __future__ import annotations

import pytest

from qa_runs import save_baselines
from vts_hw.store import ResultsStore
from vts_hw.store.baselines import load_baseline, load_baselines
from vts_hw.vision.wall_baseline import Baseline, BaselineMarker, NoBaseline


def one(x: float, taken: float) -> Baseline:
    return Baseline("cam1", (BaselineMarker("M1", x, 100.0),), taken)


def test_the_rooms_own_then_an_unnamed_one_never_another_rooms(tmp_path):
    with ResultsStore(tmp_path / "shared.sqlite") as store:
        save_baselines(store, [one(10.0, 1000.0)], rig="", started=1000.0)  # unnamed, oldest
        assert load_baseline(store, "cam1", "room3").markers[0].x == 10.0  # the room has none: taken
        save_baselines(store, [one(30.0, 3000.0)], rig="room4", started=3000.0)  # another room's cam1
        assert load_baseline(store, "cam1", "room3").markers[0].x == 10.0
        save_baselines(store, [one(20.0, 2000.0)], rig="room3", started=2000.0)  # the room's own
        assert load_baseline(store, "cam1", "room3").markers[0].x == 20.0
        save_baselines(store, [one(40.0, 4000.0)], rig="", started=4000.0)  # a later unnamed one
        assert load_baselines(store, ["cam1"], "room3")["cam1"].markers[0].x == 20.0
        assert load_baseline(store, "cam1", "room4").markers[0].x == 30.0
        assert load_baseline(store, "cam1").markers[0].x == 40.0  # no room asked: the latest
        with pytest.raises(NoBaseline, match="camera cam2 has no drift baseline"):
            load_baseline(store, "cam2", "room3")
