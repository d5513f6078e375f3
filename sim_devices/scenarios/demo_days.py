"""The demo: the daily QA of a simulated rig, day after day, on a virtual clock.

A simulated rig of two cameras comes up on 127.0.0.1 (the reference rig, with cam2 drifting
faster than the others so that it passes its tolerance along the way). The baseline is set
on day 0; then the clock jumps a day at a time and the daily QA set runs against the
simulated cameras through the real drivers, into a fresh results store. Each day the drift
the QA measured is compared with the drift the scene injected (the truth). At the end the
drift trend report is written (HTML and PDF).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vts_hw.config import parse_rig
from vts_hw.procedures.baseline import BaselineSet, take_baseline
from vts_hw.procedures.daily import QARun
from vts_hw.report import build_drift_report
from vts_hw.report.build import build_rooms_report
from vts_hw.room import Room
from vts_hw.sim_devices.clock import VirtualClock
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.scenarios.step_chain import run_sim_steps
from vts_hw.store import ResultsStore
from vts_hw.store.baselines import load_baselines
from vts_hw.store.recorder import ResultRecorder, record

DAY = 86400.0
FAST_CAMERA = "cam2"
FAST_DRIFT_PX_PER_60_DAYS = 2.4


@dataclass
class DayRow:
    day: int
    when: float
    state: str
    cameras: dict[str, dict] = field(default_factory=dict)  # name -> dx, dy, truth_dx, truth_dy, state


@dataclass
class DemoResult:
    rows: list[DayRow]
    store_path: Path
    report_html: Path
    report_pdf: Path
    max_error_px: dict[str, tuple[float, float]]
    steps: object = None  # the step test's SimStepsResult
    rooms_html: Path | None = None  # the department page over the store (one room here)


#: the message (``on_step``) that the step test begins, and the one that the reports are written
STEPS_START = "7-sphere step test: stereo calibration, VTS -> SPECT mapping, 22 positions"
REPORTS_START = "writing the QA report (drift trend and step test)"


def injected_drift(scene, cam: str, t0: float, t1: float) -> tuple[float, float]:
    """Mean image displacement of the wall markers between t0 and t1: the truth."""
    a = {m: (u, v) for m, u, v in scene.truth(cam, t0) if m.startswith("W")}
    b = {m: (u, v) for m, u, v in scene.truth(cam, t1) if m.startswith("W")}
    d = np.array([np.subtract(b[k], a[k]) for k in a if k in b])
    return float(d[:, 0].mean()), float(d[:, 1].mean())


def run_demo(
    out: str | Path,
    days: int = 60,
    n_cameras: int = 2,
    frames: int = 5,
    seed: int = 0,
    on_day: Callable[[DayRow], None] | None = None,
    on_step: Callable[[str], None] | None = None,
) -> DemoResult:
    say = on_step or (lambda m: None)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    db = out / "results.sqlite"
    for p in out.glob("results.sqlite*"):
        p.unlink()  # a fresh store each demo: its history is the demo's 60 days
    clock = VirtualClock(time.time() - days * DAY)  # the demo's last day is today
    with (
        SimRig(
            n_cameras=n_cameras, seed=seed, clock=clock, drift_px_per_60_days={FAST_CAMERA: FAST_DRIFT_PX_PER_60_DAYS}
        ) as rig,
        rig.env(),
    ):
        base = rig.config().model_dump(mode="json", exclude_none=True)
        base["store"] = {"url": f"sqlite:///{db.resolve()}"}
        base["rig"] = "sim-demo"
        cfg = parse_rig(base, "demo rig")
        scene = rig.scene
        with ResultsStore(cfg.store.url) as store:
            # day 0: the baseline
            t_base = clock.now()
            baselines = []
            with Room(cfg, clock=clock.now) as room:
                for c in cfg.cameras:
                    baselines.append(take_baseline(room.camera(c.name), frames, clock.now))
            record(
                store,
                BaselineSet(baselines),
                rig=cfg.rig,
                operator="demo",
                tolerances=cfg.tolerances,
                started=t_base,
                finished=t_base,
                clock=clock.now,
            )
            stored_baselines = load_baselines(store, [c.name for c in cfg.cameras], cfg.rig)
            say(f"day 0: baseline set ({', '.join(f'{b.camera}: {len(b.markers)} markers' for b in baselines)})")
            rows: list[DayRow] = []
            for day in range(1, days + 1):
                clock.advance(t_base + day * DAY - clock.now())  # day `day` after the baseline
                rig.ntp_sync(clock.now() - 1800.0)  # the cameras' NTP synced their clocks half an hour ago
                day_room = Room(cfg, clock=clock.now)  # the day's cameras, closed with it
                qa = QARun(
                    cfg,
                    baselines=stored_baselines,
                    n_frames=frames,
                    clock=clock.now,
                    open_camera=lambda c, room=day_room: room.camera(c.name),
                    artifacts_dir=out / "artifacts",
                    plots=(day == days),
                )
                now = clock.now()
                with (
                    day_room,
                    ResultRecorder(
                        store,
                        qa.procedure,
                        rig=cfg.rig,
                        operator="demo",
                        tolerances=cfg.tolerances,
                        started=now,
                        clock=clock.now,
                    ) as rec,
                ):
                    res = qa.run(started=now, run_id=rec.run_id)
                    rec.finish(res, artifacts=res.artifacts, finished=res.finished)
                row = DayRow(day, res.started, str(res.state))
                for found in res.cameras:
                    d = found.drift
                    if d is None or not d.analyzed:
                        row.cameras[found.camera] = {"state": str(found.state)}
                        continue
                    tx, ty = injected_drift(scene, found.camera, t_base, res.started)
                    row.cameras[found.camera] = {
                        "dx": d.drift_px[0],
                        "dy": d.drift_px[1],
                        "truth_dx": tx,
                        "truth_dy": ty,
                        "state": str(found.state),
                    }
                rows.append(row)
                if on_day:
                    on_day(row)
            say(STEPS_START)
            steps = run_sim_steps(
                out / "steps", seed, store=store, rig=rig, operator="demo", tolerances=cfg.tolerances, rig_name=cfg.rig
            )
            sc = steps.scores
            say(steps.analysis.results())
            say(
                f"against the truth: VTS 3D RMS {sc['position_rms_mm']:.3f} mm (goal <= 0.15), 6-DOF move "
                f"rotation {sc['move_rotation_error_deg']:.4f} deg (goal <= 0.05), translation "
                f"{sc['move_translation_error_mm']:.3f} mm (goal <= 0.1)"
            )
            now = clock.now()
            say(REPORTS_START)
            html = out / "drift-report.html"
            pdf = out / "drift-report.pdf"
            build_drift_report(store, html, now=now, rig=cfg.rig)
            build_drift_report(store, pdf, now=now, rig=cfg.rig)
            rooms = out / "rooms.html"
            build_rooms_report(store, rooms, now=now)
    err: dict[str, tuple[float, float]] = {}
    for r in rows:
        for cam, v in r.cameras.items():
            if "dx" in v:
                ex, ey = abs(v["dx"] - v["truth_dx"]), abs(v["dy"] - v["truth_dy"])
                px, py = err.get(cam, (0.0, 0.0))
                err[cam] = (max(px, ex), max(py, ey))
    return DemoResult(rows, db, html, pdf, err, steps, rooms)
