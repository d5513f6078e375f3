"""The daily QA set, and the drift QA alone, as one readable script.

For each camera of the rig:

1. reachable — the camera answers (device info), and how long it has run: one started less
   than its ``warmup_min`` ago may still drift as it warms (said, and stored as ``warming_up``);
2. parameters — resolution, compression and frame rate (and any ``locked_params`` of the
   config, e.g. exposure) are still what the config locks them to;
3. clock — camera clock minus host clock is within tolerance;
4. LED and drift — the wall-marker drift procedure (``drift.py``) against the baseline.

The run's state is the worst of its measurements. The caller gives the cameras (``open_camera``: the room's ``room.camera``)
and the drift baselines, and records the result (vts_hw.store.recorder: the "running" row
before the cameras are measured, then one transaction); this script never holds a store.
``plan()`` lists the steps without touching the rig (``--dry-run``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw import catalog
from vts_hw.camera import CameraError, Parameters, Refused, RunningTime
from vts_hw.catalog import qa_set_name
from vts_hw.errors import UsageError, VtsError
from vts_hw.files import filled_folder, write_atomic
from vts_hw.procedures.daily_plot import daily_png
from vts_hw.procedures.drift import DriftAnalysis
from vts_hw.procedures.marker_room import room_geometry
from vts_hw.results import Measure
from vts_hw.tolerance import State, Window, worst
from vts_hw.vision.wall_baseline import NoBaseline

EXIT_CODES = {State.OK: 0, State.TOLERANCE: 10, State.ACTION: 20}
STEPS = ("reachable", "params", "clock", "drift")


@dataclass(frozen=True)
class QAStep:
    """Where a run is (``QARun(on_step=...)``, a page showing its progress): camera ``camera``
    (number ``index`` from 1 of ``cameras``), its ``step`` (``connect``, then those of STEPS the
    run takes, then ``done`` with the camera's ``state``); in the drift step the frames
    ``taken`` of ``needed`` and the ``frame`` just taken (first None, taken 0, before the LED
    is switched)."""

    camera: str
    index: int
    cameras: int
    step: str
    taken: int = 0
    needed: int = 0
    frame: object = None
    state: str = ""


@dataclass
class CameraResult:
    camera: str
    measures: list[Measure] = field(default_factory=list)
    problems: list[str] = field(default_factory=list)
    drift: DriftAnalysis | None = None
    drift_at: tuple = ()  # where the drift's measures and problems start (they are made again by place)

    @property
    def state(self) -> State:
        return worst(m[4] for m in self.measures if "/" not in m[0])


@dataclass
class QAResult:
    procedure: str
    run_id: int | None
    started: float
    cameras: list[CameraResult]
    artifacts: list[str] = field(default_factory=list)
    finished: float | None = None
    store_error: str | None = None  # the store could not take the run: its figures are here only
    windows: dict = field(default_factory=dict)  # the tolerance windows the run was judged by
    room_why: str = ""  # why the still markers not in a baseline were not placed in the room ("" when they were)

    @property
    def state(self) -> State:
        return worst(c.state for c in self.cameras)

    @property
    def measures(self) -> list[Measure]:
        """Every camera's measures, in camera order (the one QA result shape)."""
        return [m for c in self.cameras for m in c.measures]

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self.state]

    def results_data(self) -> dict:
        return {
            "procedure": self.procedure,
            "run_id": self.run_id,
            "started": self.started,
            "state": str(self.state),
            "cameras": [
                {
                    "camera": c.camera,
                    "state": str(c.state),
                    "problems": c.problems,
                    "measurements": [
                        {"subject": s, "metric": m, "value": v, "unit": u, "state": str(st)}
                        for s, m, v, u, st in c.measures
                        if "/" not in s
                    ],
                    "drift": c.drift.results_data() if c.drift is not None and c.drift.analyzed else None,
                }
                for c in self.cameras
            ],
            "artifacts": self.artifacts,
            **({"store_error": self.store_error} if self.store_error else {}),
            **({"markers_not_placed": self.room_why} if self.room_why else {}),
        }

    def plot(self, path=None) -> bytes:
        """PNG: per camera, the drift inside its windows and the other checks' states."""
        return daily_png(self, self.windows, path)

    def results(self) -> str:
        lines = [f"{self.procedure} QA: {self.state}" + (f" (run {self.run_id})" if self.run_id else "")]
        for c in self.cameras:
            lines.append(f"  {c.camera}: {c.state}")
            for s, m, v, u, st in c.measures:
                if "/" in s:
                    continue
                val = "n/a" if v is None else f"{v:+.3f}" if isinstance(v, float) and not v.is_integer() else f"{v:g}"
                flag = "" if st == State.OK else f"   <- {st}"
                lines.append(f"      {m:<17} {val:>9} {u}{flag}")
            for p in c.problems:
                lines.append(f"      ! {p}")
            d = c.drift
            for x, y, r in d.others if d is not None and d.analyzed else []:
                lines.append(f"      not a wall marker at ({x:.0f}, {y:.0f}) px: {r.role}, {r.reason}")
        if self.room_why:
            lines.append(f"  still markers not in a baseline were not placed: {self.room_why}")
        return "\n".join(lines)


class QARun:
    """One QA run over the cameras of a rig. ``steps`` chooses the checks (default: all);
    ``baselines`` (camera name -> Baseline) are the drift step's, read by the caller."""

    def __init__(
        self,
        rig,
        *,
        baselines=None,
        steps=STEPS,
        cameras: list[str] | None = None,
        n_frames: int = 5,
        clock: Callable[[], float] = time.time,
        artifacts_dir: str | Path | None = None,
        plots: bool = False,
        open_camera: Callable | None = None,
        progress: Callable[[str], None] | None = None,
        on_step: Callable[[QAStep], None] | None = None,
    ):
        self.rig = rig
        self.baselines = dict(baselines or {})
        self.steps = tuple(steps)
        self.procedure = qa_set_name(self.steps, STEPS)
        self.camera_names = cameras or [c.name for c in rig.cameras]
        self.n_frames = n_frames
        self.clock = clock
        self.artifacts_dir = Path(artifacts_dir) if artifacts_dir else None
        self.plots = plots
        # the cameras are given, not built here: open_camera(cfg) -> Camera (drivers.registry's)
        self.open_camera = open_camera
        self.progress = progress or (lambda msg: None)
        #: hears of each step and drift frame as it happens (QAStep); must return at once
        self.on_step = on_step or (lambda step: None)
        self.tolerances: dict[str, Window] = catalog.windows(rig.tolerances)

    @property
    def needs_baselines(self) -> bool:
        return "drift" in self.steps

    def plan(self, where: str = "the results store") -> list[str]:
        """The steps this run would take, without touching the rig."""
        out = []
        for name in self.camera_names:
            cfg = self.rig.camera(name)
            if "reachable" in self.steps:
                out.append(
                    f"{name}: ask {cfg.base_url} for its device info and uptime "
                    f"(warm-up {getattr(cfg, 'warmup_min', 30.0):g} min)"
                )
            if "params" in self.steps:
                locked = ", ".join(f"{k}={v}" for k, v in self.locked(cfg).items())
                out.append(f"{name}: check the locked parameters ({locked})")
            if "clock" in self.steps:
                out.append(f"{name}: measure its clock against this host")
            if "drift" in self.steps:
                out.append(
                    f"{name}: LED on, {self.n_frames} snapshots; LED off, 1 snapshot; LED on; "
                    f"detect the wall markers and compare with the baseline"
                )
        out.append(f"store the run ({self.procedure}) in {where}")
        return out

    @staticmethod
    def locked(cfg) -> dict[str, str]:
        values = {
            "Image.I0.Appearance.Resolution": cfg.resolution_str,
            "Image.I0.Appearance.Compression": str(cfg.compression),
            "Image.I0.Stream.FPS": f"{cfg.fps:g}",
        }
        values.update(getattr(cfg, "locked_params", {}) or {})
        return values

    def preflight(self) -> None:
        """Setup mistakes end here, before the rig is touched: an unknown camera name or an
        unset password variable (ConfigError, exit 2)."""
        for name in self.camera_names:
            self.rig.camera(name).password()

    def run(self, started: float | None = None, run_id: int | None = None) -> QAResult:
        """Measure every camera; the result for the caller to record. ``run_id``: the run the
        caller began (its saved frames go to ``run<id>``), None when the store cannot take it.
        A camera without a baseline (drift step) is NoBaseline (exit 5), before the rig is touched."""
        self.preflight()
        missing = [n for n in self.camera_names if self.needs_baselines and n not in self.baselines]
        if missing:
            raise NoBaseline(f"camera {missing[0]} has no drift baseline: run `vts qa drift --set-baseline` first")
        now = self.clock() if started is None else started
        results: list[CameraResult] = []
        for i, name in enumerate(self.camera_names, 1):
            self.progress(f"{name}: checking")
            res = self._camera(name, self.baselines.get(name), i)
            results.append(res)
            self.on_step(QAStep(name, i, len(self.camera_names), "done", state=str(res.state)))
        before = [str(r.state) for r in results]
        room_why = place_others(results, self.rig) if "drift" in self.steps else ""
        for i, (res, was) in enumerate(zip(results, before), 1):
            if str(res.state) != was:  # a stray found on the table: the camera's state, said again
                self.on_step(QAStep(res.camera, i, len(self.camera_names), "done", state=str(res.state)))
        result = QAResult(
            self.procedure, None, now, results, finished=self.clock(), windows=self.tolerances, room_why=room_why
        )
        result.artifacts = self._save_all_artifacts(run_id, results, result)
        return result

    # -- one camera ------------------------------------------------------------------------
    def _camera(self, name: str, baseline=None, index: int = 1) -> CameraResult:
        cfg = self.rig.camera(name)
        out = CameraResult(name)
        tol = self.tolerances
        n_cams = len(self.camera_names)

        def step(what, **more):
            self.on_step(QAStep(name, index, n_cams, what, **more))

        def add(metric, value, unit, window=None):
            w = tol.get(window or metric)
            st = State.ACTION if value is None else (w.state(value) if w else State.OK)
            out.measures.append(Measure(name, metric, value, unit, st))

        if self.open_camera is None:
            raise UsageError("QARun was given no cameras (open_camera=...)")
        step("connect")
        try:
            cam = self.open_camera(cfg)
        except CameraError as exc:  # a device that cannot be reached (setup mistakes failed preflight)
            out.problems.append(str(exc))
            add("camera_reachable", 0.0, "")
            return out
        with cam:
            try:
                if "reachable" in self.steps:
                    step("reachable")
                    cam.device_info()
                    add("camera_reachable", 1.0, "")
                    self._warmup(cam, cfg, out, add)
                if "params" in self.steps:
                    step("params")
                    if not isinstance(cam, Parameters):  # e.g. a replayed recording: nothing to lock
                        out.problems.append(
                            f"parameters not checked: camera {cfg.name} (kind {cfg.kind}) has no parameters"
                        )
                    else:
                        changed = self._params(cam, cfg, out)
                        add("params_changed", float(changed), "params")
                if "clock" in self.steps:
                    step("clock")
                    off = cam.clock_offset()
                    add("clock_offset_s", off.offset_s, "s")
                if "drift" in self.steps:
                    mm = getattr(cfg, "wall_mm_per_px", 1.25)

                    def frame_taken(frame, led_on, taken, needed):
                        step("drift", taken=taken, needed=needed, frame=frame)

                    d = DriftAnalysis.acquire(cam, baseline, self.n_frames, on_frame=frame_taken, mm_per_px=mm).analyze(
                        tol
                    )
                    d.look_longer(cam, on_frame=frame_taken)  # strays: a breath's frames more
                    out.drift = d
                    out.drift_at = (len(out.measures), len(out.problems))
                    _drift_into(out, d)
            except CameraError as exc:
                out.problems.append(str(exc))
                add("camera_reachable", 0.0, "")
        return out

    @staticmethod
    def _warmup(cam, cfg, out: CameraResult, add) -> None:
        """The camera's uptime against its warm-up time (``warmup_min``): a camera started less
        than that ago may still be drifting as it warms. Stored as ``uptime_min`` and
        ``warming_up`` (1: its drift may not have settled), neither of which changes the state."""
        warm = float(getattr(cfg, "warmup_min", 30.0))
        if not isinstance(cam, RunningTime):
            out.problems.append(
                "uptime not known (this kind of camera does not tell it): whether its drift has settled is not known"
            )
            return
        try:
            up = cam.uptime()
        except CameraError as exc:
            out.problems.append(f"uptime not known ({exc}): whether its drift has settled is not known")
            return
        minutes = up.seconds / 60.0
        add("uptime_min", round(minutes, 1), "min")
        warming = minutes < warm  # a coarse uptime (whole minutes) counts its lower end: may still be warming
        add("warming_up", 1.0 if warming else 0.0, "")
        if warming:
            out.problems.append(
                f"started {minutes:.0f} min ago, less than its warm-up time ({warm:g} min): "
                f"its drift may not have settled (about {warm - minutes:.0f} min to go)"
            )

    def _params(self, cam, cfg, out: CameraResult) -> int:
        changed = 0
        groups: dict[str, dict[str, str]] = {}
        for key, want in self.locked(cfg).items():
            group = key.rsplit(".", 2)[0] if key.count(".") >= 2 else key.split(".")[0]
            if group not in groups:
                try:
                    groups[group] = cam.get_params(group)
                except Refused:  # the firmware has no such group: every key in it counts as changed
                    groups[group] = {}
            have = groups[group].get(key)
            if have is None or have.strip() != str(want):
                changed += 1
                out.problems.append(f"parameter {key} is {have!r}, locked at {want!r}")
        return changed

    def _save_all_artifacts(self, run_id: int | None, results: list[CameraResult], result=None) -> list[str]:
        """Frames (and plots: per camera, and the run's overview) beside the store; a file that
        cannot be written is a problem of its camera, never a lost run."""
        out = []
        for res in results:
            try:
                out += [str(p) for p in self._save_artifacts(run_id, res)]
            except (VtsError, OSError) as exc:
                res.problems.append(f"frames not saved: {exc}")
        if self.plots and self.artifacts_dir is not None and result is not None and results:
            d = self.artifacts_dir / (f"run{run_id:06d}" if run_id is not None else f"unsaved-{int(self.clock())}")
            try:
                with filled_folder(d, "artifacts folder"):
                    result.plot(d / f"{self.procedure.replace(':', '-')}.png")
                out.append(str(d / f"{self.procedure.replace(':', '-')}.png"))
            except (VtsError, OSError) as exc:
                results[0].problems.append(f"overview plot not saved: {exc}")
        return out

    def _save_artifacts(self, run_id: int | None, res: CameraResult) -> list[Path]:
        if self.artifacts_dir is None or res.drift is None:
            return []
        d = self.artifacts_dir / (
            f"run{run_id:06d}" if run_id is not None else f"unsaved-{int(self.clock())}-{res.camera}"
        )
        with filled_folder(d, "artifacts folder"):  # (none left empty by a full disk)
            paths = [write_atomic(d / f"{res.camera}-led-on.jpg", res.drift.frames_on[0].jpeg)]
            if res.drift.frame_off is not None:
                paths.append(write_atomic(d / f"{res.camera}-led-off.jpg", res.drift.frame_off.jpeg))
            if self.plots:
                png = d / f"{res.camera}-drift.png"
                res.drift.plot(png)
                paths.append(png)
        return paths


def _drift_into(out: CameraResult, d: DriftAnalysis) -> None:
    """The drift's measures and problems into the camera's result, in place of any it had (the
    drift is the camera's last step: everything from ``drift_at`` on is the drift's)."""
    m0, p0 = out.drift_at
    new = [f"marker {m} not found" for m in d.missing]
    new += [f"stray bright blob at ({x:.0f}, {y:.0f}) px" for x, y in d.strays]
    if d.led_off_visible:
        new.append(f"{d.led_off_visible} marker(s) still bright with the LED off")
    out.measures[m0:] = list(d.measures)
    out.problems[p0:] = new


def place_others(results: list[CameraResult], rig) -> str:
    """Rule 2 of vts_hw/vision/marker_roles.py across the cameras measured: each camera's still
    markers that are not its baseline's placed in the room (the rig's calibration and mapping);
    one on the table (the phantom, a patient holding still) is no stray. Returns why they were not
    placed ("" when they were)."""
    drifts = {r.camera: (r, r.drift) for r in results if r.drift is not None and r.drift.analyzed}
    if not any(d.candidates for _, d in drifts.values()):
        return ""
    room, why = room_geometry(rig)
    if room is None:
        return why
    placed = room.place({n: d.candidates for n, (_, d) in drifts.items()})
    for n, (r, d) in drifts.items():
        d.place(placed.get(n, []))
        _drift_into(r, d)
    return ""
