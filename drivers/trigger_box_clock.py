"""The trigger box's clock mapped to host time: ``TIME?`` round trips and the fit over them.

A round trip is (host time just before the write, host time the reply was complete, device
µs). The fit (:func:`fit_clock`) is weighted least squares of each round trip's midpoint
(moved by the line's asymmetry, :func:`wire_skew`) on device time, weight 1/rtt² (the round
trip no shorter than the line allows, :attr:`RoundTrip.spread`), then once
more without outliers (docs/decisions/0011-trigger-box-driver.md, "Clock mapping"). Pure
computation, and :class:`BoxClock`, the part of the driver that samples the round trips and
keeps the history (:meth:`~BoxClock.clock_mapping`; mixed into
:class:`~vts_hw.drivers.trigger_box.TriggerBox`).
"""

from __future__ import annotations

import math
import threading
from abc import abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from vts_hw.drivers.trigger import CLOCK, EDGES, ClockMapping, TriggerBase, TriggerError
from vts_hw.drivers.trigger_box_protocol import uint

MAX_ROUND_TRIPS_KEPT = 2000  # clock-mapping history (about 100 calls of 20)
OUTSIDE_SPREAD = 2.0  # a sample this many half spreads off the fitted line is dropped


@dataclass(frozen=True)
class RoundTrip:
    """One ``TIME?`` exchange: host time just before the write and just after the reply.

    ``skew`` moves the midpoint to where the box most likely read its clock: it reads it once
    the whole command has arrived and before the first byte of its reply leaves, so with a
    6-byte command and an 11-byte reply on a 115200-baud line the reading is
    (11 - 6) * 10 / 115200 / 2 = 0.2 ms before the midpoint: skew = (wire_in - wire_out) / 2.
    """

    host_sent: float
    host_received: float
    device_us: int
    skew: float = 0.0
    wire: float = 0.0

    @property
    def rtt(self) -> float:
        return self.host_received - self.host_sent

    @property
    def spread(self) -> float:
        """How far the midpoint may be off, doubled: the round trip, but never less than the
        line's own time for the two lines (``wire``). A round trip shorter than the line
        allows means the stamps are not where the bytes were (a host that stamped late, an
        emulated box catching up): such a sample is not the most certain one."""
        return max(self.rtt, self.wire)

    @property
    def host_mid(self) -> float:
        return 0.5 * (self.host_sent + self.host_received) + self.skew


def wire_skew(cmd: str, reply: str, baudrate: float | None, bits_per_byte: int = 10) -> float:
    """(time on the wire of the command line - of the reply line) / 2, in seconds (8N1: 10 bits
    a byte); 0 when the baud rate is unknown."""
    if not baudrate:
        return 0.0
    return (len(cmd) + 1 - (len(reply) + 1)) * bits_per_byte / baudrate / 2


def wire_time(cmd: str, reply: str, baudrate: float | None, bits_per_byte: int = 10) -> float:
    """The least time a round trip takes on the line: the command and the reply lines on the
    wire (8N1: 10 bits a byte); 0 when the baud rate is unknown."""
    if not baudrate:
        return 0.0
    return (len(cmd) + 1 + len(reply) + 1) * bits_per_byte / baudrate


def clock_jumped(before: RoundTrip, after: RoundTrip) -> bool:
    """The box's clock did not advance with the host's between two samples (to 1 %, far more
    than any resonator is off, plus 50 ms): it rebooted, or it is another box."""
    dh = after.host_mid - before.host_mid
    dd = (after.device_us - before.device_us) * 1e-6
    return dd < 0 or abs(dd - dh) > 0.01 * abs(dh) + 0.05


def best_round_trips(trips: Sequence[RoundTrip], keep: float = 0.5) -> list[RoundTrip]:
    """The ``keep`` fraction (at least 2, at most all) with the shortest round trips (their
    :attr:`~RoundTrip.spread`), in time order."""
    n = min(len(trips), max(2, math.ceil(keep * len(trips))))
    best = sorted(range(len(trips)), key=lambda i: trips[i].spread)[:n]
    return [trips[i] for i in sorted(best)]


def fit_clock(trips: Sequence[RoundTrip]) -> tuple[ClockMapping, float]:
    """Fit host_mid = ref_host + (device_us - ref_device_us) * 1e-6 * (1 + drift * 1e-6).

    Weighted least squares, weight 1/spread² (a round trip, never shorter than the line allows:
    the midpoint is off by at most half of it, so short round trips count most), then once more
    without samples whose residual is beyond 4 robust SDs (and beyond their own half spread),
    then, one at a time, without the sample farthest outside its own half spread from the line
    fitted without it (more than ``OUTSIDE_SPREAD`` of them). Differences are taken from the
    first sample in integers before any float arithmetic, so 64-bit device counts and epoch
    host times keep their microseconds. ``ref_device_us`` is the weighted centre of the samples
    (where the offset is best known). Returns the mapping and the drift's standard error in ppm
    (``inf`` when it cannot be estimated).
    """
    if len(trips) < 2:
        raise ValueError("a clock fit needs at least 2 round trips")
    d0 = trips[0].device_us
    h0 = trips[0].host_mid
    xs = [(t.device_us - d0) * 1e-6 for t in trips]
    ys = [t.host_mid - h0 for t in trips]
    spreads = [max(t.spread, 1e-7) for t in trips]
    use = [True] * len(trips)

    def solve(mask):
        w = [1.0 / r**2 if u else 0.0 for r, u in zip(spreads, mask)]
        sw = sum(w)
        xm = sum(wi * x for wi, x in zip(w, xs)) / sw
        ym = sum(wi * y for wi, y in zip(w, ys)) / sw
        sxx = sum(wi * (x - xm) ** 2 for wi, x in zip(w, xs))
        if sxx <= 0 or sum(mask) < 2:
            b = 1.0  # one device time only: offset alone, no drift
        else:
            b = sum(wi * (x - xm) * (y - ym) for wi, x, y in zip(w, xs, ys)) / sxx
        res = [y - (ym + b * (x - xm)) for x, y in zip(xs, ys)]
        return w, sw, xm, ym, sxx, b, res

    w, sw, xm, ym, sxx, b, res = solve(use)
    if len(trips) >= 6:
        kept = sorted(abs(r) for r in res)
        sigma = 1.4826 * kept[len(kept) // 2]
        mask = [abs(r) <= max(4 * sigma, sp / 2) for r, sp in zip(res, spreads)]
        if sum(mask) >= 3 and not all(mask):
            use = mask
            w, sw, xm, ym, sxx, b, res = solve(use)
    # the box read its clock inside each round trip: a sample whose midpoint lies well outside
    # its own half spread from the line the others give has stamps that are not where its
    # bytes were; drop the worst such sample and fit again (one bad sample with a short round
    # trip at an end tilts the whole fit towards itself, so that its own residual is small)
    while sum(use) > 3:
        # each residual as if its sample were left out of the fit (r / (1 - leverage))
        lev = [wi * (1.0 / sw + ((x - xm) ** 2 / sxx if sxx > 0 else 0.0)) for wi, x in zip(w, xs)]
        z = [abs(r) / max(1.0 - h, 1e-9) / (sp / 2) if u else 0.0 for r, h, sp, u in zip(res, lev, spreads, use)]
        worst = max(range(len(z)), key=z.__getitem__)
        if z[worst] <= OUTSIDE_SPREAD:
            break
        use = [u and i != worst for i, u in enumerate(use)]
        w, sw, xm, ym, sxx, b, res = solve(use)

    n = sum(use)
    ref_device_us = d0 + round(xm * 1e6)
    x_ref = (ref_device_us - d0) * 1e-6
    ref_host = h0 + ym + b * (x_ref - xm)
    used_res = [r for r, u in zip(res, use) if u]
    residual = math.sqrt(sum(r * r for r in used_res) / n)
    if sxx > 0 and n > 2:
        chi = sum(wi * r * r for wi, r in zip(w, res)) / (n - 2)
        drift_se = math.sqrt(chi / sxx) * 1e6
    else:
        drift_se = math.inf
    mapping = ClockMapping(
        ref_host=ref_host,
        ref_device_us=ref_device_us,
        drift_ppm=(b - 1.0) * 1e6,
        residual_s=residual,
        uncertainty_s=min(r for r, u in zip(spreads, use) if u) / 2,
        samples=n,
    )
    return mapping, drift_se


if TYPE_CHECKING:

    class TriggerBoxParts(TriggerBase):
        """What :class:`~vts_hw.drivers.trigger_box.TriggerBox` gives its mixins (BoxClock, BoxWatchdog),
        said once for the type checker, which alone sees it as their base."""

        port: str
        baudrate: int
        clock: Callable[[], float]
        sleep: Callable[[float], None]
        mapping: ClockMapping | None
        drift_se_ppm: float | None
        _lock: threading.RLock
        _serial: Any
        _batches: list[list[RoundTrip]]
        _logged_edges: tuple[int | None, int | None]
        _wave: tuple[float, float, str, float | None] | None
        _wave_first_us: int | None

        @property
        @abstractmethod
        def where(self) -> str: ...

        @abstractmethod
        def query(self, cmd: str) -> str: ...

        @abstractmethod
        def _exchange(self, cmd: str) -> tuple[str, float, float]: ...

        @abstractmethod
        def _command(self, cmd: str) -> None: ...

        @abstractmethod
        def _parse(self, cmd: str, reply: str, parse: Callable[[str], Any], what: str) -> Any: ...

        @abstractmethod
        def _log(self, kind: str, text: str, device_us: int | None = None, host_time: float | None = None) -> None: ...

        @abstractmethod
        def device_time_us(self) -> int: ...

        @abstractmethod
        def edges(self) -> tuple[int, int, int]: ...

    _Parts = TriggerBoxParts
else:
    _Parts = object


class BoxClock(_Parts):
    """The trigger box driver's clock: ``TIME?``, ``EDGES?`` and their mapping to host time (a
    mixin of :class:`~vts_hw.drivers.trigger_box.TriggerBox`, which provides ``query``,
    ``_exchange``, ``_parse``, ``_lock``, ``_log``, ``clock``, ``sleep``, ``where``, ``_serial``,
    ``baudrate``, ``_batches`` and ``_logged_edges``)."""

    def device_time_us(self) -> int:
        """``TIME?``: microseconds since the box booted."""
        return self._parse("TIME?", self.query("TIME?"), uint, "count of microseconds")

    def edges(self) -> tuple[int, int, int]:
        """``EDGES?``: (rising edges since the last start, device us of the first, of the last).

        A first or last edge not logged before is written to ``trigger.csv`` as an ``edge`` line
        with its device time, and its host time through :attr:`mapping` when one has been fitted
        (else the host time of the report, and the text says so).
        """
        self.require(EDGES)
        with self._lock:
            reply = self.query("EDGES?")
            parts = reply.split(",")
            if len(parts) != 3:
                raise TriggerError(f"{self.where} answered 'EDGES?' with {reply!r}, not '<count>,<first us>,<last us>'")
            n, first, last = (self._parse("EDGES?", p.strip(), uint, "count or time") for p in parts)
            if n:
                self._log_edges(n, first, last)
        return n, first, last

    def _log_edges(self, n: int, first: int, last: int) -> None:
        logged_first, logged_last = self._logged_edges
        m = self.mapping
        how = "host time mapped from the box clock" if m else "host time = when reported (no clock mapping)"
        if first != logged_first:
            self._log(
                "edge",
                f"first rising edge (1 of {n}); {how}",
                device_us=first,
                host_time=m.to_host(first) if m else None,
            )
        if last != logged_last and last != first:
            self._log(
                "edge",
                f"last rising edge ({n} of {n}); {how}",
                device_us=last,
                host_time=m.to_host(last) if m else None,
            )
        self._logged_edges = (first, last)

    def clock_mapping(
        self, samples: int = 20, *, over_s: float = 1.0, keep: float = 0.5, history: bool = True
    ) -> ClockMapping:
        """Map the box's microseconds to host time from ``samples`` ``TIME?`` round trips.

        The samples are spread evenly over ``over_s`` seconds; of each call's samples the
        ``keep`` fraction with the shortest round trips is used. With ``history`` the fit also
        uses the samples kept by earlier calls since the box's clock last went back (a reboot),
        so a mapping at the end of a session fits the drift over the whole session. The fit
        (:func:`fit_clock`) weights each sample by 1/spread²; the result is kept in
        :attr:`mapping`, used for the edge lines of the log, and logged as an ``event``.
        """
        self.require(CLOCK)
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
            raise ValueError(f"clock_mapping needs at least 2 samples, not {samples!r}")
        if not over_s >= 0 or not 0 < keep <= 1:
            raise ValueError(f"clock_mapping: over_s must be >= 0 and keep in (0, 1] (got {over_s!r}, {keep!r})")
        gap = over_s / (samples - 1)
        trips: list[RoundTrip] = []
        t_begin = self.clock()
        for i in range(samples):
            if i and gap > 0:
                wait = t_begin + i * gap - self.clock()
                if wait > 0:
                    self.sleep(wait)
            reply, sent, received = self._exchange("TIME?")
            device_us = self._parse("TIME?", reply, uint, "count of microseconds")
            if trips and device_us < trips[-1].device_us:
                raise TriggerError(
                    f"{self.where}: its clock went back from {trips[-1].device_us} "
                    f"to {device_us} us during the clock mapping (did it reboot?)"
                )
            baud = self._wire_baud()
            trips.append(
                RoundTrip(sent, received, device_us, wire_skew("TIME?", reply, baud), wire_time("TIME?", reply, baud))
            )
        kept = best_round_trips(trips, keep)
        with self._lock:
            if self._batches and clock_jumped(self._batches[-1][-1], kept[0]):
                self._log("event", "box clock jumped since the last clock mapping (reboot?): earlier samples dropped")
                self._batches.clear()
            if not history:
                self._batches.clear()
            self._batches.append(kept)
            while sum(len(b) for b in self._batches) > MAX_ROUND_TRIPS_KEPT and len(self._batches) > 1:
                self._batches.pop(0)
            used = [t for b in self._batches for t in b]
            mapping, drift_se = fit_clock(used)
            self.mapping = mapping
            self.drift_se_ppm = drift_se
            span = (used[-1].device_us - used[0].device_us) * 1e-6
            self._log(
                "event",
                f"clock mapping: host = {mapping.ref_host:.6f} + (device_us - "
                f"{mapping.ref_device_us}) * 1e-6 * (1 + {mapping.drift_ppm:.3f}e-6); "
                f"drift {mapping.drift_ppm:+.3f} ± {drift_se:.3f} ppm, residual "
                f"{mapping.residual_s * 1e6:.1f} us, uncertainty {mapping.uncertainty_s * 1e6:.1f} us, "
                f"{mapping.samples} samples over {span:.3f} s ({len(kept)} of {len(trips)} kept now)",
                device_us=mapping.ref_device_us,
                host_time=mapping.ref_host,
            )
            self.log.clock_mapped(self.name, mapping, drift_se)
        return mapping

    def _wire_baud(self) -> float | None:
        """The line's baud rate when it is a real (or emulated) serial line, else None."""
        baud = getattr(self._serial, "baudrate", self.baudrate)
        return float(baud) if isinstance(baud, (int, float)) and baud > 0 else None
