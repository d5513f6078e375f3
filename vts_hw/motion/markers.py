"""Marker tracks as a regular table: per frame f and physical marker m, a position or NaN.

:class:`~vts_hw.tracking.tracks.Tracks` gives points with identities; an identity ends when a
marker is unseen for a while (a camera gap, a SPECT head in the way) and the marker comes back
under a new id. :func:`marker_series` re-joins such pieces (ids that follow one another in time
and meet within ``join_mm``) and lays the points out as ``P[f, m, :]``.

Clock and frame are chosen once here and said in :attr:`MarkerSeries.clock` and
:attr:`MarkerSeries.frame`: SPECT list-mode seconds when the tracks have ``spect_time`` (else
host UTC epoch seconds); SPECT-frame positions when the tracks have them (else the VTS frame).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from vts_hw.errors import DataError
from vts_hw.vision.registration import kabsch

__all__ = ["MarkerSeries", "marker_series", "join_pieces"]

JOIN_MM = 25.0  # pieces of one marker meet within this across a gap
JOIN_GAP_S = 10.0  # ... and follow one another within this
COHORT_S = 0.5  # pieces starting this close together after a gap are matched as one body
COHORT_GAP_S = 600.0  # ... after a gap of up to this (a rigid match of 3 or more does not happen by chance)
RIGID_GATE_MM = 12.0  # ... each within this of its marker after the body's rigid motion (breathing
# changes the band's shape by a few mm between two breath levels)
BAND_GATE_MM = 50.0  # a piece and a marker no rigid motion pairs: one another's nearest within this,
BAND_RATIO = 2.5  # ... any other this many times as far (_band_pairs)


@dataclass
class MarkerSeries:
    """Positions ``P`` (F, M, 3) mm (NaN where unseen) at times ``t`` (F,) s; ``ids[m]``: the
    track ids joined into marker m; ``clock``/``frame``: what ``t`` and ``P`` are;
    ``cameras[f, m]``: how many cameras saw the point (0 when unseen); ``camera_sets``: per
    marker, how many points each camera took part in."""

    t: np.ndarray
    P: np.ndarray
    ids: list
    clock: str = "host"
    frame: str = "vts"
    cameras: np.ndarray | None = None
    camera_names: list = field(default_factory=list)
    camera_sets: list = field(default_factory=list)
    numbers: list = field(default_factory=list)  # per column: the marker's number in the whole series

    @property
    def seen(self) -> np.ndarray:
        """(F, M) bool."""
        return np.isfinite(self.P[..., 0])

    def subset(self, cols) -> MarkerSeries:
        cols = list(cols)
        return MarkerSeries(
            self.t,
            self.P[:, cols],
            [self.ids[c] for c in cols],
            self.clock,
            self.frame,
            None if self.cameras is None else self.cameras[:, cols],
            list(self.camera_names),
            [self.camera_sets[c] for c in cols] if self.camera_sets else [],
            [self.number(c) for c in cols],
        )

    def number(self, m: int) -> int:
        """Marker m's number (1, 2, ... in the order the markers were first seen; kept by subset)."""
        return self.numbers[m] if self.numbers else m + 1

    def label(self, m: int) -> str:
        """``marker 3``, or ``marker 3 (26 track pieces)`` when it was tracked in pieces (its ids
        are in ``ids[m]``)."""
        n = len(self.ids[m])
        return f"marker {self.number(m)}" + (f" ({n} track pieces)" if n > 1 else "")


def rigid_match(starts, ends, gate_mm: float = RIGID_GATE_MM, start_gate_mm: float = 2 * RIGID_GATE_MM):
    """Pairs ``(i, a)`` of pieces starting at ``starts[i]`` and markers last seen at ``ends[a]``
    that one rigid motion of the body explains (the body moved while none was seen): every
    pairing of one start with one end proposes a translation; the one that brings most starts
    within ``start_gate_mm`` of an end wins; then the assignment (Hungarian) and a rigid fit of
    the pairs, twice, the gate shrinking to ``gate_mm``. Fewer than 3 pairs: none (two points
    do not show a rigid motion)."""
    S, E = np.asarray(starts, float), np.asarray(ends, float)
    if len(S) < 3 or len(E) < 3:
        return []
    best, best_key = None, (0, np.inf)
    for i in range(len(S)):
        for a in range(len(E)):
            D = np.linalg.norm(S[:, None] + (E[a] - S[i]) - E[None], axis=2)
            m = D.min(axis=1)
            key = (int((m < start_gate_mm).sum()), float(np.sum(np.minimum(m, start_gate_mm))))
            if key[0] > best_key[0] or (key[0] == best_key[0] and key[1] < best_key[1]):
                best, best_key = E[a] - S[i], key
    moved = S + best
    pairs = []
    for gate in (start_gate_mm, gate_mm, gate_mm):
        D = np.linalg.norm(moved[:, None] - E[None], axis=2)
        r, c = linear_sum_assignment(np.minimum(D, 1e6))
        pairs = [(int(i), int(a)) for i, a in zip(r, c) if D[i, a] < gate]
        if len(pairs) < 3:
            return []
        try:
            tr = kabsch(S[[i for i, _ in pairs]], E[[a for _, a in pairs]])
        except ValueError:  # the pairs on one line: no turn can be told
            return []
        moved = tr.apply(S)
    return pairs


def _band_pairs(starts, ends, gate_mm: float = BAND_GATE_MM, ratio: float = BAND_RATIO):
    """Pairs ``(i, a)`` of pieces starting together after a gap and markers lost just before
    it that no rigid motion explains -- a band seen at the top of a deep breath on one side of
    the gap and at its middle on the other moves 25-30 mm, and not rigidly -- each start and
    end one another's nearest, within ``gate_mm``, every other end and start at least
    ``ratio`` times as far (the band's markers are 80 mm or more apart): no choice is made
    where two were possible."""
    S, E = np.asarray(starts, float).reshape(-1, 3), np.asarray(ends, float).reshape(-1, 3)
    if len(S) == 0 or len(E) == 0:
        return []
    D = np.linalg.norm(S[:, None] - E[None], axis=2)
    pairs = []
    for i in range(len(S)):
        a = int(np.argmin(D[i]))
        d = D[i, a]
        others = np.concatenate([np.delete(D[i], a), np.delete(D[:, a], i)])
        if d < gate_mm and int(np.argmin(D[:, a])) == i and (others.size == 0 or others.min() >= ratio * d):
            pairs.append((i, a))
    return pairs


def join_pieces(first, last, start_xyz, end_xyz, ids, join_mm=JOIN_MM, gap_s=JOIN_GAP_S) -> list[list]:
    """Group track pieces into physical markers, in time order. Pieces that start together
    (within :data:`COHORT_S`) after markers were lost together -- a gap in the recording --
    join those markers as one rigid body (:func:`rigid_match`; then the pieces left, as another:
    a band that breathed between the two sides of the gap), after a gap of up to
    :data:`COHORT_GAP_S`: the patient may have moved in the gap by more than ``join_mm``. Any
    other piece joins the chain whose end it follows in
    time (within ``gap_s``) and meets nearest (within ``join_mm``)."""
    order = list(np.argsort(first, kind="stable"))
    chains: list[dict] = []

    def open_chains(t, within=gap_s):
        return [c for c in chains if c["last"] < t <= c["last"] + within]

    def extend(c, k):
        c["ids"].append(ids[k])
        c["last"], c["end"] = last[k], end_xyz[k]

    j = 0
    while j < len(order):
        cohort = [k for k in order[j:] if first[k] <= first[order[j]] + COHORT_S]
        j += len(cohort)
        cands = [c for c in open_chains(first[cohort[0]], COHORT_GAP_S) if c["last"] < min(first[k] for k in cohort)]
        taken = set()
        # one rigid body, then what is left (the abdomen's band, say: breathing moves it up to
        # ~25 mm between two breath levels, more than the gate, but it moves as a whole)
        for _ in range(3):
            left = [k for k in cohort if k not in taken]
            if len(left) < 3 or len(cands) < 3:
                break
            pairs = rigid_match(start_xyz[left], np.array([c["end"] for c in cands]))
            if not pairs:
                break
            for i, a in pairs:
                extend(cands[a], left[i])
                taken.add(left[i])
            cands = [c for j, c in enumerate(cands) if j not in {a for _, a in pairs}]
        left = [k for k in cohort if k not in taken]
        near = [c for c in cands if c["last"] >= first[cohort[0]] - gap_s]
        for i, a in _band_pairs(start_xyz[left], np.array([c["end"] for c in near]).reshape(-1, 3)):
            extend(near[a], left[i])
            taken.add(left[i])
        for k in cohort:
            if k in taken:
                continue
            best, best_d = None, join_mm
            for c in open_chains(first[k]):
                d = float(np.linalg.norm(c["end"] - start_xyz[k]))
                if d <= best_d:
                    best, best_d = c, d
            if best is None:
                chains.append({"ids": [ids[k]], "last": last[k], "end": end_xyz[k]})
            else:
                extend(best, k)
    return [c["ids"] for c in chains]


def marker_series(tracks, *, join_mm: float = JOIN_MM, use_spect: bool = True) -> MarkerSeries:
    """The tracks as a :class:`MarkerSeries` (see the module for the clock and frame)."""
    if len(tracks.marker) == 0:
        raise DataError("no marker was triangulated in the recording (LEDs off? wrong calibration?)")
    spect_clock = use_spect and tracks.spect_time is not None
    spect_frame = use_spect and tracks.xyz_spect is not None
    t_frames = np.asarray(tracks.spect_time if spect_clock else tracks.host_time, float)
    xyz = np.asarray(tracks.xyz_spect if spect_frame else tracks.xyz, float)
    pf = np.asarray(tracks.point_frame, int)
    mk = np.asarray(tracks.marker, int)
    pt = t_frames[pf]
    uniq = sorted(set(mk.tolist()))
    first, last, p0, p1 = [], [], [], []
    for m in uniq:
        sel = np.flatnonzero(mk == m)
        o = sel[np.argsort(pt[sel], kind="stable")]
        first.append(pt[o[0]])
        last.append(pt[o[-1]])
        p0.append(xyz[o[0]])
        p1.append(xyz[o[-1]])
    chains = join_pieces(np.array(first), np.array(last), np.array(p0), np.array(p1), uniq, join_mm)
    col = {i: c for c, ch in enumerate(chains) for i in ch}
    F, M = len(t_frames), len(chains)
    P = np.full((F, M, 3), np.nan)
    ncam = np.zeros((F, M), int)
    cams = tracks.point_cameras
    c_of = np.array([col[m] for m in mk.tolist()])
    P[pf, c_of] = xyz  # a second point of one marker in one frame: the last wins
    ncam[pf, c_of] = cams.sum(axis=1)
    names = list(tracks.camera_names)
    sets = []
    for c in range(M):
        sel = c_of == c
        sets.append({n: int(cams[sel, k].sum()) for k, n in enumerate(names)})
    return MarkerSeries(
        t_frames,
        P,
        chains,
        "spect" if spect_clock else "host",
        "spect" if spect_frame else "vts",
        ncam,
        names,
        sets,
        list(range(1, M + 1)),
    )
