"""Every QA result is stored one way (vts_hw.store.recorder): a run with a
measurement per measure — and on a full disk, or a database server that is down, a file that
`vts qa import` stores later. On both back ends (conftest.store_url)."""

from __future__ import annotations

import json

from vts_hw.results import Analysis, Measure, overall_state
from vts_hw.store import ResultsStore
from vts_hw.store.recorder import import_unsaved
from vts_hw.store.recorder import record as store_result
from vts_hw.tolerance import State, Window


class TwoFigures:
    """A QA result of the common shape with two figures, one in tolerance."""

    procedure = "example"

    @property
    def measures(self):
        return [
            Measure.judged("cam1", "drift_x_px", 0.2, "px", Window.symmetric(1.0, 2.0, "px")),
            Measure.judged("cam1", "drift_y_px", 1.4, "px", Window.symmetric(1.0, 2.0, "px")),
        ]

    @property
    def state(self):
        return overall_state(self.measures)

    def results(self):
        return "two figures"

    def results_data(self):
        return {"figures": [m.as_dict() for m in self.measures]}

    def plot(self, path=None):
        return b""


def test_a_result_becomes_a_run_with_its_measures(store_url):
    result = TwoFigures()
    assert isinstance(result, Analysis) and result.state is State.TOLERANCE
    url = store_url
    stored = store_result(url, result, rig="room1", started=1000.0)
    assert stored.ok and stored.unsaved is None
    with ResultsStore(url) as store:
        run = store.run(stored.run_id)
        assert (run.procedure, run.rig, run.status, run.started) == ("example", "room1", "TOLERANCE", 1000.0)
        got = sorted((m.metric, m.value, m.status.value) for m in store.measurements(run_id=run.id))
    assert got == [("drift_x_px", 0.2, "OK"), ("drift_y_px", 1.4, "TOLERANCE")]


def test_a_full_disk_keeps_every_figure_for_later(tmp_path, small_disk):
    disk = small_disk(512)
    url = f"sqlite:///{disk.path / 'r.sqlite'}"
    with ResultsStore(url):
        pass
    disk.fill()
    stored = store_result(url, TwoFigures(), rig="room1", started=2000.0)
    assert not stored.ok and stored.error and stored.unsaved is not None
    assert not str(stored.unsaved).startswith(str(disk.path))  # the full disk could not take it
    doc = json.loads(stored.unsaved.read_text())
    assert [m["value"] for m in doc["measurements"]] == [0.2, 1.4] and doc["state"] == "TOLERANCE"
    other = f"sqlite:///{tmp_path / 'later.sqlite'}"
    with ResultsStore(other) as store:
        run_id = import_unsaved(store, stored.unsaved)
        run = store.run(run_id)
        assert run.status == "TOLERANCE" and run.started == 2000.0 and len(store.measurements(run_id=run_id)) == 2


def test_a_database_server_that_is_down_keeps_every_figure_for_later(pg_server, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    db = pg_server.new_database(owner="vts")
    down = f"postgresql://vts@127.0.0.1:{_closed_port()}/{db}"
    stored = store_result(down, TwoFigures(), rig="room1", started=3000.0)
    assert not stored.ok and "cannot read the results store" in stored.error and stored.unsaved is not None
    doc = json.loads(stored.unsaved.read_text())
    assert [m["value"] for m in doc["measurements"]] == [0.2, 1.4] and doc["rig"] == "room1"
    # the server back (here: the right port): `vts qa import` puts the run in, once
    with ResultsStore(pg_server.url(db)) as store:
        run_id = import_unsaved(store, stored.unsaved)
        assert store.run(run_id).started == 3000.0 and len(store.measurements(run_id=run_id)) == 2


def _closed_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # nothing listens there once the socket is closed


def test_an_unsaved_run_naming_a_folder_as_its_artifact_imports_without_it(tmp_path):
    # found by bench/fuzz.py (unsaved): a folder among the artifacts was an IsADirectoryError
    plot = tmp_path / "plot.png"
    plot.write_bytes(b"\x89PNG")
    p = tmp_path / "run.json"
    p.write_text(
        json.dumps(
            {
                "format": "vts-unsaved-run/1",
                "procedure": "drift",
                "started": 2000.0,
                "state": "OK",
                "measurements": [],
                "artifacts": [str(tmp_path), str(plot)],
            }
        )
    )
    with ResultsStore(f"sqlite:///{tmp_path / 'r.sqlite'}") as store:
        run_id = import_unsaved(store, p)
        assert [a.path for a in store.artifacts(run_id=run_id)] == [str(plot)]
    assert (tmp_path / "run.json.imported").exists()


def test_a_store_that_cannot_be_created_on_a_full_disk_leaves_no_empty_file(small_disk):
    """A new SQLite store on a full disk: one StoreError naming it, and no 0-byte `results.sqlite`
    (or journal) left to look like a store; an existing file is never removed."""
    import pytest

    from vts_hw.store.errors import StoreError

    disk = small_disk(64)
    disk.fill()
    with pytest.raises(StoreError) as e:
        ResultsStore(f"sqlite:///{disk.path / 'results.sqlite'}")
    assert "results.sqlite" in str(e.value) and "full" in str(e.value)
    assert disk.files() == {}
    (disk.path / "other.sqlite").write_bytes(b"")  # an empty file someone made: kept
    with pytest.raises(StoreError):
        ResultsStore(f"sqlite:///{disk.path / 'other.sqlite'}")
    assert disk.files() == {"other.sqlite": 0}
