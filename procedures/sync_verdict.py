"""The sync check's verdict: its figures judged against the tolerance table's sync windows.

``sync_max_abs_dt_ms`` (the worst event both systems saw), ``sync_events_one_system`` (events
one system saw alone) and ``sync_events_both`` (at least one, or nothing was checked); the
state is the worst of the three, as for every QA procedure, and the reason says why in words.
"""

from __future__ import annotations

from vts_hw import catalog
from vts_hw.tolerance import State, Window, worst

METRICS = ("sync_max_abs_dt_ms", "sync_events_one_system", "sync_events_both")


def sync_windows(overrides: dict | None = None) -> dict[str, Window]:
    """The sync windows of the catalog's (the rig's overrides on top of the defaults)."""
    table = catalog.windows(overrides)
    return {m: table[m] for m in METRICS}


def sync_measures(summary: dict) -> dict[str, float | None]:
    """The three figures the windows judge, from a sync summary."""
    worst_s = summary.get("max_abs_dt_s")
    return {
        "sync_max_abs_dt_ms": None if worst_s is None else worst_s * 1e3,
        "sync_events_one_system": (summary.get("events_spect_only") or 0) + (summary.get("events_vts_only") or 0),
        "sync_events_both": summary.get("events_both") or 0,
    }


def sync_verdict(summary: dict, windows: dict[str, Window] | None = None, problems=()) -> tuple[State, str]:
    """(state, reason) of a sync summary; ``windows`` from :func:`sync_windows`."""
    w = windows or sync_windows()
    values = sync_measures(summary)
    states = {m: w[m].state(values[m]) for m in METRICS}
    state = worst(states.values())
    dt_w = w["sync_max_abs_dt_ms"]
    both, one_side, dt = values["sync_events_both"], values["sync_events_one_system"], values["sync_max_abs_dt_ms"]
    if states["sync_events_both"] is State.ACTION or dt is None:
        reason = "no motion event was seen by both the VTS and the SPECT"
    elif states["sync_max_abs_dt_ms"] is State.ACTION:
        reason = f"an event differs by {dt:.0f} ms, more than {dt_w.action_high:g} ms"
    elif states["sync_max_abs_dt_ms"] is State.TOLERANCE:
        reason = f"an event differs by {dt:.0f} ms, more than the {dt_w.tolerance_high:g} ms goal"
    elif states["sync_events_one_system"] is not State.OK:
        reason = f"{one_side:g} event(s) seen by one system only"
    else:
        reason = f"every one of the {both:g} event(s) agrees within {dt_w.tolerance_high:g} ms"
        if not problems:
            reason += "; no problems found"
    return state, reason
