"""A results store for the console's History page, filled by the one recorder
(vts_hw.store.recorder) as the procedures fill it: runs relative to now (the reports ignore runs
after now), of several procedures and every run state, one with a PNG plot, a CSV and a file
since deleted.

- rig ``room-h``: 56 daily QA runs, one a day back from yesterday, cam1 drifting (the last 3
  days ACTION on drift_y_px, 4 days before TOLERANCE); a drift baseline 60 days ago;
  a sync check 2 days ago with the plot ``sync.png``, ``sync.csv`` and ``gone.csv`` (deleted);
  a motion analysis 1 day ago, ACTION; a step test aborted; a sync check still running (the
  recorder begun, never finished) and one that ended in error.
- rig ``room-z``: one calibration, 3 days ago (another rig's run).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw.results import Measure, overall_state
from vts_hw.store import ResultsStore
from vts_hw.store.recorder import ResultRecorder, record
from vts_hw.tolerance import DEFAULT_TOLERANCES, State

DAY = 86400.0
RIG = "room-h"
N_DAILY = 56


@dataclass
class Result:
    """An analysed result as a procedure hands it to the recorder (the Analysis protocol)."""

    procedure: str
    measures: list = field(default_factory=list)
    state_given: State | None = None

    @property
    def state(self) -> State:
        return self.state_given or overall_state(self.measures)

    def results(self) -> str:
        return self.procedure

    def results_data(self) -> dict:
        return {"procedure": self.procedure}

    def plot(self, path=None) -> bytes:
        return b""


def judged(subject, metric, value, unit) -> Measure:
    return Measure.judged(subject, metric, value, unit, DEFAULT_TOLERANCES.get(metric))


def png(path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4, 3), dpi=60)
    ax.plot([0, 1, 2], [0, 12, 8], "o-")
    ax.set_title("sync check: |dt| per event")
    fig.savefig(path)
    plt.close(fig)
    return path


def fill(url: str | Path, folder: Path, now: float | None = None) -> dict:
    """Fill the store at ``url``; returns the ids and files the tests look for."""
    now = time.time() if now is None else now
    ids: dict = {"daily": []}
    with ResultsStore(url) as store:
        base = now - 60 * DAY
        ids["baseline"] = record(store, Result("drift-baseline"), rig=RIG, started=base, finished=base + 30).run_id
        for i in range(N_DAILY):
            t = now - (N_DAILY - i) * DAY
            late = N_DAILY - i
            y = 2.6 if late <= 3 else (1.2 if late <= 7 else 0.1)
            ms = [
                judged(cam, m, v, u)
                for cam in ("cam1", "cam2")
                for m, v, u in (
                    ("drift_x_px", 0.05, "px"),
                    ("drift_y_px", y if cam == "cam1" else 0.1, "px"),
                    ("led_off_visible", 0, "markers"),
                )
            ]
            ids["daily"].append(
                record(store, Result("daily", ms), rig=RIG, operator="tech", started=t, finished=t + 40).run_id
            )
        sync_png = png(folder / "sync.png")
        sync_csv = folder / "sync.csv"
        sync_csv.write_text("event,dt_ms\n1,12.0\n")
        gone = folder / "gone.csv"
        gone.write_text("gone\n")
        t = now - 2 * DAY + 3600
        ids["sync"] = record(
            store,
            Result(
                "sync",
                [
                    judged("vts-spect", "sync_max_abs_dt_ms", 12.0, "ms"),
                    Measure("vts-spect", "sync_offset_ms", 3.0, "ms", State.OK),
                ],
            ),
            rig=RIG,
            operator="physicist",
            notes="after the gantry service",
            started=t,
            finished=t + 300,
            artifacts=[sync_png, sync_csv, gone],
        ).run_id
        gone.unlink()
        t = now - DAY + 7200
        ids["motion"] = record(
            store,
            Result("motion", [Measure("body", "motion_body_max_mm", 7.5, "mm", State.ACTION)]),
            rig=RIG,
            operator="tech",
            started=t,
            finished=t + 900,
        ).run_id
        rec = ResultRecorder(store, "sphere-steps", rig=RIG, operator="physicist", started=now - 3 * DAY).begin()
        rec.abort("the phantom slipped")
        ids["aborted"] = rec.run_id
        running = ResultRecorder(store, "sync", rig=RIG, started=now - 3600).begin()
        ids["running"] = running.run_id
        ids["other_rig"] = record(
            store,
            Result("calibration", [Measure("set", "calibration_rms_px", 0.3, "px", State.OK)]),
            rig="room-z",
            started=now - 3 * DAY,
            finished=now - 3 * DAY + 60,
        ).run_id
        with store.begin_run("sync", rig=RIG, started=now - 4 * DAY + 60) as h:
            h.finish(status="error", finished=now - 4 * DAY + 70, notes="the SPECT list-mode file was empty")
            ids["error"] = h.run_id
    ids["files"] = {"png": sync_png, "csv": sync_csv, "gone": gone}
    return ids
