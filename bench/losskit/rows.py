"""One row of bench/motion_under_loss.py: a scan's live and offline figures against the truth.

Every figure comes from what the scan and `vts motion analyze` wrote (the manifest, the
analysis' JSON and motion_6dof.csv) and from the simulated rig's truth (which frames exist and
when they were captured, the patient's breathing cycles, poses and moves). ``bad`` lists the
figures outside their goal that are not flagged unknown or bounded; the verdicts of the bench
are counted from the rows.
"""

from __future__ import annotations

import copy
import csv
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from losskit.truth import (
    MOVE_MIN,
    POSE_GOAL,
    match_moves,
    observed_instants,
    overlap,
    rate_figures,
    stretches_without,
    true_rate,
)
from vts_hw.recording.folder import read_index

LATE_S = 0.5  # the live path's allowance (decision 0048): shorter holes are not NOT TRACKING
EDGE_S = 0.15  # a reported stretch may start or end this much off the frames' times
SIX = ("tx_mm", "ty_mm", "tz_mm", "rx_deg", "ry_deg", "rz_deg")


def exposures(scene, session: Path, names) -> dict:
    """Per camera, the capture times (host s) of the frames the session recorded: each stamp
    through the simulated camera's clock (stamps are truncated to 10 ms: +5 ms)."""
    out = {}
    for n in names:
        clock = scene.clocks[n]
        out[n] = np.array([clock.host_time(r.camera_time) + 0.005 for r in read_index(session / f"{n}.index.csv")])
    return out


def frame_loss(lost, period: float, times: dict) -> tuple[float, int]:
    """(share of frame slots the fault dropped, frames missing that it did not drop: loss the
    renderer or the host added) between each camera's first and last recorded frame;
    ``lost(camera, t)``: whether the fault drops the frame captured at ``t``."""
    slots = dropped = extra = 0
    for n, t in times.items():
        if not len(t):
            continue
        have = set(np.round(t / period).astype(np.int64).tolist())
        for g in range(int(round(t[0] / period)), int(round(t[-1] / period)) + 1):
            slots += 1
            if lost(n, g * period):
                dropped += 1
            elif g not in have:
                extra += 1
    return (dropped / slots if slots else float("nan")), extra


def _pose_rows(export: Path, origin: float):
    with open(export / "motion_6dof.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    t = np.array([float(r["time_s"]) for r in rows]) + origin
    ok = np.array([r["quality"] == "ok" for r in rows])
    six = np.array([[float(r[k]) if r[k] not in ("", None) else np.nan for k in SIX] for r in rows])
    return t, ok, six


def offline(scan, moves) -> dict:
    """Time covered, rate, pose RMS and moves from the analysis, against the truth."""
    d = scan.analysis
    origin = d["time_origin"]
    cov = d["coverage"]
    t, ok, six = _pose_rows(scan.export, origin)
    period, patient = scan.truth.period, scan.truth.patient
    a, b = t[0], t[-1] + period
    seen = observed_instants(scan.truth.times, 2, 0.02)
    inside = np.concatenate([[a - period], seen[(seen >= a) & (seen < b)], [b]])
    gaps = np.diff(inside)
    true_no = float(np.sum(np.where(gaps > 1.5 * period, gaps - period, 0.0)))
    bad = []
    if abs(cov["no_frames_s"] - true_no) > 0.01 * cov["duration_s"]:
        bad.append(f"time without frames {cov['no_frames_s']:.1f} s reported, {true_no:.1f} s truly")
    rate = rate_figures(d["breathing"], true_rate(patient, a, b))
    bad += [rate["bad"]] if rate["bad"] else []
    still = ok & np.isfinite(six).all(axis=1)
    for m in patient.motion.moves:
        still &= ~((t >= m.t_start - 0.2) & (t <= m.t_end + 0.5))
    if still.any():
        err = six[still] - np.array([patient.six_dof(float(x)) for x in t[still]])
        mm = float(np.sqrt(np.mean(np.sum(err[:, :3] ** 2, axis=1))))
        deg = float(np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, axis=1))))
    else:
        mm = deg = float("nan")
    if not (mm <= POSE_GOAL[0] and deg <= POSE_GOAL[1]):
        bad.append(f"pose {mm:.3f} mm {deg:.3f} deg")
    result = SimpleNamespace(
        pose=SimpleNamespace(t=t, valid=ok),
        events=[
            SimpleNamespace(
                t_start=e["t_start"] + origin,
                start_bounds=None
                if not e.get("start_bounds_s")
                else (e["start_bounds_s"][0] + origin, e["start_bounds_s"][1] + origin),
            )
            for e in d["events"]
        ],
    )
    mv = match_moves(result, [m for m in moves if a <= m.t_start <= b])
    bad += mv["bad"]
    return {
        "covered": cov["share"],
        "true_covered": 1.0 - true_no / cov["duration_s"],
        "rate": rate,
        "pose": (mm, deg),
        "moves": mv,
        "bad": bad,
    }


def centre_shift(patient, m) -> tuple[float, float]:
    """The move's translation of the markers' centre (mm) and its turn (deg)."""
    centre = np.mean([k.center for k in patient.markers_at(m.t_start - 0.01, np.zeros(3))], axis=0)
    R0, t0 = patient.body_transform(m.t_start - 0.01)
    R1, t1 = patient.body_transform(m.t_end + 0.01)
    cos = (np.trace(R1 @ R0.T) - 1.0) / 2.0
    return float(np.linalg.norm((R1 @ centre + t1) - (R0 @ centre + t0))), float(
        np.degrees(np.arccos(np.clip(cos, -1, 1)))
    )


def live(scan, moves) -> dict:
    """NOT TRACKING reported (manifest) against the time truly without a frame set of two
    cameras (stretches over ``LATE_S``), and each move's alert against its true start."""
    m = scan.manifest
    lm = m.get("live_motion") or {}
    summ = lm.get("summary") or {}
    st = (m.get("scan") or {}).get("times") or {}
    a, b = st.get("first_frames"), st.get("stopped")
    bad = []
    if a is None or b is None or not summ:
        return {
            "reported": None,
            "truly": None,
            "unreported": None,
            "latency": [],
            "bad": ["the scan did not run live"],
            "flagged": 0,
            "other_alerts": 0,
            "phase": None,
        }
    seen = observed_instants(scan.truth.times, 2, 0.02)
    truly = stretches_without(seen, a, b, LATE_S)
    rep = [(e["start"], e["end"]) for e in lm.get("not_tracking", [])]
    # stretches the live path was behind the frames, not without them: the host's doing
    late = sum(
        e["end"] - e["start"]
        for e in lm.get("not_tracking", [])
        if all(r.startswith("frames too late") for r in e.get("reasons", []))
    )
    unrep = [(s0, s1, (s1 - s0) - overlap(rep, s0, s1)) for s0, s1 in truly]
    for s0, s1, u in unrep:
        if u > EDGE_S:
            bad.append(f"{u:.2f} s of {s1 - s0:.2f} s without frames at {s0 - a:.1f} s not reported NOT TRACKING")
    after = lm.get("alert_after_s", 1.0)
    learned = None
    if summ.get("phase") == "tracking":
        learned = a + (summ.get("tracking") or {}).get("reference_s", 0.0)
        for s0, s1 in sorted(rep):
            if s0 <= learned:
                learned += s1 - s0
    alerts = sorted(lm.get("alerts", []), key=lambda x: x["raised"])
    firsts, other = {}, 0
    for x in alerts:
        before = [k for k, mv in enumerate(moves) if mv.t_start - 0.5 <= x["raised"]]
        if before and before[-1] not in firsts:
            firsts[before[-1]] = x
        else:
            other += 1
    if other:
        bad.append(f"{other} alert(s) for no move")
    lat, flagged = [], 0
    lim_mm, lim_deg = lm.get("alert_mm", 3.0), lm.get("alert_deg", 2.0)
    for k, mv in enumerate(moves):
        if not a <= mv.t_start <= b - after - 0.5:
            continue
        mm, deg = centre_shift(scan.truth.patient, mv)
        must = mm >= 1.2 * lim_mm or deg >= 1.2 * lim_deg
        x = firsts.get(k)
        blind = learned is None or mv.t_start < learned or overlap(rep, mv.t_start, mv.t_end + after + 0.5) > 0
        if x is None:
            if must:
                lat.append(("none", None))
                if blind:
                    flagged += 1
                else:
                    bad.append(f"no alert for the move at {mv.t_start - a:.1f} s ({mm:.1f} mm, {deg:.1f} deg)")
            continue
        delay = x["raised"] - mv.t_start
        bounded = x.get("onset_known_s", 0.0) > 0.25
        lat.append(("bounded" if bounded else "measured", delay))
        # an alert that says it was raised late (the host behind its frames) is flagged when,
        # without the lateness it reported, it would be within the goal
        host_late = x.get("late_s", 0.0) > 0.25 and delay - x["late_s"] <= after + 0.5
        if delay > after + 0.5 and must:
            if bounded or blind or host_late:
                flagged += 1
            else:
                bad.append(f"alert {delay:.2f} s after the move at {mv.t_start - a:.1f} s")
    return {
        "reported": sum(e1 - e0 for e0, e1 in rep),
        "late": late,
        "truly": sum(s1 - s0 for s0, s1 in truly),
        "stretches": (len(rep), len(truly)),
        "unreported": sum(max(0.0, u) for *_, u in unrep),
        "latency": lat,
        "after": after,
        "bad": bad,
        "flagged": flagged,
        "other_alerts": other,
        "phase": summ.get("phase"),
        "live_dropped": sum((summ.get("live_dropped") or {}).values()),
    }


def slot_truth(prig, scan) -> SimpleNamespace:
    """What the truth says of ``scan``, taken before the rig moves on to the next pattern (the
    stretch rewound moves the patient's plan; the faults change): the patient as it was, each
    camera's capture times, the share of frame slots the fault dropped and the frames missing
    that it did not drop."""
    names = list(scan.manifest.get("cameras") or {})
    times = exposures(prig.rig.scene, scan.session, names) if names else {}
    dropped, extra = frame_loss(prig.lost, 1.0 / prig.rig.fps, times) if times else (float("nan"), 0)
    return SimpleNamespace(
        patient=copy.deepcopy(prig.patient), times=times, period=1.0 / prig.rig.fps, dropped=dropped, extra=extra
    )


def score(scan, loss: float, load: bool, seed: int, bank_live: int) -> dict:
    """The row of one scan (``scan.truth`` from :func:`slot_truth`; ``loss``: the share
    asked; ``bank_live``: frames of the slot the simulated cameras had to render live, not from
    those made ahead)."""
    tr = scan.truth
    moves = [
        mv
        for mv in tr.patient.motion.moves
        if np.linalg.norm(mv.translation_mm) >= MOVE_MIN[0] or np.linalg.norm(mv.rotation_deg) >= MOVE_MIN[1]
    ]
    row = {
        "seed": seed,
        "cameras": scan.cameras,
        "loss": loss,
        "load": load,
        "dropped": tr.dropped,
        "extra": tr.extra,
        "bank_live": bank_live,
        "wall_s": scan.wall_s,
        "analysis_s": scan.analysis_wall_s,
        "exit": scan.returncode,
        "status": scan.manifest.get("status"),
        "watched": ((scan.manifest.get("live_motion") or {}).get("summary") or {}).get("watched"),
    }
    row["live"] = live(scan, moves)
    row["agree"] = (scan.analysis or {}).get("live")  # live poses against offline ones (issue 33)
    if scan.analysis is None:
        row["offline"] = None
        row["bad"] = row["live"]["bad"] + [scan.analysis_error or "no analysis"]
    else:
        row["offline"] = offline(scan, moves)
        row["bad"] = row["offline"]["bad"] + row["live"]["bad"]
    off = row["offline"]
    row["flagged"] = row["live"]["flagged"] + (
        0
        if off is None
        else ((off["rate"]["status"] in ("unknown", "bounded")) + off["moves"]["bounded"] + off["moves"]["unseen"])
    )
    return row
