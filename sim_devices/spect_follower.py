"""A simulated SPECT that sits beside a running simulated rig and records every scan.

``vts sim up --trigger triggerbox --spect`` runs one: a source marker stands on the table (in
the scene the cameras render); when the trigger box sends its SPECT start pulse (pin CH2), the
marker starts moving along the table axis every ~15 s (for 10 minutes), clear of the SPECT's
head rotations; when the square wave stops, the simulated SPECT writes the list-mode of that acquisition,
following the start pulse and square wave the emulated box actually emitted, into
``<dir>/spect/scan-<UTC time>.vtslm`` (truth beside it in ``.truth.json``). Then it waits for
the next scan. A scan it cannot record (a full or read-only folder, a scan too short, the rig
stopped mid-scan) is said in sim.log and left as ``scan-<UTC time>.failed.json`` in the same
folder (docs/listmode-format.md, "Failure records"), which `vts sync analyze` and `vts sim down`
report, in one sentence each. A scan whose host died with the wave on (a ``kill -9``: the box's
watchdog cuts the wave later, or the next scan stops it and fires again) ends with the wave's
last edge before the next start pulse, and is recorded as the SPECT would have acquired it.
So a person can try the whole scan-time chain by hand::

    vts sim up --trigger triggerbox --spect --detach --dir sim
    source sim/sim.env; export VTS_CONFIG=sim/rig.yaml
    vts scan start --duration 60 -o scan1
    vts sync analyze scan1 --listmode sim/spect/scan-*.vtslm -o sync.html

Host UTC epoch seconds throughout.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import threading
import time
from pathlib import Path

from vts_hw.errors import VtsError
from vts_hw.files import ensure_dir, os_reason
from vts_hw.sim_devices.spect_listmode import SimListModeSpect, TriggerEdges, edges_from_trigger_box
from vts_hw.sim_devices.sync_truth import place_source_marker, plan_sync_moves, schedule_source_moves
from vts_hw.spect.listmode.failures import write_failure_record

HORIZON_S = 600.0  # moves are planned over the first 10 minutes after a start pulse
MOVE_EVERY_S = 15.0  # about one move per this many seconds
WAVE_ENDED_S = 3.0  # no square-wave edge for this long after the last one: the scan stopped
SPECT_TAIL_S = 0.6  # the acquisition ends this long before the wave's last edge
POLL_S = 0.2


class SpectFollower:
    """Watches ``rig.trigger_box``; one list-mode file per scan in ``folder``. Create it before
    the rig's cameras are in use (it adds the source marker to the scene). ``sources``: what
    holds the activity instead of a moving source marker (the patient's heart,
    :func:`~vts_hw.sim_devices.patient_source.heart_source`): nothing is added or moved then."""

    def __init__(self, rig, folder, seed: int = 0, log=print, sources=None):
        if rig.trigger != "triggerbox":
            raise ValueError("the simulated SPECT follows the trigger box: run the rig with trigger='triggerbox'")
        self.rig = rig
        self.folder = Path(folder)
        self.seed = seed
        self.log = log
        self.sources = list(sources) if sources else None
        self.marker = None if self.sources else place_source_marker(rig.scene)
        self.written: list[Path] = []
        self.failures: list[Path] = []  # failure records written (scans not recorded)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> SpectFollower:
        self._thread = threading.Thread(target=self._run, name="sim-spect", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10)

    # ------------------------------------------------------------------ the watch
    def _rising(self, pin: str, after_cycle: int) -> list:
        box = self.rig.trigger_box
        return [e for e in box.edges(pin) if e.value == 1 and e.cycle > after_cycle]

    def _run(self) -> None:
        box = self.rig.trigger_box  # the pulses sent before this SPECT was there are not its scans
        seen_cycle = box.cycles_now() if box is not None and box.running() else -1
        n = 0
        while not self._stop.wait(POLL_S):
            box = self.rig.trigger_box
            if box is None or not box.running():
                continue
            scan: tuple[float, float | None] | None = None  # (fire, end) host s of the scan being followed
            out: Path | None = None  # its file
            try:
                starts = self._rising("CH2", seen_cycle)
                if not starts:
                    continue
                start = starts[0]
                seen_cycle = start.cycle  # whatever happens next, this pulse is handled
                fire = box.host_time(start.cycle)
                scan = (fire, None)
                if self.sources:
                    self.log(
                        f"sim SPECT: start pulse at {_iso(fire)}; counting "
                        f"{', '.join(getattr(x, 'name', x.body) for x in self.sources)}"
                    )
                    sources = self.sources
                else:
                    self.log(
                        f"sim SPECT: start pulse at {_iso(fire)}; the source marker moves every ~{MOVE_EVERY_S:g} s"
                    )
                    times, steps = plan_sync_moves(fire, HORIZON_S, n=int(HORIZON_S / MOVE_EVERY_S), seed=self.seed + n)
                    sources = [schedule_source_moves(self.rig.scene, self.marker, times, steps)]
                last, cut = self._wait_wave_end(start.cycle)
                if last is None:
                    self._failed(fire, None, "the simulated rig was stopped while the scan was running")
                    return
                seen_cycle = last
                end = box.host_time(last)
                scan = (fire, end)
                if cut:
                    self.log(
                        f"sim SPECT: the next scan's start pulse came before the square wave of the scan "
                        f"started at {_iso(fire)} had been quiet for {WAVE_ENDED_S:g} s (its host killed with "
                        f"the wave on?): that acquisition ends with the wave's last edge before the pulse, "
                        f"{_iso(end)}"
                    )
                duration = end - fire - SPECT_TAIL_S
                if duration <= 1.0:
                    self._failed(
                        fire,
                        end,
                        f"the scan was too short to record ({duration + SPECT_TAIL_S:.1f} s "
                        f"of square wave; more than {1.0 + SPECT_TAIL_S:g} s needed)",
                    )
                    continue
                n += 1
                out = self.folder / _listmode_name(fire)
                ensure_dir(self.folder, "simulated SPECT folder")
                SimListModeSpect(self.rig.scene, sources, seed=self.seed + n).write(
                    out, _scan_edges(box, start.cycle, last), duration, _known_until(box)
                )
                self.written.append(out)
                self.log(f"sim SPECT: wrote {out} ({duration:.1f} s)")
            except Exception as exc:  # keep the rig up; say what happened where the user looks
                why = f"{type(exc).__name__}: {exc}"
                if isinstance(exc, OSError):
                    why = f"could not write {out.name if out else 'into ' + str(self.folder)} ({os_reason(exc)})"
                elif isinstance(exc, VtsError):
                    why = str(exc)
                elif isinstance(exc, ValueError):  # the simulation's own refusal, in its words
                    why = f"the scan's trigger could not be followed: {exc}"
                started, ended = scan if scan is not None else (None, None)
                self._failed(started, ended, why)

    def _failed(self, start: float | None, end: float | None, reason: str) -> None:
        """Say it in sim.log and leave a failure record where the list-mode would have gone
        (docs/listmode-format.md, "Failure records"), for `vts sync analyze` and `vts sim down`."""
        self.log(
            f"sim SPECT: FAILED to record the scan started at "
            f"{_iso(start) if start is not None else 'an unknown time'}: {reason}"
        )
        log = self.folder.parent / "sim.log"
        try:
            ensure_dir(self.folder, "simulated SPECT folder")
            rec = write_failure_record(
                self.folder,
                _listmode_name(start if start is not None else time.time()),
                reason,
                by="the simulated SPECT",
                start=start,
                end=end,
                log=log if log.exists() else None,
            )
        except VtsError as exc:
            self.log(f"sim SPECT: and could not leave a failure record: {exc}")
            return
        self.failures.append(rec)

    def _wait_wave_end(self, start_cycle: int) -> tuple[int | None, bool]:
        """``(cycle, cut)``: the cycle of the wave's last edge once it has been quiet for
        WAVE_ENDED_S (``cut`` False); or, when the next scan's start pulse comes first (the wave
        of a scan whose host died runs on until the next scan stops and fires it again), the
        last edge before that pulse (``cut`` True). ``(None, False)``: the rig stopped."""
        box = self.rig.trigger_box
        last_edge, quiet_since = start_cycle, time.monotonic()
        while not self._stop.wait(POLL_S):
            nxt = self._rising("CH2", start_cycle)
            edges = [e for e in box.edges("OC1A") if e.cycle > last_edge and (not nxt or e.cycle < nxt[0].cycle)]
            if edges:
                last_edge, quiet_since = edges[-1].cycle, time.monotonic()
            if nxt:
                return last_edge, True
            if not edges and time.monotonic() - quiet_since > WAVE_ENDED_S:
                return last_edge, False
        return None, False


def _scan_edges(box, start_cycle: int, last_cycle: int) -> TriggerEdges:
    """What the box sent for one scan: its start pulse (not a later scan's) and the square
    wave up to the scan's last edge (a later scan's edges left out)."""
    edges = edges_from_trigger_box(box)
    until = box.host_time(last_cycle)
    return dataclasses.replace(
        edges,
        rising=edges.rising[edges.rising <= until],
        falling=edges.falling[edges.falling <= until],
        start_pulse=box.host_time(start_cycle),
    )


def _known_until(box) -> float | None:
    """The host time the emulation has reached (its pins known until then); None once stopped.
    The status file is rewritten in place: the best of 3 reads."""
    return box.host_time(max(box.cycles_now() for _ in range(3))) if box.running() else None


def _listmode_name(fire: float) -> str:
    return f"scan-{_dt.datetime.fromtimestamp(fire, _dt.UTC):%Y%m%dT%H%M%SZ}.vtslm"


def _iso(t: float) -> str:
    return _dt.datetime.fromtimestamp(t, _dt.UTC).strftime("%H:%M:%S.%f")[:-3] + "Z"
