"""The drift trend report's numbers, collected from the results store.

``collect(store)`` reads the runs of the wall-marker drift QA (procedures ``drift`` and
``daily``) and the baselines (``drift-baseline``), and computes per camera and axis the control
limits, the linear trend since the latest baseline and the date the trend reaches the action
level. :func:`vts_hw.report.build.build_drift_report` writes it as a self-contained HTML file or
a PDF (renderers by suffix: :mod:`vts_hw.report.renderers`).

Reading rules:
- a run counts when its status is OK, TOLERANCE or ACTION; the others (aborted, error,
  unfinished) are listed, their measurements are not plotted;
- a baseline run resets the drift of the cameras it has measurements for, or of every camera
  when it has none;
- the bands are the ``drift_x_px`` / ``drift_y_px`` windows in effect at each moment (the
  store's; the built-in default where the store has none);
- control limits and trend use every run since the camera's latest baseline, even one before
  ``since``; the plots and tables show the period ``[since, now]``.
"""

from __future__ import annotations

import math
import time
from collections import defaultdict

import numpy as np

from vts_hw import __version__, catalog
from vts_hw.report.model import AXES, AxisSummary, BandSegment, CameraDrift, DriftReport, RunInfo, RunPoint
from vts_hw.report.times import parse_since  # noqa: F401  (re-exported for the CLI)
from vts_hw.report.trend import CONTROL_METHOD, control_limits, fit_trend, forecast
from vts_hw.tolerance import Window, worst

DRIFT_PROCEDURES = catalog.family(catalog.DAILY.key)  # daily and drift QA: one check
BASELINE_PROCEDURE = catalog.BASELINE.name
COMPLETED = {"OK", "TOLERANCE", "ACTION"}
BAND_METRICS = {"x": "drift_x_px", "y": "drift_y_px"}
_BISECT_RESOLUTION_S = 60.0


def _completed(run) -> bool:
    return str(run.status or "").upper() in COMPLETED


def _is_camera(subject: str) -> bool:
    return bool(subject) and "/" not in subject


# --- tolerance windows ---------------------------------------------------------------------


class _Windows:
    """The window of a metric in effect at a time, from the store (cached per time)."""

    def __init__(self, store, metric: str, default: Window):
        self.store, self.metric, self.default = store, metric, default
        self._cache: dict[float, tuple] = {}

    def at(self, t: float):
        if t not in self._cache:
            got = self.store.tolerance(self.metric, at=t)
            self._cache[t] = got if got is not None else (None, self.default)
        return self._cache[t]

    def segments(self, times, start: float, end: float) -> list[BandSegment]:
        """The windows in effect over ``[start, end]`` as a step function.

        The store is asked at ``start``, ``end`` and each run time; where two neighbouring
        answers differ the change is found by bisection to within a minute.
        """
        ts = sorted({start, end, *[t for t in times if start <= t <= end]})
        edges = [(ts[0], self.at(ts[0]))]
        for a, b in zip(ts, ts[1:]):
            if self.at(a)[0] == self.at(b)[0]:
                continue
            lo, hi = a, b
            while hi - lo > _BISECT_RESOLUTION_S:
                mid = (lo + hi) / 2
                if self.at(mid)[0] == self.at(a)[0]:
                    lo = mid
                else:
                    hi = mid
            edges.append((hi, self.at(b)))
        out = []
        for i, (t0, (wid, win)) in enumerate(edges):
            t1 = edges[i + 1][0] if i + 1 < len(edges) else end
            out.append(BandSegment(t0, t1, wid, win))
        return out

    def state(self, value: float | None, t: float) -> str:
        return str(self.at(t)[1].state(value))


# --- reading the store ---------------------------------------------------------------------


def _baseline_cameras(store, baseline_runs) -> dict[int, set[str] | None]:
    """Baseline run id -> the cameras it reset (None: all of them)."""
    ids = {r.id for r in baseline_runs}
    cams: dict[int, set[str]] = defaultdict(set)
    if ids:
        for m in store.measurements(procedure=BASELINE_PROCEDURE):
            if m.run_id in ids and m.subject:
                cams[m.run_id].add(m.subject.split("/")[0])
    return {i: (cams[i] or None) for i in ids}


def _latest_before(times: list[float], t: float) -> float | None:
    earlier = [b for b in times if b <= t]
    return max(earlier) if earlier else None


def _mm_per_px(points: list[RunPoint], axis: str) -> float | None:
    """Least-squares scale through the origin of the stored mm against px values."""
    px = np.array([p.value(f"drift_{axis}_px") for p in points])
    mm = np.array([p.value(f"drift_{axis}_mm") for p in points])
    ok = np.isfinite(px) & np.isfinite(mm)
    den = float(np.sum(px[ok] ** 2))
    return float(np.sum(px[ok] * mm[ok]) / den) if den > 1e-12 else None


from vts_hw.report.history import collect_history  # noqa: E402
from vts_hw.report.steps import collect_steps  # noqa: E402


def collect(
    store, since: float | None = None, now: float | None = None, rig: str | None = None, title: str | None = None
) -> DriftReport:
    """Read the store and compute the report's data (nothing is written)."""
    now = time.time() if now is None else float(now)
    runs = [
        r
        for r in store.runs(procedure=(*DRIFT_PROCEDURES, BASELINE_PROCEDURE))
        if r.started <= now and (rig is None or (r.rig or "") == rig)
    ]
    in_period = [r for r in runs if since is None or r.started >= since]

    baseline_runs = [r for r in runs if r.procedure == BASELINE_PROCEDURE and _completed(r)]
    baseline_ids = {r.id for r in baseline_runs}
    reset = _baseline_cameras(store, baseline_runs)
    all_cam_baselines = [r.started for r in baseline_runs if reset[r.id] is None]

    def baselines_of(cam: str) -> list[float]:
        return sorted(r.started for r in baseline_runs if (only := reset[r.id]) is None or cam in only)

    # fetch from the earliest "latest baseline" so the trend can reach back before `since`
    fetch_since = since
    if since is not None and baseline_runs:
        named = {c for s in reset.values() if s for c in s}
        latest_of = [_latest_before(all_cam_baselines, now)] + [_latest_before(baselines_of(c), now) for c in named]
        latest = [t for t in latest_of if t is not None]
        if latest:
            fetch_since = min(since, min(latest))

    drift_runs = {r.id: r for r in runs if r.procedure in DRIFT_PROCEDURES and _completed(r)}
    values: dict[tuple[str, int], dict] = defaultdict(dict)
    status: dict[tuple[str, int], dict] = defaultdict(dict)
    markers: dict[tuple[str, int], dict] = defaultdict(lambda: defaultdict(dict))
    windows = {m: _Windows(store, m, w) for m, w in catalog.windows().items()}  # the catalog's windows
    for m in store.measurements(procedure=DRIFT_PROCEDURES, since=fetch_since):
        run = drift_runs.get(m.run_id)
        if run is None or not m.subject:
            continue
        v = None if m.value is None or (isinstance(m.value, float) and math.isnan(m.value)) else float(m.value)
        if _is_camera(m.subject):
            values[(m.subject, run.id)][m.metric] = v
            st = m.status
            if not st and m.metric in windows:
                st = windows[m.metric].state(v, run.started)
            if st:  # a metric measured twice in a run (reachable, then lost): its worst
                got = status[(m.subject, run.id)]
                got[m.metric] = str(worst([got.get(m.metric, "OK"), str(st)]))
        else:
            cam, marker = m.subject.split("/", 1)
            markers[(cam, run.id)][marker][m.metric] = v

    points_of: dict[str, list[RunPoint]] = defaultdict(list)
    for (cam, run_id), vals in values.items():
        # every run that measured anything of the camera is a point, also one whose drift it
        # could not measure (the camera did not answer): its state is then ACTION, never OK
        run = drift_runs[run_id]
        points_of[cam].append(RunPoint(run_id, run.started, run.procedure, vals, status[(cam, run_id)]))

    shown_times = [p.t for pts in points_of.values() for p in pts if since is None or p.t >= since]
    period_start = (
        since
        if since is not None
        else (min(shown_times + [r.started for r in in_period]) if (shown_times or in_period) else None)
    )
    band_start = period_start if period_start is not None else now
    bands = {a: windows[m].segments(shown_times, band_start, now) for a, m in BAND_METRICS.items()}

    cameras = {}
    for cam in sorted(points_of, key=_camera_sort_key):
        pts = sorted(points_of[cam], key=lambda p: p.t)
        bl = _latest_before(baselines_of(cam), now)
        fit_pts = [p for p in pts if bl is None or p.t > bl]
        shown = [p for p in pts if since is None or p.t >= since]
        axes = {}
        for a in AXES:
            t = np.array([p.t for p in fit_pts])
            drift = np.array([p.value(f"drift_{a}_px") for p in fit_pts])
            trend = fit_trend(t, drift)
            w = bands[a][-1].window
            axes[a] = AxisSummary(control_limits(t, drift), trend, forecast(trend, w.action_low, w.action_high, now))
        latest_id = shown[-1].run_id if shown else None
        cameras[cam] = CameraDrift(
            name=cam,
            points=shown,
            baselines=[b for b in baselines_of(cam) if (since is None or b >= since) and b <= now],
            baseline_t=bl,
            axes=axes,
            mm_per_px={a: _mm_per_px(pts, a) for a in AXES},
            markers={k: dict(v) for k, v in sorted(markers.get((cam, latest_id), {}).items())}
            if latest_id is not None
            else {},
        )

    return DriftReport(
        title=title or ("VTS camera drift" + (f" — {rig}" if rig else "")),
        rig=rig,
        since=since,
        now=now,
        period_start=period_start,
        cameras=cameras,
        bands=bands,
        baselines=[RunInfo.of(r) for r in in_period if r.id in baseline_ids],
        not_completed=[RunInfo.of(r) for r in in_period if not _completed(r) and r.id not in baseline_ids],
        software_version=__version__,
        control_method=CONTROL_METHOD,
        steps=collect_steps(store, since, now, rig),
        has_baseline=bool(baseline_runs),
        history=collect_history(store, since, now, rig),
    )


def _camera_sort_key(name: str):
    """cam2 before cam10."""
    head = name.rstrip("0123456789")
    tail = name[len(head) :]
    return (head, int(tail) if tail else -1, name)


__all__ = ["collect", "DriftReport", "parse_since"]
