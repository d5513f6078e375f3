"""Has a camera's clock settled after it started? The clock half of the commissioning's warm-up.

A camera's clock runs at a rate against the host's (its skew, ppm) that is not yet settled in
the minutes after it starts (the quartz warms with the board, the NTP client's frequency
correction hunts): its offset to the host then drifts at a changing rate, and a scan's time
line-up, which fits one straight line of camera time to host time per recording
(vts_hw/timing/camera_clock.py), is worse for it. At each sample of the picture
(procedures/warmup.py) the step reads every camera's clock offset as the daily QA's clock check
does (``cam.clock_offset()``: ``time.cgi``, 1 ms resolution, the midpoint of the quickest of 5
round trips; 10 ms JPEG stamps on old firmware). Over the same window:

* the rate (ppm): a straight line through the offsets (its slope, signed);
* how the rate changes (ppm/min, the judged figure): a parabola through them, with
  :func:`procedures.warmup.fit_rate` (``order=2``): the same fit as the picture's px/min, one
  derivative higher, and the same way to the time constant (a cubic: the change slowing,
  significant at 3 standard errors) and to the wait (``settle_wait_min``);
* judged against the ``warmup_clock_change_ppm_min`` window (default OK ≤ 5 ppm/min), only
  where the window can tell: a change whose standard error is over half the limit (too few
  samples, too short a window, readings too coarse: a clock fast virtual time reads across long
  round trips) is *not known* (said, TOLERANCE, never waited for: waiting the same window again
  would not tell either).

docs/decisions/0072-warm-up-settling.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from vts_hw.procedures.warmup import RateFit, fit_rate
from vts_hw.tolerance import State

__all__ = ["ClockReading", "ClockWatch", "ClockJudgement", "judge_clock", "PPM_PER_S_MIN"]

#: offsets in s against time in minutes: d/dt (s/min) * 1e6 / 60 is ppm; d2/dt2 (s/min2) the same is ppm/min
PPM_PER_S_MIN = 1e6 / 60.0
# time.cgi answers in whole milliseconds: a reading's own noise is at least that resolution's
# (uniform: 1 ms / sqrt(12)); 4 readings can fit a parabola exactly, and a change of the rate
# judged "0.00 ± 0.00 ppm/min" from them is not known (seen under load)
READING_SD_S = 0.001 / math.sqrt(12.0)


@dataclass
class ClockReading:
    t: float  # host time of the reading (epoch s)
    offset_s: float  # camera minus host (NaN: not read)
    uncertainty_s: float
    method: str


@dataclass
class ClockWatch:
    """One camera's clock readings, one per sample of the warm-up step."""

    cam: object
    readings: list[ClockReading] = field(default_factory=list)
    problem: str | None = None  # why there is no clock to read (said once)

    def read(self) -> ClockReading:
        off = None
        read = getattr(self.cam, "clock_offset", None)
        if read is not None and self.problem is None:
            off = read()
            if getattr(off, "source", "camera") != "camera":
                self.problem, off = f"its frames carry no clock of its own ({off.method})", None
        elif read is None:
            self.problem = "it does not tell its clock"
        r = (
            ClockReading(off.host_time, off.offset_s, off.uncertainty_s, off.method)
            if off is not None
            else ClockReading(math.nan, math.nan, math.nan, "none")
        )
        self.readings.append(r)
        return r

    def fits(self, last: int) -> tuple[RateFit, RateFit, float | None]:
        """(the rate's fit, ppm; its change's fit, ppm/min; the signed rate, ppm) over the last readings."""
        got = [r for r in self.readings[-last:] if math.isfinite(r.offset_s)]
        t = [r.t for r in got]
        o = [[r.offset_s] for r in got]
        rate = fit_rate(t, o, order=1, scale=PPM_PER_S_MIN, sigma=READING_SD_S)
        change = fit_rate(t, o, order=2, scale=PPM_PER_S_MIN, sigma=READING_SD_S)
        return rate, change, rate.signed


@dataclass(frozen=True)
class ClockJudgement:
    state: State
    known: bool
    why: str  # what is said: the figures, or why not known

    @property
    def settled(self) -> bool:
        return self.known and self.state == State.OK


def change_text(f: RateFit) -> str:
    return f"{f.rate:.2f} ± {f.se:.2f} ppm/min over {f.window_min:.1f} min"


def judge_clock(change: RateFit, window, limit: float, problem: str | None = None) -> ClockJudgement:
    """The clock's state: its change against ``window`` where the window can tell it (see the module)."""
    if problem:
        return ClockJudgement(State.TOLERANCE, False, f"clock not known: {problem}")
    if change.rate is None or change.se is None:  # set together
        return ClockJudgement(
            State.TOLERANCE,
            False,
            f"clock's change not known: {change.n} reading(s) in the window, a parabola needs 4 or more",
        )
    if not change.se <= limit / 2:
        return ClockJudgement(
            State.TOLERANCE,
            False,
            f"clock's change not known: {change_text(change)}, the window "
            f"cannot tell it from {limit:g} ppm/min (more samples, or a "
            f"longer interval, tell it)",
        )
    return ClockJudgement(window.state(change.rate), True, f"clock's rate changing {change_text(change)}")
