"""What the Daily QA page shows of a run: each camera's state, its figures against their windows,
whether it was measured at all, the run's QATrack+ push; and each camera's drift plot.

Read from the results store (a run just made is shown as the store has it), or from the run's
own result when the store could not take it. Every function here reads the store or draws with
matplotlib: the web layer calls them in threads (``asyncio.to_thread``), never on its loop.

A camera that did not answer (``camera_reachable`` 0, or no figure of it at all) is
``measured: False``: the page says NOT MEASURED with the reason, whatever else; its stored
state is ACTION (procedures/daily.py), never OK.
"""

from __future__ import annotations

import math
import time

from vts_hw import catalog
from vts_hw import report as reports  # the package: its names load when first asked for (vts_hw.lazy)
from vts_hw.console.history import when  # (the History page's wording of a time)
from vts_hw.errors import VtsError
from vts_hw.figures import figure_png
from vts_hw.qatrack import TARGET
from vts_hw.report.drift import collect
from vts_hw.store.baselines import load_baseline
from vts_hw.vision.wall_baseline import NoBaseline

DAILY_NAMES = catalog.by_label()[catalog.DAILY.label]  # daily and drift QA: one check
PLOT_SINCE_S = 60 * 86400.0  # the drift plot's period, as the History page's report
STATE_ORDER = {"OK": 0, "TOLERANCE": 1, "ACTION": 2}


def value_text(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "not measured"
    v = float(v)
    return f"{v:g}" if v.is_integer() else f"{v:+.3f}"


def camera_view(name: str, rows: list[tuple], problems: list[str], run_id: int | None) -> dict:
    """One camera's card: ``rows`` are (metric, value, unit, state, window text) of its own
    figures (per-marker rows left out)."""
    values = {m: v for m, v, _, _, _ in rows}
    reach = values.get("camera_reachable")
    measured = bool(rows) and reach != 0.0
    states = [str(st) for _, _, _, st, _ in rows]
    state = max(states, key=lambda s: STATE_ORDER.get(s, 2)) if states else "ACTION"
    why = ""
    if not measured:
        why = "the camera did not answer" + (f": {problems[0]}" if problems else "")
    drift_known = values.get("drift_x_px") is not None and values.get("drift_y_px") is not None
    return {
        "camera": name,
        "state": state,
        "measured": measured,
        "why": why,
        "drift_measured": measured and drift_known,
        "figures": [
            {"metric": m, "value": value_text(v), "unit": u, "state": str(st), "window": w} for m, v, u, st, w in rows
        ],
        "problems": list(problems),
        "plot": f"/qa/plot/{name}.png?run={run_id}" if run_id is not None else f"/qa/plot/{name}.png",
    }


def _own(subject: str) -> bool:
    return bool(subject) and "/" not in subject


def view_of_result(result, cameras: list[str]) -> dict:
    """The view of a QAResult the store did not take (its figures are in memory only)."""
    windows = result.windows or {}
    cams = []
    for c in result.cameras:
        rows = [
            (m, v, u, st, windows[m].describe() if m in windows else "") for s, m, v, u, st in c.measures if _own(s)
        ]
        cams.append(camera_view(c.camera, rows, c.problems, None))
    seen = {c["camera"] for c in cams}
    cams += [camera_view(n, [], ["no figure of it in this run"], None) for n in cameras if n not in seen]
    return {
        "run": None,
        "procedure": catalog.label(result.procedure),
        "state": str(result.state),
        "started": when(result.started),
        "finished": when(result.finished),
        "status": str(result.state),
        "cameras": cams,
        "push": None,
        "stored": False,
    }


def view_of_run(store, run_id: int, cameras: list[str], problems: dict | None = None) -> dict:
    """The view of stored run ``run_id``; ``problems`` (camera -> sentences) from the run's
    result when the page made it (the store keeps figures, not the procedure's remarks)."""
    run = store.run(run_id)
    ms = store.measurements(run_id=run_id)
    windows = store.windows(m.tolerance_id for m in ms)
    by_cam: dict[str, list] = {}
    for m in ms:
        if _own(m.subject):
            w = windows[m.tolerance_id].describe() if m.tolerance_id in windows else ""
            by_cam.setdefault(m.subject, []).append((m.metric, m.value, m.unit, str(m.status), w))
    problems = problems or {}
    names = list(cameras) + [c for c in by_cam if c not in cameras]
    cams = []
    for n in names:
        rows = by_cam.get(n, [])
        probs = problems.get(n) or ([] if rows else ["no figure of it in this run"])
        cams.append(camera_view(n, rows, probs, run_id))
    return {
        "run": run_id,
        "procedure": catalog.label(run.procedure),
        "state": str(run.status),
        "started": when(run.started),
        "finished": when(run.finished),
        "status": str(run.status),
        "operator": run.operator,
        "cameras": cams,
        "push": push_state(store, run_id),
        "stored": True,
    }


def push_state(store, run_id: int) -> dict | None:
    """The run's QATrack+ outbox row: sent / pending / refused with the peer's last sentence."""
    items = store.outbox_items(TARGET, run_ids=[run_id])
    if not items:
        return None
    i = items[0]
    return {"state": i.state, "message": i.last_error or "", "remote": i.remote or ""}


def latest_run_id(store, rig: str) -> int | None:
    runs = [r for r in store.runs(procedure=DAILY_NAMES) if (r.rig or "") == rig]
    return max(runs, key=lambda r: (r.started, r.id)).id if runs else None


def baselines(store, cameras: list[str], rig: str | None = None) -> dict:
    """Each camera's drift baseline in use (of rig ``rig``, as the daily QA reads them): its run
    and when it was set (None: none yet)."""
    out: dict[str, dict | None] = {}
    for n in cameras:
        try:
            b = load_baseline(store, n, rig)
        except NoBaseline:
            out[n] = None
        else:
            out[n] = {"run": b.run_id, "taken": when(b.taken), "markers": len(b.markers)}
    return out


def latest_view(open_store, rig: str, cameras: list[str]) -> dict:
    """The page's opening state: the latest daily QA of the rig and the baselines in use."""
    if open_store is None:
        raise VtsError("no results store is named for this console")
    with open_store() as store:
        rid = latest_run_id(store, rig)
        return {
            "latest": view_of_run(store, rid, cameras) if rid is not None else None,
            "baselines": baselines(store, cameras, rig),
        }


def drift_plot_png(open_store, rig: str, camera: str, now: float | None = None) -> bytes | None:
    """PNG of ``camera``'s drift over the last 60 days inside its tolerance and action windows
    (the drift report's figure, read from the store); None when the store has no drift of it."""
    now = time.time() if now is None else now
    with open_store() as store:
        report = collect(store, since=now - PLOT_SINCE_S, now=now + 1.0, rig=rig)
    cam = report.cameras.get(camera)
    if cam is None or not cam.points:
        return None
    # through the report package's name loaded when first asked for: the console starts without matplotlib
    return figure_png(reports.camera_figure(report, cam), dpi=80)  # the report's own size: its titles fit


__all__ = ["latest_view", "view_of_run", "view_of_result", "drift_plot_png", "baselines", "push_state"]
