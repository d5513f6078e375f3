"""The sync check's SPECT half: what the gating signal and the events of a list-mode say.

Pure functions on a :class:`~vts_hw.spect.listmode.ListMode` (list-mode time: seconds since the
acquisition start on the SPECT's clock):

* :func:`find_gate_edges` — the square wave's rising and falling edges in the recorded gating
  voltage: levels by two-cluster medians, states with hysteresis (25 %/75 % of the swing, so
  noise never makes an edge), each edge timed where the voltage crosses the mid level,
  linearly interpolated between the two samples around it (sub-sample);
* :func:`fit_spect_clock` — the edges against the known square wave: the trigger starts the
  wave with a rising edge on the same timer tick as the SPECT start pulse (a ``fire``), and its
  period is known in host seconds. Rising edge *k* (k = 0 at the start pulse) is at list-mode
  time ``t_wave + k·P·(1 + skew)``, falling edges ``duty·P·(1 + skew)`` later. A least-squares
  fit of all edges gives ``t_wave`` (the start pulse on the list-mode clock), the SPECT
  clock's skew against the trigger and the duty. With the trigger's host time of that first
  edge (``fire_host``, from the trigger log) list-mode time maps to host time;
* **what can be measured**: the acquisition starts some time after its start pulse, so the
  start edge itself is not in the file; edges are counted from the first recorded one, whose
  index is ``edges_before_start`` (default 1: the start delay is taken to be shorter than one
  period of the square wave — use a period longer than the longest start delay, 1 s by
  default). The start delay is then ``−t_wave`` (in host seconds ``−t_wave/(1+skew)``) and is
  known modulo one period only. A first rising edge more than 1.5 periods into the recording
  means the wave started after the acquisition (no start pulse, e.g. a function generator
  switched on later): then that edge is the start edge and the delay is negative;
* :func:`dead_time_from_events` — the intervals without events (heads rotating);
* :func:`axial_centre_of_mass` — the mean axial position of the counts per time bin;
* :func:`analyze_gating` — all of the above in one result.

The trigger's side (the wave's period and the host time of its first edge) comes from the
session's ``trigger.csv``, read by :func:`vts_hw.recording.trigger_wave.wave_from_trigger_log`
from the neutral rows every backend writes (docs/trigger-log-format.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from vts_hw.errors import DataError
from vts_hw.spect.listmode.base import GATE_TRANSITIONS, ListMode

__all__ = [
    "GateEdges",
    "SpectClock",
    "GatingResult",
    "find_gate_edges",
    "fit_spect_clock",
    "dead_time_from_events",
    "axial_centre_of_mass",
    "analyze_gating",
]


# ------------------------------------------------------------------------------------ edges


@dataclass(frozen=True)
class GateEdges:
    """Edges of the gating square wave, list-mode seconds; levels in volts."""

    rising: np.ndarray
    falling: np.ndarray
    low_v: float
    high_v: float
    noise_v: float  # robust SD of the low level

    @property
    def mid_v(self) -> float:
        return 0.5 * (self.low_v + self.high_v)


def _two_levels(v: np.ndarray) -> tuple[float, float, float]:
    """Low and high levels (medians of two clusters) and the noise (MAD of the low one)."""
    lo, hi = float(np.min(v)), float(np.max(v))
    for _ in range(20):
        mid = 0.5 * (lo + hi)
        below, above = v[v < mid], v[v >= mid]
        if below.size == 0 or above.size == 0:
            break
        new = float(np.median(below)), float(np.median(above))
        if new == (lo, hi):
            break
        lo, hi = new
    low = v[v < 0.5 * (lo + hi)]
    noise = 1.4826 * float(np.median(np.abs(low - lo))) if low.size else 0.0
    return lo, hi, noise


def find_gate_edges(lm: ListMode, *, hysteresis: float = 0.25, min_swing_v: float = 0.2) -> GateEdges:
    """Rising and falling edges of the gating signal (list-mode s).

    Sampled voltage: a sample is "high" above ``low + (0.5 + hysteresis)·swing``, "low" below
    ``low + (0.5 − hysteresis)·swing``, else it keeps the state before it; at each change of
    state the edge is where the voltage crosses the mid level, interpolated between the two
    samples around the crossing. Gate transitions (a format that records level changes): the
    times of the changes. No square wave (swing below ``min_swing_v`` or below 10 noise SDs):
    empty edges.
    """
    t = np.asarray(lm.gate_t, dtype=np.float64)
    v = np.asarray(lm.gate_v, dtype=np.float64)
    empty = np.empty(0)
    if v.size < 2:
        return GateEdges(empty, empty, math.nan, math.nan, math.nan)
    low, high, noise = _two_levels(v)
    swing = high - low
    if not swing > max(min_swing_v, 10 * noise):
        return GateEdges(empty, empty, low, high, noise)
    mid = 0.5 * (low + high)
    if lm.gate_kind == GATE_TRANSITIONS:
        up = v >= mid
        change = np.flatnonzero(up[1:] != up[:-1]) + 1
        return GateEdges(t[change[up[change]]], t[change[~up[change]]], low, high, noise)
    upper, lower = low + (0.5 + hysteresis) * swing, low + (0.5 - hysteresis) * swing
    state = np.where(v > upper, 1, np.where(v < lower, 0, -1))
    decided = np.where(state >= 0, np.arange(v.size), 0)
    np.maximum.accumulate(decided, out=decided)
    state = state[decided]  # undecided samples keep the last decided state
    if state[0] < 0:  # undecided from the first sample: the first decision
        first = np.flatnonzero(state >= 0)
        if first.size == 0:
            return GateEdges(empty, empty, low, high, noise)
        state[: first[0]] = state[first[0]]
    change = np.flatnonzero(state[1:] != state[:-1]) + 1  # first sample in the new state
    above = v >= mid
    cross = np.flatnonzero(above[1:] != above[:-1]) + 1  # v[k-1], v[k] on either side

    def timed(kinds_up: bool) -> np.ndarray:
        j = change[(state[change] == 1) == kinds_up]
        c = cross[above[cross] == kinds_up]
        if j.size == 0 or c.size == 0:
            return empty
        i = np.searchsorted(c, j, side="right") - 1  # the last crossing at or before j
        ok = i >= 0
        k = c[i[ok]]
        frac = (mid - v[k - 1]) / (v[k] - v[k - 1])
        return t[k - 1] + frac * (t[k] - t[k - 1])

    return GateEdges(timed(True), timed(False), low, high, noise)


# ------------------------------------------------------------------------------ clock fit


@dataclass(frozen=True)
class SpectClock:
    """List-mode time against the trigger's square wave.

    ``to_trigger(t) = (t − t_wave) / (1 + skew)``: host seconds since the wave's first rising
    edge (the start pulse). With ``fire_host`` (host UTC epoch s of that edge) ``to_host``
    gives host time. ``skew`` is SPECT seconds per trigger second − 1 (0 when the period was
    not given: then it cannot be told from the edges alone).
    """

    t_wave: float  # list-mode time of the start edge (negative: before t = 0)
    skew: float
    period_spect: float  # the period as the list-mode clock measured it, s
    duty: float  # nan without falling edges
    first_index: int  # index of the first recorded rising edge (start edge = 0)
    n_edges: int  # rising + falling edges used
    residual_s: float  # RMS of the fit
    max_residual_s: float
    fire_host: float | None = None
    period_s: float | None = None  # the known period (host s), if given

    @property
    def skew_ppm(self) -> float:
        return self.skew * 1e6

    @property
    def start_delay_s(self) -> float:
        """Acquisition start − start pulse, host seconds (modulo one period, see the module)."""
        return -self.t_wave / (1.0 + self.skew)

    def to_trigger(self, t):
        return (np.asarray(t, dtype=np.float64) - self.t_wave) / (1.0 + self.skew)

    def to_host(self, t):
        if self.fire_host is None:
            raise ValueError("no host time of the trigger's first edge (fire_host) was given")
        return self.fire_host + self.to_trigger(t)

    def to_list(self, host_t):
        if self.fire_host is None:
            raise ValueError("no host time of the trigger's first edge (fire_host) was given")
        return self.t_wave + (np.asarray(host_t, dtype=np.float64) - self.fire_host) * (1.0 + self.skew)


def fit_spect_clock(
    rising,
    falling=(),
    *,
    period_s: float | None = None,
    edges_before_start: int | None = None,
    fire_host: float | None = None,
    where: str = "list-mode",
) -> SpectClock:
    """Fit the square wave's edges (list-mode s) to ``t_wave + (k + duty·is_falling)·β``.

    ``period_s``: the square wave's period in host seconds (from the trigger's settings);
    without it the period is measured and the skew set to 0. ``edges_before_start``: how many
    rising edges the trigger made before the acquisition started, counting the start edge
    (default 1, i.e. a start delay shorter than one period). DataError (naming ``where``)
    with fewer than 2 rising edges or edges that are not one steady square wave.
    """
    r = np.sort(np.asarray(rising, dtype=np.float64))
    f = np.sort(np.asarray(falling, dtype=np.float64))
    if r.size < 2:
        raise DataError(
            f"{where}: {r.size} rising edge(s) in the gating signal, need at least 2 to time the square wave"
        )
    n0 = 1 if edges_before_start is None else int(edges_before_start)
    if n0 < 0:
        raise ValueError("edges_before_start must be >= 0")
    guess = float(period_s) if period_s else float(np.median(np.diff(r)))
    if not guess > 0:
        raise DataError(f"{where}: the gating edges do not repeat (period {guess!r} s)")
    k = np.round((r - r[0]) / guess)
    # refine the period over the whole run before assigning falling edges (a skew of tens of
    # ppm is far below half a period, so rounding with the nominal period is safe)
    beta, alpha = np.polyfit(k, r, 1) if np.ptp(k) > 0 else (guess, r[0])
    k = np.round((r - alpha) / beta)
    kf = np.floor((f - alpha) / beta) if f.size else np.empty(0)
    x = np.concatenate([k, kf])
    y = np.concatenate([r, f])
    isf = np.concatenate([np.zeros(r.size), np.ones(f.size)])
    cols = [np.ones_like(x), x] + ([isf] if f.size else [])
    A = np.column_stack(cols)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    res = y - A @ coef
    alpha, beta = float(coef[0]), float(coef[1])
    duty = float(coef[2] / beta) if f.size else math.nan
    rms = float(np.sqrt(np.mean(res**2)))
    worst = float(np.max(np.abs(res)))
    if worst > 0.25 * beta or (f.size and not 0 < duty < 1):
        raise DataError(
            f"{where}: the gating edges are not one steady square wave (worst edge "
            f"{worst * 1e3:.1f} ms off a period of {beta * 1e3:.1f} ms)"
        )
    # k counts the recorded rising edges from the first one (k = 0 there, up to rounding),
    # which is edge n0 of the wave; the start edge is n0 periods before it
    k_first = float(np.round((r[0] - alpha) / beta))
    t_wave = alpha + (k_first - n0) * beta
    skew = beta / float(period_s) - 1.0 if period_s else 0.0
    return SpectClock(
        t_wave=t_wave,
        skew=skew,
        period_spect=beta,
        duty=duty,
        first_index=n0,
        n_edges=int(y.size),
        residual_s=rms,
        max_residual_s=worst,
        fire_host=fire_host,
        period_s=float(period_s) if period_s else None,
    )


# ------------------------------------------------------------------------------ dead time


def dead_time_from_events(lm: ListMode, min_gap_s: float | None = None) -> np.ndarray:
    """Intervals without events, ``(k, 2)`` [start, end) list-mode s: the gaps between
    consecutive events (and at the start and the end) longer than ``min_gap_s`` (default
    ``max(0.2 s, 30 / event rate)``, far beyond any gap of a Poisson stream)."""
    t = np.asarray(lm.t, dtype=np.float64)
    if t.size == 0:
        return np.array([[0.0, lm.duration_s]]) if lm.duration_s > 0 else np.empty((0, 2))
    if min_gap_s is None:
        live = max(lm.duration_s, float(t[-1] - t[0]), 1e-9)
        min_gap_s = max(0.2, 30.0 / (t.size / live))
    edges = np.concatenate([[0.0], t, [max(lm.duration_s, float(t[-1]))]])
    gaps = np.diff(edges)
    i = np.flatnonzero(gaps > min_gap_s)
    return np.column_stack([edges[i], edges[i + 1]]) if i.size else np.empty((0, 2))


def _in_intervals(x: np.ndarray, intervals: np.ndarray) -> np.ndarray:
    if intervals is None or len(intervals) == 0:
        return np.zeros(x.shape, bool)
    iv = np.asarray(intervals, dtype=np.float64)
    iv = iv[np.argsort(iv[:, 0])]
    i = np.searchsorted(iv[:, 0], x, side="right") - 1
    ok = i >= 0
    out = np.zeros(x.shape, bool)
    out[ok] = x[ok] < iv[i[ok], 1]
    return out


def axial_centre_of_mass(lm: ListMode, bin_s: float = 0.1, dead=None):
    """Mean axial position ``z`` (mm) of the counts in bins of ``bin_s`` list-mode seconds.

    Returns ``(t, z)``: the bin centres (list-mode s) and the mean z per bin, ``nan`` where
    there are no counts or the bin's centre is in dead time (``dead`` intervals if given, else
    the file's own records, else :func:`dead_time_from_events`). Map ``t`` to host time with
    :meth:`SpectClock.to_host`.
    """
    if not bin_s > 0:
        raise ValueError("bin_s must be positive")
    n = max(1, int(math.ceil(lm.duration_s / bin_s - 1e-9)))
    idx = np.floor(np.asarray(lm.t, np.float64) / bin_s).astype(np.int64)
    keep = (idx >= 0) & (idx < n)
    counts = np.bincount(idx[keep], minlength=n)
    sums = np.bincount(idx[keep], weights=np.asarray(lm.z, np.float64)[keep], minlength=n)
    centres = (np.arange(n) + 0.5) * bin_s
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(counts > 0, sums / np.maximum(counts, 1), np.nan)
    if dead is None:
        dead = lm.dead if lm.dead is not None else dead_time_from_events(lm)
    z[_in_intervals(centres, dead)] = np.nan
    return centres, z


# ------------------------------------------------------------------------------- together


@dataclass
class GatingResult:
    """What the gating signal and the events of one list-mode say (list-mode s unless named)."""

    edges: GateEdges
    clock: SpectClock
    dead: np.ndarray  # from the events
    dead_recorded: np.ndarray | None  # as the file records it (None: it does not)
    start_time: float  # the SPECT wall clock at t = 0, as the header says
    problems: list[str] = field(default_factory=list)

    @property
    def start_delay_s(self) -> float:
        """SPECT acquisition start − its start pulse (the wave's first edge), host seconds."""
        return self.clock.start_delay_s

    @property
    def clock_offset_s(self) -> float | None:
        """The SPECT's wall clock − host time at the acquisition start (needs fire_host)."""
        if self.clock.fire_host is None:
            return None
        return self.start_time - float(self.clock.to_host(0.0))

    def to_json(self) -> dict:
        """A JSON-ready summary (non-finite numbers as null)."""
        c = self.clock
        return _finite(
            {
                "start_delay_s": self.start_delay_s,
                "start_delay_modulo_s": c.period_spect,
                "edges_before_start": c.first_index,
                "rising_edges": int(self.edges.rising.size),
                "falling_edges": int(self.edges.falling.size),
                "gate_low_v": self.edges.low_v,
                "gate_high_v": self.edges.high_v,
                "gate_noise_v": self.edges.noise_v,
                "period_spect_s": c.period_spect,
                "period_s": c.period_s,
                "duty": c.duty,
                "skew_ppm": c.skew_ppm,
                "t_wave_s": c.t_wave,
                "fire_host": c.fire_host,
                "clock_offset_s": self.clock_offset_s,
                "spect_start_time": self.start_time,
                "fit_rms_s": c.residual_s,
                "fit_max_s": c.max_residual_s,
                "dead_time": self.dead.tolist(),
                "dead_time_recorded": None if self.dead_recorded is None else self.dead_recorded.tolist(),
                "problems": list(self.problems),
            }
        )


def _finite(x):
    """``x`` with every non-finite float (nan, inf) replaced by None, recursively."""
    if isinstance(x, dict):
        return {k: _finite(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_finite(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def analyze_gating(
    lm: ListMode,
    *,
    period_s: float | None = None,
    fire_host: float | None = None,
    edges_before_start: int | None = None,
    min_gap_s: float | None = None,
) -> GatingResult:
    """Edges, SPECT clock (start delay, skew, host mapping) and dead time of one list-mode.

    ``period_s`` (host s) and ``fire_host`` (host epoch s of the wave's first rising edge)
    come from the trigger: :func:`vts_hw.recording.trigger_wave.wave_from_trigger_log` reads
    both from a session's ``trigger.csv``. Raises DataError (naming the file) when the gating signal has no usable
    square wave.
    """
    where = lm.where()
    edges = find_gate_edges(lm)
    if edges.rising.size < 2:
        raise DataError(
            f"{where}: no square wave in the gating signal ({edges.rising.size} rising "
            f"edges; levels {edges.low_v:.3g} to {edges.high_v:.3g} V)"
        )
    problems = []
    if edges_before_start is None and lm.gate_kind != GATE_TRANSITIONS and lm.gate_t.size:
        # a running wave shows a rising edge within one period of the first sample: a first
        # edge much later means the wave started after the acquisition (edge 0 is recorded)
        spacing = float(np.median(np.diff(edges.rising)))
        late = edges.rising[0] - float(lm.gate_t[0])
        if late > 1.5 * (period_s or spacing):
            edges_before_start = 0
            problems.append(
                f"the square wave started {late:.3f} s after the acquisition: its "
                f"first edge is in the file and the start delay is negative"
            )
    clock = fit_spect_clock(
        edges.rising,
        edges.falling,
        period_s=period_s,
        edges_before_start=edges_before_start,
        fire_host=fire_host,
        where=where,
    )
    if period_s is None:
        problems.append("no square-wave period given: the SPECT clock's skew is not measured")
    if fire_host is None:
        problems.append("no host time of the trigger: list-mode time maps to trigger time only")
    if period_s is not None and abs(clock.skew) > 1e-3:
        problems.append(
            f"the SPECT clock runs {clock.skew_ppm:+.0f} ppm against the trigger: is the period {period_s} s right?"
        )
    dead = dead_time_from_events(lm, min_gap_s)
    return GatingResult(edges, clock, dead, lm.dead, lm.start_time, problems)
