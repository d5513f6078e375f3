"""The source marker's steps in a position trace (the sync check's moves; not the patient's motion
events, vts_hw/motion/): find the steps, time each one's mid-crossing precisely.

The sync check moves a source marker a few times along the table axis; both systems see each
move as a step in the axial position (VTS: the marker's z at 25 fps; SPECT: the z of the
counts). The time of a step is its **mid-crossing**: when the position is half-way between
its level before and its level after. Both systems should agree on it.

* :func:`find_steps` — candidate steps: on a regular grid (``grid_s``) the difference of the
  medians of the samples in the ``window_s`` after and before; runs above a threshold
  (``min_step_mm``, or 8 noise SDs of that difference, whichever is larger) give one step
  each, at the middle of the run's plateau (within 90 % of its extremum). Medians ignore
  single outliers; a side with too few samples (dead time, a camera gap) gives no
  difference there. Coarse: the grid's resolution.
* :func:`fit_step` — the precise time: a least-squares fit of ``a + b·Φ((t − t0)/s)`` (Φ the
  normal CDF: a smooth step of width ``s``) to the **raw** samples in a window around the
  candidate — the VTS positions frame by frame, or every SPECT event's z (thousands of
  events; better than interpolating between 50–100 ms bin centres: bench/sync_edge_timing.py).
  ``t0`` is the fitted mid-crossing; for any move symmetric in time (a smooth start and stop)
  it is the true mid-crossing whatever the shape. A soft-L1 loss keeps scattered counts
  (background, blur tails) from pulling it. Its standard error comes from the Jacobian.
* :func:`match_events` — pairs the two systems' steps by time (nearest, within ``max_dt_s``,
  same direction) and leaves the rest as seen by one system only.

Units: seconds on whatever clock the caller gives (host UTC epoch s in the sync analysis),
positions in mm.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.special import ndtr

__all__ = ["StepCandidate", "StepFit", "find_steps", "fit_step", "mid_crossing", "match_events", "robust_sd"]


@dataclass(frozen=True)
class StepCandidate:
    """A step found by :func:`find_steps`: coarse time (s) and size (mm, after − before)."""

    t: float
    step_mm: float


@dataclass(frozen=True)
class StepFit:
    """A step's fitted edge. ``t_mid``: mid-crossing (s); ``t_err_s``: its standard error;
    ``width_s``: the edge's SD (a 0.3 s smooth move gives about 0.06 s); levels in mm."""

    t_mid: float
    t_err_s: float
    step_mm: float
    z_before: float
    z_after: float
    width_s: float
    n: int
    rms_mm: float
    method: str

    def to_json(self) -> dict:
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in asdict(self).items()}


def robust_sd(x) -> float:
    """1.4826 × the median absolute deviation of the finite values (nan when none)."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return math.nan
    return 1.4826 * float(np.median(np.abs(x - np.median(x))))


def _side_medians(t, z, grid, window_s, min_n):
    """Median of z in (g − W, g] and in (g, g + W] for every grid time g (nan: too few)."""
    lo = np.searchsorted(t, grid - window_s, side="right")
    mid = np.searchsorted(t, grid, side="right")
    hi = np.searchsorted(t, grid + window_s, side="right")
    left = np.full(grid.size, np.nan)
    right = np.full(grid.size, np.nan)
    for i in range(grid.size):
        if mid[i] - lo[i] >= min_n and hi[i] - mid[i] >= min_n:
            left[i] = np.median(z[lo[i] : mid[i]])
            right[i] = np.median(z[mid[i] : hi[i]])
    return left, right


def find_steps(
    t,
    z,
    *,
    window_s: float = 0.5,
    grid_s: float = 0.02,
    min_step_mm: float = 4.0,
    min_separation_s: float = 1.0,
    min_fill: float = 0.5,
) -> list[StepCandidate]:
    """Steps in a trace ``z(t)`` (s, mm; NaN samples ignored), in time order.

    A grid time counts only when both sides hold at least ``min_fill`` of the samples the
    trace's median spacing would put there (at least 3). Steps closer than
    ``min_separation_s`` merge (the larger wins)."""
    t = np.asarray(t, float)
    z = np.asarray(z, float)
    ok = np.isfinite(t) & np.isfinite(z)
    t, z = t[ok], z[ok]
    if t.size < 8:
        return []
    order = np.argsort(t, kind="stable")
    t, z = t[order], z[order]
    dt = float(np.median(np.diff(t))) or grid_s
    min_n = max(3, int(min_fill * window_s / max(dt, 1e-9)))
    grid = np.arange(t[0] + window_s, t[-1] - window_s, grid_s)
    if grid.size == 0:
        return []
    left, right = _side_medians(t, z, grid, window_s, min_n)
    d = right - left
    # the noise of d: the samples' own noise (from successive differences) through two medians
    sample_sd = robust_sd(np.diff(z)) / math.sqrt(2.0)
    d_sd = 1.2533 * sample_sd * math.sqrt(2.0 / min_n) if math.isfinite(sample_sd) else 0.0
    thr = max(min_step_mm, 8.0 * d_sd)
    above = np.isfinite(d) & (np.abs(d) > thr)
    sign = np.sign(np.where(above, d, 0.0))
    cands: list[StepCandidate] = []
    i = 0
    while i < grid.size:
        if not above[i]:
            i += 1
            continue
        j = i
        while j + 1 < grid.size and above[j + 1] and sign[j + 1] == sign[i]:
            j += 1
        seg = np.abs(d[i : j + 1])
        top = seg >= 0.9 * seg.max()  # the plateau of the difference: centred on the step
        cands.append(StepCandidate(float(np.mean(grid[i : j + 1][top])), float(d[i + int(np.argmax(seg))])))
        i = j + 1
    merged: list[StepCandidate] = []
    for c in cands:
        if merged and c.t - merged[-1].t < min_separation_s:
            if abs(c.step_mm) > abs(merged[-1].step_mm):
                merged[-1] = c
            continue
        merged.append(c)
    return merged


def mid_crossing(t, z, t_guess: float, z_before: float, z_after: float, half_window_s: float = 0.5) -> float:
    """Where ``z`` first crosses half-way between the two levels near ``t_guess``, linearly
    interpolated between the two samples around the crossing (nan when it does not)."""
    t = np.asarray(t, float)
    z = np.asarray(z, float)
    sel = np.isfinite(z) & (np.abs(t - t_guess) <= half_window_s)
    t, z = t[sel], z[sel]
    if t.size < 2:
        return math.nan
    half = 0.5 * (z_before + z_after)
    s = np.sign(z_after - z_before) * (z - half)
    up = np.flatnonzero((s[:-1] < 0) & (s[1:] >= 0))
    if up.size == 0:
        return math.nan
    k = up[np.argmin(np.abs(t[up] - t_guess))]
    f = -s[k] / (s[k + 1] - s[k])
    return float(t[k] + f * (t[k + 1] - t[k]))


def fit_step(
    t,
    z,
    t_guess: float,
    *,
    half_window_s: float = 0.8,
    noise_mm: float | None = None,
    min_width_s: float = 0.002,
    max_width_s: float = 0.4,
    method: str = "",
) -> StepFit:
    """Fit ``a + b·Φ((t − t0)/s)`` to the samples within ``half_window_s`` of ``t_guess``.

    ``noise_mm``: the samples' SD (sets the soft-L1 loss's scale; default from the data).
    Raises ValueError with fewer than 8 samples, or samples on one side only."""
    t = np.asarray(t, float)
    z = np.asarray(z, float)
    sel = np.isfinite(t) & np.isfinite(z) & (np.abs(t - t_guess) <= half_window_s)
    tt, zz = t[sel] - t_guess, z[sel]
    if tt.size < 8 or (tt < 0).sum() < 3 or (tt > 0).sum() < 3:
        raise ValueError(f"too few samples around {t_guess:.3f} s to fit a step")
    before = (
        float(np.median(zz[tt < -0.25 * half_window_s]))
        if (tt < -0.25 * half_window_s).sum() >= 3
        else float(np.median(zz[tt < 0]))
    )
    after = (
        float(np.median(zz[tt > 0.25 * half_window_s]))
        if (tt > 0.25 * half_window_s).sum() >= 3
        else float(np.median(zz[tt > 0]))
    )
    scale = noise_mm if noise_mm and noise_mm > 0 else max(robust_sd(np.diff(zz)) / math.sqrt(2.0), 1e-3)

    def model(p, x):
        a, b, t0, s = p
        return a + b * ndtr((x - t0) / s)

    def resid(p):
        return model(p, tt) - zz

    p0 = np.array([before, after - before, 0.0, 0.06])
    lo = [-np.inf, -np.inf, -half_window_s, min_width_s]
    hi = [np.inf, np.inf, half_window_s, max_width_s]
    res = least_squares(
        resid,
        p0,
        bounds=(lo, hi),
        loss="soft_l1",
        f_scale=2.0 * scale,
        x_scale=[scale, max(abs(p0[1]), scale), 0.01, 0.01],
    )
    a, b, t0, s = res.x
    r = resid(res.x)
    rms = float(np.sqrt(np.mean(r**2)))
    # standard error of t0: the Gauss-Newton covariance with a robust residual scale
    J = res.jac
    try:
        cov = np.linalg.inv(J.T @ J) * (1.4826 * float(np.median(np.abs(r)))) ** 2
        err = float(math.sqrt(max(cov[2, 2], 0.0)))
    except np.linalg.LinAlgError:
        err = math.nan
    return StepFit(
        t_mid=float(t_guess + t0),
        t_err_s=err,
        step_mm=float(b),
        z_before=float(a),
        z_after=float(a + b),
        width_s=float(s),
        n=int(tt.size),
        rms_mm=rms,
        method=method or "edge fit (normal-CDF step, soft-L1)",
    )


def match_events(t_a, step_a, t_b, step_b, max_dt_s: float = 0.5) -> list[tuple[int | None, int | None]]:
    """Pairs ``(i, j)`` of events of a and b (times s, steps mm): each of a with the nearest of
    b within ``max_dt_s`` and with a step of the same sign, one-to-one (closest pairs first);
    the rest as ``(i, None)`` / ``(None, j)``. Sorted by time."""
    t_a, t_b = np.asarray(t_a, float), np.asarray(t_b, float)
    cand = []
    for i in range(t_a.size):
        for j in range(t_b.size):
            d = abs(t_a[i] - t_b[j])
            if d <= max_dt_s and np.sign(step_a[i]) == np.sign(step_b[j]):
                cand.append((d, i, j))
    used_a: set[int] = set()
    used_b: set[int] = set()
    pairs: list[tuple[int | None, int | None]] = []
    for _, i, j in sorted(cand):
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    pairs += [(i, None) for i in range(t_a.size) if i not in used_a]
    pairs += [(None, j) for j in range(t_b.size) if j not in used_b]

    def when(p):
        i, j = p
        return t_a[i] if i is not None else t_b[j]

    return sorted(pairs, key=when)
