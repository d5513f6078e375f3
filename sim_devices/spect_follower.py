"""A simulated SPECT that sits beside a running simulated rig and records every scan.

``vts sim up --trigger triggerbox --spect`` runs one: a source marker stands on the table (in
the scene the cameras render); when the trigger box sends its SPECT start pulse (pin CH2), the
marker starts moving along the table axis every ~15 s (for 10 minutes), clear of the SPECT's
head rotations; when the square wave stops, the simulated SPECT writes the list-mode of that acquisition,
following the start pulse and square wave the emulated box actually emitted, into
``<dir>/spect/scan-<UTC time>.vtslm`` (truth beside it in ``.truth.json``). Then it waits for
the next scan. So a person can try the whole scan-time chain by hand::

    vts sim up --trigger triggerbox --spect --detach --dir sim
    source sim/sim.env; export VTS_CONFIG=sim/rig.yaml
    vts scan start --duration 60 -o scan1
    vts sync analyze scan1 --listmode sim/spect/scan-*.vtslm -o sync.html

Host UTC epoch seconds throughout.
"""

from __future__ import annotations

import datetime as _dt
import threading
import time
from pathlib import Path

from .spect_listmode import SimListModeSpect
from .sync_sim import place_source_marker, plan_sync_moves, schedule_source_moves

HORIZON_S = 600.0      # moves are planned over the first 10 minutes after a start pulse
MOVE_EVERY_S = 15.0    # about one move per this many seconds
WAVE_ENDED_S = 3.0     # no square-wave edge for this long after the last one: the scan stopped
SPECT_TAIL_S = 0.6     # the acquisition ends this long before the wave's last edge
POLL_S = 0.2


class SpectFollower:
    """Watches ``rig.trigger_box``; one list-mode file per scan in ``folder``. Create it before
    the rig's cameras are in use (it adds the source marker to the scene)."""

    def __init__(self, rig, folder, seed: int = 0, log=print):
        if rig.trigger != "triggerbox":
            raise ValueError("the simulated SPECT follows the trigger box: run the rig with trigger='triggerbox'")
        self.rig = rig
        self.folder = Path(folder)
        self.seed = seed
        self.log = log
        self.marker = place_source_marker(rig.scene)
        self.written: list[Path] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> "SpectFollower":
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
        seen_cycle = -1
        n = 0
        while not self._stop.wait(POLL_S):
            box = self.rig.trigger_box
            if box is None or not box.running():
                continue
            try:
                starts = self._rising("CH2", seen_cycle)
                if not starts:
                    continue
                start = starts[0]
                seen_cycle = start.cycle          # whatever happens next, this pulse is handled
                fire = box.host_time(start.cycle)
                self.log(f"sim SPECT: start pulse at {_iso(fire)}; the source marker moves every "
                         f"~{MOVE_EVERY_S:g} s")
                times, steps = plan_sync_moves(fire, HORIZON_S, n=int(HORIZON_S / MOVE_EVERY_S),
                                               seed=self.seed + n)
                source = schedule_source_moves(self.rig.scene, self.marker, times, steps)
                last = self._wait_wave_end(start.cycle)
                if last is None:
                    return
                seen_cycle = last
                duration = box.host_time(last) - fire - SPECT_TAIL_S
                if duration <= 1.0:
                    self.log("sim SPECT: the scan was too short to record")
                    continue
                n += 1
                self.folder.mkdir(parents=True, exist_ok=True)
                out = self.folder / f"scan-{_dt.datetime.fromtimestamp(fire, _dt.timezone.utc):%Y%m%dT%H%M%SZ}.vtslm"
                SimListModeSpect(self.rig.scene, [source], seed=self.seed + n) \
                    .follow_trigger_box(box, out, duration)
                self.written.append(out)
                self.log(f"sim SPECT: wrote {out} ({duration:.1f} s)")
            except Exception as exc:  # keep the rig up; say what happened in sim.log
                self.log(f"sim SPECT: {type(exc).__name__}: {exc}")

    def _wait_wave_end(self, start_cycle: int) -> int | None:
        """The cycle of the wave's last edge once it has been quiet for WAVE_ENDED_S."""
        box = self.rig.trigger_box
        last_edge, quiet_since = start_cycle, time.monotonic()
        while not self._stop.wait(POLL_S):
            edges = [e for e in box.edges("OC1A") if e.cycle > last_edge]
            if edges:
                last_edge, quiet_since = edges[-1].cycle, time.monotonic()
            elif time.monotonic() - quiet_since > WAVE_ENDED_S:
                return last_edge
        return None


def _iso(t: float) -> str:
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc).strftime("%H:%M:%S.%f")[:-3] + "Z"
