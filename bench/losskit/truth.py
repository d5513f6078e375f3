"""Figures of a motion analysis or a live path scored against the simulated patient's truth,
shared by bench/motion_loss.py, bench/live_blind_time.py and bench/motion_under_loss.py.

The goals are the patient issue's: breathing rate within ``RATE_GOAL`` /min of the truth (the
median rate of the true breaths in the span analysed); body pose in still frames within
``POSE_GOAL`` (mm, deg RMS); every move of ``MOVE_MIN`` (mm or deg) or more found with its start
within ``START_GOAL`` s -- or, when it began where nothing was seen, its start bounded by that
time (the true start inside the bound). A figure outside its goal must say so (``unknown``, or
``bounded`` with the truth inside); anything else is a miss, listed in ``bad``.
"""

from __future__ import annotations

import numpy as np

RATE_GOAL = 0.5  # /min
POSE_GOAL = (0.3, 0.2)  # mm, deg RMS in still frames
MOVE_MIN = (2.0, 1.0)  # a move to be found: mm or deg
START_GOAL = 0.5  # s


def true_rate(patient, a: float, b: float) -> float:
    """The median rate (/min) of the patient's true breaths lying whole in [a, b] (host s)."""
    cyc = [c for c in patient.breathing.cycles if a <= c.t_start and c.t_start + c.period_s <= b and c.kind != "pause"]
    return float(np.median([60.0 / c.period_s for c in cyc])) if cyc else float("nan")


def rate_figures(b: dict, truth: float) -> dict:
    """The analysis' ``breathing`` (``results_data()["breathing"]``) against the true rate:
    status, value, range, error, whether the truth lies in a bounded range, and the miss (or
    None): a measured rate off by more than the goal, a range missing the truth, ``none``."""
    rate, rng, status = b["rate_per_min"], b.get("rate_range_per_min"), b["status"]
    err = None if rate is None else rate - truth
    inside = None if not rng else bool(rng[0] <= truth <= rng[1])
    bad = None
    if status == "measured" and abs(err) > RATE_GOAL:
        bad = f"rate {rate:.2f} against {truth:.2f} (measured)"
    elif status == "bounded" and not inside:
        bad = f"rate range {rng} misses {truth:.2f}"
    elif status == "none":
        bad = "breathing reported as none"
    return {"status": status, "rate": rate, "range": rng, "truth": truth, "err": err, "inside": inside, "bad": bad}


def pose_rms(result, patient) -> tuple[float, float]:
    """Body 6-DOF RMS (mm, deg) against the truth over the frames with a pose outside moves."""
    t = result.pose.t
    sel = result.pose.valid & ~result.moving
    if not sel.any():
        return float("nan"), float("nan")
    err = result.pose.six_dof()[sel] - np.array([patient.six_dof(float(x)) for x in t[sel]])
    return (
        float(np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1)))),
        float(np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1)))),
    )


def true_moves(patient, a: float = -np.inf, b: float = np.inf) -> list:
    """The patient's moves of ``MOVE_MIN`` or more starting in [a, b]."""
    return [
        m
        for m in patient.motion.moves
        if a <= m.t_start <= b
        and (np.linalg.norm(m.translation_mm) >= MOVE_MIN[0] or np.linalg.norm(m.rotation_deg) >= MOVE_MIN[1])
    ]


def match_moves(result, moves) -> dict:
    """Each true move against the analysis' events: ``found`` (start measured within the
    goal), ``bounded`` (start given as a range holding the truth), ``unseen`` (no pose after
    it: nothing can show it, and the coverage says so); the rest are misses in ``bad``.
    ``max_err``: the largest start error of those found; ``ranges``: the bounds given;
    ``false``: events matching no true move."""
    t = result.pose.t
    out = {
        "moves": len(moves),
        "found": 0,
        "bounded": 0,
        "unseen": 0,
        "max_err": None,
        "ranges": [],
        "false": 0,
        "bad": [],
    }
    used = set()
    for m in moves:
        ok = None
        for k, e in enumerate(result.events):
            if e.start_bounds is None and abs(e.t_start - m.t_start) <= START_GOAL:
                ok = ("found", k)
            elif e.start_bounds is not None and e.start_bounds[0] <= m.t_start <= e.start_bounds[1]:
                ok = ("bounded", k)
            if ok:
                break
        if ok is None:
            if not result.pose.valid[t > m.t_start].any():
                out["unseen"] += 1
                continue
            near = [e.t_start - m.t_start for e in result.events if e.start_bounds is None]
            off = f" (nearest event {min(near, key=abs):+.2f} s off)" if near else ""
            out["bad"].append(f"move at {m.t_start - t[0]:.2f} s not found{off}")
            continue
        used.add(ok[1])
        e = result.events[ok[1]]
        out[ok[0]] += 1
        if ok[0] == "found":
            err = e.t_start - m.t_start
            out["max_err"] = err if out["max_err"] is None or abs(err) > abs(out["max_err"]) else out["max_err"]
        else:
            out["ranges"].append((e.start_bounds[0] - m.t_start, e.start_bounds[1] - m.t_start))
    out["false"] = len(result.events) - len(used)
    if out["false"]:
        out["bad"].append(f"{out['false']} event(s) that did not happen")
    return out


def observed_instants(times: dict, min_cams: int = 2, tol: float = 0.02, ref: str | None = None) -> np.ndarray:
    """Instants (sorted) at which at least ``min_cams`` cameras have a frame within ``tol`` s of
    each other: the frames of ``ref`` (default: of every camera) that enough others saw too.
    ``times``: per camera, its frames' times (any order)."""
    arrays = {n: np.sort(np.asarray(v, float)) for n, v in times.items() if len(v)}
    if len(arrays) < min_cams:
        return np.zeros(0)
    cands = [ref] if ref is not None else list(arrays)
    out = []
    for c in cands:
        a = arrays.get(c)
        if a is None:
            continue
        count = np.ones(a.size, int)
        for n, b in arrays.items():
            if n == c:
                continue
            if b.size == 1:
                count += np.abs(b[0] - a) <= tol
                continue
            j = np.clip(np.searchsorted(b, a), 1, b.size - 1)
            count += np.minimum(np.abs(b[j] - a), np.abs(b[j - 1] - a)) <= tol
        out.append(a[count >= min_cams])
    return np.unique(np.concatenate(out)) if out else np.zeros(0)


def stretches_without(instants: np.ndarray, a: float, b: float, longer_s: float) -> list[tuple[float, float]]:
    """The stretches of [a, b] longer than ``longer_s`` between consecutive ``instants`` (the
    span's ends count as instants)."""
    inside = instants[(instants > a) & (instants < b)]
    both = np.concatenate([[a], inside, [b]])
    gaps = np.diff(both)
    return [(float(both[i]), float(both[i + 1])) for i in np.flatnonzero(gaps > longer_s)]


def overlap(stretches, a: float, b: float) -> float:
    """Seconds of [a, b] that ``stretches`` ((start, end) pairs) cover."""
    return float(sum(max(0.0, min(e, b) - max(s, a)) for s, e in stretches))
