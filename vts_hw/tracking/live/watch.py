"""Whether the patient is watched, at every moment: TRACKING, REFERENCE, or NOT TRACKING and why.

The live worker publishes :class:`Facts` after each frame set (the capture time of the last
instant that *observed* the patient: a pose while tracking, three or more points while
learning the reference; the last frame set of any kind; why the last one did not observe).
Times are monotonic seconds of **capture**: a frame's arrival at the live tap less how much
later than usual it arrived (so frames that reach the host late count as late).

:meth:`Watch.classify` says, at any ``now``, from the facts and each camera's silence:

* **TRACKING**: the reference is learned and the patient was observed within ``late_s``;
* **REFERENCE**: learning the reference, frames with markers coming in, for at most
  ``reference_deadline_s`` from the first frame (and the first ``late_s``, waiting for them);
* **NOT TRACKING**, with the first reason that holds (each reason is ``kind: detail``):
  ``camera lost`` (fewer than two cameras delivered a frame within ``late_s``: no 3D point can
  be made), ``frames too late`` (the newest frame set estimated is older than ``late_s``: the
  live path or the frames are behind), ``too few markers`` (frame sets come in but fewer than
  three of the model's markers are in them), ``no reference`` (the reference deadline passed).

:meth:`Watch.tick` (one thread, a few times a second) keeps the record: status changes
(:class:`Change`), NOT TRACKING stretches (:class:`Episode`: from the last instant observed to
the first observed again, so a stretch is the time without a pose, not the time it took to
notice; when the frames were late rather than lost, to when the view had a fresh pose again), a :class:`BlindAlert` once a stretch lasts more than ``blind_alert_s``, and the time
spent in each status (:meth:`Watch.totals`). Time without frames is never TRACKING.
See docs/decisions/0048-live-tracking-when-frames-are-lost.md.
"""

from __future__ import annotations

import datetime as _dt
import re
from dataclasses import dataclass, field

__all__ = ["TRACKING", "REFERENCE", "NOT_TRACKING", "Facts", "Episode", "BlindAlert", "Change", "Watch"]

TRACKING, REFERENCE, NOT_TRACKING = "TRACKING", "REFERENCE", "NOT TRACKING"


@dataclass(frozen=True)
class Facts:
    """What the live worker last published (monotonic s of capture)."""

    phase: str = "waiting"  # the estimator's: waiting | reference | tracking
    started: float | None = None  # the first frame at the live tap
    seen: float | None = None  # the last instant that observed the patient
    resumed: float | None = None  # the first observed instant after a break longer than late_s
    estimate: float | None = None  # the last frame set estimated, whatever it gave
    why: str = ""  # why the last frame set did not observe the patient
    learned: float | None = None  # when the reference was learned
    seen_arrival: float | None = None  # when the last frame of the last observing set reached the tap
    broke: float | None = None  # the last observed instant before ``resumed`` (the break's start)


@dataclass
class Episode:
    """A stretch NOT TRACKING: ``start`` (the last instant observed, or when the reference
    deadline passed) to ``end`` (the first observed again; None while it lasts)."""

    start: float
    reasons: list[str] = field(default_factory=list)
    end: float | None = None
    alerted: bool = False

    def duration(self, now: float) -> float:
        return (self.end if self.end is not None else now) - self.start


@dataclass(frozen=True)
class BlindAlert:
    """NOT TRACKING for longer than ``blind_alert_s``: an alert of its own."""

    start: float  # host s of the last instant the patient was observed
    raised: float  # host s
    reason: str

    def text(self) -> str:
        since = _dt.datetime.fromtimestamp(self.start, _dt.UTC).strftime("%H:%M:%S")
        return (
            f"PATIENT NOT TRACKED for {self.raised - self.start:.1f} s: {self.reason}; "
            f"the patient's motion since {since} UTC is not known"
        )


@dataclass(frozen=True)
class Change:
    status: str
    reason: str
    at: float  # host s it became so


def _kind(reason: str) -> str:
    """A reason without its figures ("camera lost: cam2", "frames too late"): a stretch lists
    each kind once."""
    head, _, rest = reason.partition(":")
    if head == "camera lost":
        names = re.findall(r"(\S+) \(no frame", rest)
        return f"{head}: {', '.join(names) if names else 'all'}"
    return head


class Watch:
    """``cameras``: the names; ``host_of(mono)``: host epoch s of a monotonic time."""

    def __init__(
        self,
        cameras,
        *,
        late_s: float = 0.5,
        blind_alert_s: float = 3.0,
        reference_deadline_s: float = 20.0,
        host_of=lambda m: m,
    ):
        self.cameras = list(cameras)
        self.late_s, self.blind_alert_s = float(late_s), float(blind_alert_s)
        self.reference_deadline_s = float(reference_deadline_s)
        self.host_of = host_of
        self.status: str | None = None
        self.reason = ""
        self.since: float | None = None  # (None while status is: set together)
        self.episodes: list[Episode] = []
        self._spent = {TRACKING: 0.0, REFERENCE: 0.0, NOT_TRACKING: 0.0}
        self._end: float | None = None
        self._resumed: float | None = None  # the last break accounted for

    # -- what it is now ---------------------------------------------------------------------------
    def classify(self, now: float, f: Facts, silent: dict) -> tuple[str, str]:
        """``(status, reason)`` at monotonic ``now``; ``silent``: per camera the seconds since
        its last frame reached the live path (None: none yet). A camera that sent nothing since
        the last frame set that observed the patient counts as lost. Changes nothing."""
        if f.started is None:
            return NOT_TRACKING, "no frames yet"
        late = self.late_s
        if f.seen is None and f.phase != "tracking" and now - f.started <= late:
            return REFERENCE, "waiting for the first frame set"  # nothing is late yet
        if f.seen is not None and now - f.seen <= late:
            if f.phase == "tracking":
                return TRACKING, ""
            if now - f.started <= self.reference_deadline_s:
                return REFERENCE, f.why
            return NOT_TRACKING, f"no reference: none learned in {now - f.started:.0f} s" + (
                f" ({f.why})" if f.why else ""
            )
        # lost: nothing since the last frame set that observed the patient, or quiet for late_s
        lost = {
            n: s
            for n, s in silent.items()
            if s is None or s > late or (f.seen_arrival is not None and now - s <= f.seen_arrival)
        }
        if len(silent) - len(lost) < 2:
            if len(lost) == len(silent):
                quiet = min((s for s in lost.values() if s is not None), default=None)
                return NOT_TRACKING, (
                    "camera lost: no frames from any camera"
                    + ("" if quiet is None else f" for {quiet:.1f} s" if quiet > late else " since the last pose")
                )
            return NOT_TRACKING, "camera lost: " + ", ".join(
                f"{n} (no frame yet)"
                if s is None
                else f"{n} (no frame for {s:.1f} s)"
                if s > late
                else f"{n} (no frame since the last pose)"
                for n, s in lost.items()
            )
        lost = {n: s for n, s in lost.items() if s is None or s > late}  # the others are only behind
        if f.estimate is None:
            return NOT_TRACKING, "frames too late: no frame set estimated yet"
        if now - f.estimate > late:
            return NOT_TRACKING, f"frames too late: the newest frame set estimated is {now - f.estimate:.1f} s old"
        also = f"; {', '.join(lost)} lost" if lost else ""
        if f.phase != "tracking":
            return NOT_TRACKING, f"too few markers: fewer than three seen{also}"
        return NOT_TRACKING, f"too few markers: {f.why or 'no pose'}{also}"

    # -- the record ---------------------------------------------------------------------------------
    def tick(self, now: float, f: Facts, silent: dict) -> list:
        """Evaluate at ``now``; returns what happened: :class:`Change`, :class:`Episode` (one that
        ended), :class:`BlindAlert`."""
        if f.started is None:
            return []
        status, reason = self.classify(now, f, silent)
        out: list = []
        if self.status is None or self.since is None:
            self._enter(status, reason, f.started, out)
        elif status != self.status:
            if status == NOT_TRACKING:
                if f.seen is not None and now - f.seen > self.late_s:
                    at = f.seen  # blind since the last instant observed
                elif self.status == REFERENCE:
                    at = f.started + self.reference_deadline_s
                else:
                    at = now
            elif self.status == NOT_TRACKING:  # observed again since resumed (and learned, to track)
                ep = self.episodes[-1]
                back = [
                    x for x in (f.resumed, f.learned if status == TRACKING else None) if x is not None and x >= ep.start
                ]
                # no break in the poses: frames came late, not lost; blind until the view had a
                # fresh pose again (now, give or take a look of the watch)
                at = max(back) if back else now
            else:
                at = f.learned if f.learned is not None else now
            self._enter(status, reason, min(max(at, self.since), now), out)
        elif status == NOT_TRACKING and _kind(reason) not in map(_kind, self.episodes[-1].reasons):
            self.episodes[-1].reasons.append(reason)
        elif status != NOT_TRACKING:
            self._short_break(f, out)
        if f.resumed is not None:
            self._resumed = f.resumed
        if status == NOT_TRACKING:
            self.reason = reason
            ep = self.episodes[-1]
            if not ep.alerted and now - ep.start > self.blind_alert_s:
                ep.alerted = True
                out.append(BlindAlert(self.host_of(ep.start), self.host_of(now), reason))
        else:
            self.reason = reason
        return out

    def _short_break(self, f: Facts, out: list) -> None:
        """A break in the poses longer than late_s that ended before the watch looked (the
        ticks are a tenth of a second apart; on a busy host, more): a stretch all the same."""
        if self.status is None or self.since is None:
            return
        if f.resumed is None or f.broke is None or f.resumed == self._resumed or f.broke < self.since:
            return
        ep = Episode(
            f.broke,
            [f"no pose: {f.resumed - f.broke:.2f} s without one (shorter than the live view could show)"],
            end=f.resumed,
        )
        self._spent[self.status] += f.broke - self.since
        self._spent[NOT_TRACKING] += f.resumed - f.broke
        self.since = f.resumed
        self.episodes.append(ep)
        out.append(ep)

    def _enter(self, status: str, reason: str, at: float, out: list) -> None:
        if self.status is not None and self.since is not None:
            self._spent[self.status] += at - self.since
            if self.status == NOT_TRACKING:
                self.episodes[-1].end = at
                out.append(self.episodes[-1])
        if status == NOT_TRACKING:
            self.episodes.append(Episode(at, [reason]))
        self.status, self.reason, self.since = status, reason, at
        out.append(Change(status, reason, self.host_of(at)))

    def finish(self, now: float) -> list:
        """The live path stopped at ``now``: the last status's time counted; a stretch NOT
        TRACKING still open ends here (and is returned)."""
        if self.status is None or self.since is None or self._end is not None:
            return []
        self._spent[self.status] += max(0.0, now - self.since)
        self._end = now
        if self.status == NOT_TRACKING:
            self.episodes[-1].end = now
            return [self.episodes[-1]]
        return []

    def totals(self, now: float | None = None) -> dict:
        """Seconds per status (the current one counted to ``now``), and the NOT TRACKING share."""
        spent = dict(self._spent)
        if self.status is not None and self.since is not None and self._end is None and now is not None:
            spent[self.status] += max(0.0, now - self.since)
        total = sum(spent.values())
        return {
            "tracking_s": spent[TRACKING],
            "reference_s": spent[REFERENCE],
            "not_tracking_s": spent[NOT_TRACKING],
            "not_tracking_share": spent[NOT_TRACKING] / total if total > 0 else None,
            "watched_s": total,
        }
