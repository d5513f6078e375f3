"""A results store with three rooms and a known truth, written through ResultsStore directly
(fast: no cameras, no simulator), for the department-view tests.

- ``room-a``: 20 days of daily QA on cam1 and cam2, all OK; a baseline; a step test on day 5
  (OK); a stereo calibration on day 2 (OK); three sync checks, the latest out of tolerance
  (TOLERANCE, max |dt| 35 ms); a SPECT mapping (OK); two motion analyses, one ACTION (a patient
  who moved: never an open item).
- ``room-b``: 20 days of daily QA; cam1 ACTION on day 6 (LED) closed by OK runs after it;
  cam2 ACTION (drift_y_px) on the last 3 days: one open item, since day 17; a step test on
  day 1 with ACTION (steps_diff_max_mm) never repeated: a second open item; no calibration.
- ``room-c``: one N-camera calibration only: no daily QA yet.
"""

from __future__ import annotations

import datetime as dt

from vts_hw.store import ResultsStore
from vts_hw.tolerance import DEFAULT_TOLERANCES

DAY = 86400.0
T0 = dt.datetime(2026, 10, 1, tzinfo=dt.UTC).timestamp()
N_DAYS = 20
NOW = T0 + N_DAYS * DAY
RIGS = ("room-a", "room-b", "room-c")


def _judge(metric, value):
    return str(DEFAULT_TOLERANCES[metric].state(value)) if metric in DEFAULT_TOLERANCES else "OK"


def _run(store, procedure, rig, t, measures, notes=""):
    """One completed run; measures: (subject, metric, value, unit); its state the worst."""
    with store.begin_run(procedure, rig=rig, started=t, operator="physicist", notes=notes) as h:
        states = []
        for subject, metric, value, unit in measures:
            st = _judge(metric, value)
            states.append(st)
            h.measure(subject, metric, value, unit, status=st, at=t)
        rank = {"OK": 0, "TOLERANCE": 1, "ACTION": 2}
        h.finish(status=max(states or ["OK"], key=rank.get), finished=t + 60)
        return h.run_id


def _daily(store, rig, day, drift):
    """drift: camera -> (x px, y px, led_off_visible)."""
    t = T0 + day * DAY + 7 * 3600
    ms = []
    for cam, (x, y, led) in drift.items():
        ms += [
            (cam, "drift_x_px", x, "px"),
            (cam, "drift_y_px", y, "px"),
            (cam, "drift_x_mm", 1.25 * x, "mm"),
            (cam, "drift_y_mm", 1.25 * y, "mm"),
            (cam, "led_off_visible", led, "markers"),
            (f"{cam}/M1", "marker_dx_px", x, "px"),
        ]
    return _run(store, "daily", rig, t, ms)


def populate_rooms(store: ResultsStore) -> None:
    for rig in ("room-a", "room-b"):
        with store.begin_run("drift-baseline", rig=rig, started=T0 - DAY) as h:
            h.finish(finished=T0 - DAY + 60)
    for day in range(N_DAYS):
        _daily(store, "room-a", day, {"cam1": (0.01 * day, -0.005 * day, 0), "cam2": (0.1, 0.2 + 0.01 * day, 0)})
        cam1_led = 2 if day == 6 else 0
        cam2_y = 2.5 if day >= N_DAYS - 3 else 0.3
        _daily(store, "room-b", day, {"cam1": (0.05, 0.05, cam1_led), "cam2": (0.2, cam2_y, 0)})
    steps_ok = [("x", "steps_diff_max_mm", 0.9, "mm"), ("x", "steps_slope", 1.001, "")]
    _run(store, "sphere-steps", "room-a", T0 + 5 * DAY + 9 * 3600, steps_ok)
    _run(store, "sphere-steps", "room-b", T0 + 1 * DAY + 9 * 3600, [("x", "steps_diff_max_mm", 3.1, "mm")])
    _run(
        store,
        "calibration",
        "room-a",
        T0 + 2 * DAY + 8 * 3600,
        [
            ("left", "calibration_rms_px", 0.21, "px"),
            ("right", "calibration_rms_px", 0.24, "px"),
            ("set", "calibration_rms_px", 0.3, "px"),
        ],
    )
    for i, dt_ms in enumerate((8.0, 12.0, 35.0)):
        _run(
            store,
            "sync",
            "room-a",
            T0 + (4 + 5 * i) * DAY + 11 * 3600,
            [
                ("vts-spect", "sync_max_abs_dt_ms", dt_ms, "ms"),
                ("vts-spect", "sync_events_both", 6, "events"),
                ("vts-spect", "sync_events_one_system", 0, "events"),
            ],
        )
    _run(
        store,
        "spect_mapping",
        "room-a",
        T0 + 3 * DAY + 10 * 3600,
        [("phantom", "mapping_fre_mm", 0.05, "mm"), ("phantom", "mapping_tre_rms_mm", 0.08, "mm")],
    )
    for i, mm in enumerate((1.0, 7.5)):
        _run(
            store,
            "motion",
            "room-a",
            T0 + (8 + i) * DAY + 14 * 3600,
            [
                ("body", "motion_body_max_mm", mm, "mm"),
                ("body", "motion_body_max_deg", 0.3, "deg"),
                ("tracking", "motion_pose_coverage", 0.99, "fraction"),
            ],
        )
    _run(
        store,
        "calibration_cameras",
        "room-c",
        T0 + 12 * DAY,
        [
            ("cam1", "calibration_rms_px", 0.3, "px"),
            ("cam2", "calibration_rms_px", 0.35, "px"),
            ("cam3", "calibration_rms_px", 0.32, "px"),
            ("set", "calibration_rms_px", 0.4, "px"),
            ("set", "calibration_converged", 1, ""),
        ],
    )


def rooms_store(path) -> str:
    """A fresh SQLite store at ``path`` filled by :func:`populate_rooms`; its URL."""
    url = f"sqlite:///{path}"
    with ResultsStore(url) as store:
        populate_rooms(store)
    return url
