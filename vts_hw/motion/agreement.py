"""The live poses against the offline poses of the same scan: how far apart the two ways of
running the one patient model are (issue 33; docs/decisions/0092), and whether each alert the
technologist was given is explained by the offline poses.

Both are poses of the same model (reference -> now): a live pose and the offline pose of the
frame set it was made from are compared at the markers' centre (mm: where the two poses carry
the centre) and by the angle of the turn between them (deg). A live pose is paired with the
offline frame nearest its time within ``tolerance_s`` (less than half a frame period: the same
frame set); a live pose without one, or whose offline frame has no pose, is counted, never
compared.

An alert is **explained** when the offline analysis found a body move (an event) between its
onset (less ``margin_s``) and its time (plus ``margin_s``), or, failing an event, when the
offline poses moved the markers' centre or turned the body past the alert's limits between the
onset and the alert; otherwise the reason is given (no offline pose there, or what the offline
poses measured).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = ["Agreement", "compare_live", "explain_alerts"]


@dataclass
class Agreement:
    """``compared``: live poses paired with an offline pose; ``live``: live poses in all;
    ``unpaired``: live poses without an offline frame at their time; ``no_offline_pose``: paired
    with a frame the offline fit has no pose for; RMS and worst difference at the markers'
    centre (mm) and of the turn (deg), and when the worst were (on the offline clock);
    ``alerts``: per live alert, whether the offline poses explain it (:func:`explain_alerts`)."""

    compared: int
    live: int
    unpaired: int
    no_offline_pose: int
    rms_mm: float = float("nan")
    worst_mm: float = float("nan")
    rms_deg: float = float("nan")
    worst_deg: float = float("nan")
    worst_mm_at: float | None = None
    worst_deg_at: float | None = None
    alerts: list = field(default_factory=list)

    def to_json(self, t0: float = 0.0) -> dict:
        def f(x, n):
            return None if x is None or not np.isfinite(x) else round(float(x), n)

        return {
            "compared": self.compared,
            "live_poses": self.live,
            "unpaired": self.unpaired,
            "no_offline_pose": self.no_offline_pose,
            "rms_mm": f(self.rms_mm, 4),
            "worst_mm": f(self.worst_mm, 4),
            "rms_deg": f(self.rms_deg, 5),
            "worst_deg": f(self.worst_deg, 5),
            "worst_mm_at_s": None if self.worst_mm_at is None else round(self.worst_mm_at - t0, 3),
            "worst_deg_at_s": None if self.worst_deg_at is None else round(self.worst_deg_at - t0, 3),
            "alerts": [
                {**a, **{k: round(a[k] - t0, 3) for k in ("onset", "time", "event_start") if k in a}}
                for a in self.alerts
            ],
        }

    def text(self) -> str:
        if not self.compared:
            return (
                f"live and offline poses: none compared ({self.live} live pose(s), {self.unpaired} without an "
                f"offline frame, {self.no_offline_pose} whose frame has no offline pose)"
            )
        out = (
            f"live and offline poses agree to {self.rms_mm:.3f} mm RMS (worst {self.worst_mm:.3f} mm) and "
            f"{self.rms_deg:.4f} deg RMS (worst {self.worst_deg:.4f} deg) over {self.compared} of {self.live} "
            f"live poses"
        )
        left = self.unpaired + self.no_offline_pose
        if left:
            out += (
                f" ({self.unpaired} without an offline frame, {self.no_offline_pose} whose frame has no offline pose)"
            )
        return out


def _pose_gap(R1, T1, R2, T2, centre):
    """(mm at the centre, deg of the turn) between poses (F,3,3), (F,3) pairwise."""
    c1 = np.einsum("fij,j->fi", R1, centre) + T1
    c2 = np.einsum("fij,j->fi", R2, centre) + T2
    mm = np.linalg.norm(c1 - c2, axis=1)
    deg = np.degrees(Rotation.from_matrix(np.einsum("fij,fkj->fik", R1, R2)).magnitude())
    return mm, deg


def compare_live(t_live, R_live, T_live, t_off, R_off, T_off, centre, tolerance_s: float) -> Agreement:
    """The live poses (at ``t_live``, on the offline series' clock) against the offline poses
    (at ``t_off``, in time order; NaN where none) of the same model (``centre``: its markers'
    reference centre)."""
    t_live, t_off = np.asarray(t_live, float), np.asarray(t_off, float)
    n = len(t_live)
    if n == 0 or len(t_off) == 0:
        return Agreement(0, n, n, 0)
    k = np.clip(np.searchsorted(t_off, t_live), 1, max(len(t_off) - 1, 1))
    k = np.where(np.abs(t_off[k - 1] - t_live) <= np.abs(t_off[np.minimum(k, len(t_off) - 1)] - t_live), k - 1, k)
    k = np.minimum(k, len(t_off) - 1)
    near = np.abs(t_off[k] - t_live) <= tolerance_s
    has = near & np.isfinite(T_off[k, 0]) & np.isfinite(np.asarray(T_live)[:, 0])
    out = Agreement(int(has.sum()), n, int((~near).sum()), int((near & ~has).sum()))
    if not has.any():
        return out
    mm, deg = _pose_gap(
        np.asarray(R_live)[has], np.asarray(T_live)[has], R_off[k[has]], T_off[k[has]], np.asarray(centre, float)
    )
    tt = t_live[has]
    out.rms_mm, out.worst_mm = float(np.sqrt(np.mean(mm**2))), float(mm.max())
    out.rms_deg, out.worst_deg = float(np.sqrt(np.mean(deg**2))), float(deg.max())
    out.worst_mm_at, out.worst_deg_at = float(tt[np.argmax(mm)]), float(tt[np.argmax(deg)])
    return out


def explain_alerts(
    alerts,
    events,
    t_off,
    R_off,
    T_off,
    centre,
    alert_mm: float,
    alert_deg: float,
    margin_s: float = 1.0,
    t0: float = 0.0,
) -> list[dict]:
    """Per live alert (``onset``, ``time``: on the offline clock), whether the offline poses
    explain it: ``explained`` True with ``by`` (the event's start and size, or the offline move),
    else False with ``why`` (times in the sentences from ``t0``)."""
    out = []
    for a in alerts:
        onset, at = float(a["onset"]), float(a["time"])
        entry: dict[str, object] = {"onset": onset, "time": at}
        ev = [e for e in events if e.t_end >= onset - margin_s and e.t_start <= at + margin_s]
        if ev:
            e = max(ev, key=lambda e: e.centre_mm)
            entry.update(
                explained=True,
                by=(
                    f"the offline body move from {e.t_start - t0:.2f} to {e.t_end - t0:.2f} s: "
                    f"{e.centre_mm:.1f} mm at the centre, {e.angle_deg:.1f} deg"
                ),
                event_start=e.t_start,
            )
            out.append(entry)
            continue
        sel = (t_off >= onset - margin_s) & (t_off <= at + margin_s) & np.isfinite(T_off[:, 0])
        if sel.sum() < 2:
            entry.update(
                explained=False,
                why="the offline analysis has no pose between the alert's onset and the "
                "alert (frames missing from the recording there)",
            )
            out.append(entry)
            continue
        i = np.flatnonzero(sel)
        c = np.asarray(centre, float)
        mm, deg = _pose_gap(
            R_off[i], T_off[i], np.repeat(R_off[i[:1]], len(i), 0), np.repeat(T_off[i[:1]], len(i), 0), c
        )
        if mm.max() > alert_mm or deg.max() > alert_deg:
            entry.update(
                explained=True,
                by=(
                    f"the offline poses moved {mm.max():.1f} mm, {deg.max():.1f} deg from the "
                    f"onset (no event: shorter than an event's rules)"
                ),
            )
        else:
            entry.update(
                explained=False,
                why=(
                    f"offline the body moved at most {mm.max():.2f} mm and {deg.max():.2f} deg "
                    f"from the onset to the alert (limits {alert_mm:g} mm, {alert_deg:g} deg)"
                ),
            )
        out.append(entry)
    return out
