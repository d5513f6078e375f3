#!/usr/bin/env python3
"""The live path when frames are lost: NOT TRACKING time against the time truly without frames,
and the motion alerts' latency, per loss pattern. One recording of the simulated patient is
rendered ahead of time (2 cameras, 25 fps, breathing or not, body moves), then fed to the live
tracker on a made-up clock (each frame at its recorded receipt, the watch ticked every 0.1 s)
once per loss pattern, the lost frames left out. So the figures are the live path's own logic
(reference, grouping, fit, watch), not this host's speed; the tests check the same on a real
clock and under load.

Per pattern: frames lost; the time truly without a pose (stretches longer than the live
path's 0.5 s with no instant both cameras saw) and all time between frame sets; the time
reported NOT TRACKING and the largest difference stretch by stretch; NOT TRACKING alerts
(expected: one per stretch longer than blind_alert_s = 3 s); when the reference was learned;
per body move, the alert's delay from the move's true start (frame time: add ~30 ms on a real
host, docs/decisions/0036) and how far the start is known; other alerts (before any move, or
a second for one move).

    .venv/bin/python bench/live_blind_time.py                    # 60 s, breathing
    .venv/bin/python bench/live_blind_time.py --no-breathing --seconds 40 --seed 2
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from vts_hw.sim_devices.patient import BodyMove
from vts_hw.sim_devices.recording_sim import received_frames, simulate_recording
from vts_hw.sim_devices.sync_truth import true_cameras
from vts_hw.tracking.live.estimator import LiveSettings
from vts_hw.tracking.live.tracker import LiveTracker
from vts_hw.tracking.live.watch import Episode
from vts_hw.vision.registration import RigidTransform

sys.path.insert(0, str(Path(__file__).resolve().parent))
from losskit.truth import observed_instants, stretches_without  # noqa: E402

MOTION = SimpleNamespace(alert_mm=3.0, alert_deg=2.0, alert_after_s=1.0, blind_alert_s=3.0)
LATE_S = 0.5
MONO0 = 10_000.0


def patterns(rng: np.random.Generator):
    """(name, lost(camera, s from the first frame) -> bool)."""
    drop5 = {}
    drop20 = {}

    def random_loss(table, p):
        return lambda cam, t: table.setdefault((cam, round(t, 3)), rng.random() < p)

    yield "none", lambda cam, t: False
    yield "5 % single frames, each camera", random_loss(drop5, 0.05)
    yield "20 % single frames, each camera", random_loss(drop20, 0.20)
    yield "1.04 s bursts every 3 s, both (the issue's host)", lambda cam, t: (t - 0.5) % 3.0 < 1.04
    yield "0.4 s bursts every 2 s, both", lambda cam, t: (t - 0.3) % 2.0 < 0.4
    yield "cam2 off 5 s every 20 s", lambda cam, t: cam == "cam2" and (t - 12.0) % 20.0 < 5.0


def render(folder: Path, seconds: float, seed: int, breathing: bool):
    start = 1_790_000_000.0 + 1000.0 * seed + 5.0  # simulate_recording's default start
    moves = [
        BodyMove(start + a, start + a + 0.6, (0.0, 1.0 + 0.5 * k, 0.0), (2.0, 5.0 + k, 2.0))
        for k, a in enumerate(np.arange(17.3, seconds - 4.0, 13.7))
    ]
    sim = simulate_recording(folder, duration_s=seconds, seed=seed, patient={"moves": moves, "breathing": breathing})
    frames, offsets = received_frames(folder, sim.cameras)
    return sim, frames, offsets, moves, start


def run(sim, frames, offsets, lost, start):
    """Feed the kept frames on the made-up clock; returns the tracker, events, motion alerts and
    the kept frames' (s from the first, camera, exposure s from the first)."""
    events, alerts = [], []
    tr = LiveTracker(
        true_cameras(sim.scene, start),
        MOTION,
        mapping=RigidTransform.identity(),
        clock_offsets=offsets,
        settings=LiveSettings(reference_s=10.0),
        on_event=events.append,
        on_alert=lambda a, est: alerts.append(a),
        late_s=LATE_S,
    )
    t_first = frames[0][0]
    kept = []
    tick = 0.0
    for host, name, frame in frames:
        rel = host - t_first
        while tick <= rel:
            tr.step(0.0, now=MONO0 + tick)
            tr.tick(MONO0 + tick)
            tick = round(tick + 0.1, 6)
        if lost(name, rel):
            continue
        kept.append((rel, name, frame.camera_time - offsets[name] - t_first))
        tr.tap.put(name, frame, arrival=MONO0 + rel)
        tr.step(0.0, now=MONO0 + rel)
    end = MONO0 + frames[-1][0] - t_first
    tr.step(0.0, now=end + 2.0)
    tr.tick(end)
    events += tr.watch.finish(end)
    return tr, events, alerts, kept, end - MONO0


def unobserved(kept, end: float, tol: float = 0.02) -> tuple[float, float, list]:
    """Instants both cameras saw (frames within ``tol`` of each other); the time between them
    in stretches longer than LATE_S, all of it, and those stretches."""
    by = {}
    for _rel, name, t in kept:
        by.setdefault(name, []).append(t)
    seen = observed_instants(by, 2, tol, ref=next(iter(by)))
    long = stretches_without(seen, 0.0, end, LATE_S)
    gaps = np.diff(np.concatenate([[0.0], seen[(seen > 0.0) & (seen < end)], [end]]))
    step = 1.0 / 25.0
    return float(sum(b - a for a, b in long)), float(np.sum(np.maximum(gaps - step, 0.0))), long


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--no-breathing", action="store_true")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="vts-live-blind-") as tmp:
        t0 = time.monotonic()
        sim, frames, offsets, moves, start = render(Path(tmp) / "rec", a.seconds, a.seed, not a.no_breathing)
        t_first = frames[0][0]
        print(
            f"live path under loss: simulated patient ({'not ' if a.no_breathing else ''}breathing), 2 cameras at "
            f"25 fps, {a.seconds:g} s, seed {a.seed}, {len(moves)} body moves; rendered ahead in "
            f"{time.monotonic() - t0:.0f} s; reference 10 s, late_s {LATE_S} s, blind_alert_s "
            f"{MOTION.blind_alert_s} s; times are frame times (the made-up clock)"
        )
        rng = np.random.default_rng(a.seed)
        for name, lost in patterns(rng):
            tr, events, alerts, kept, end = run(sim, frames, offsets, lost, start)
            lost_share = 1.0 - len(kept) / len(frames)
            truly, between, long = unobserved(kept, end)
            eps = [e for e in events if isinstance(e, Episode)]
            rep = sum(e.end - e.start for e in eps)
            diffs = []
            for s0, s1 in long:  # each stretch without frames against the NOT TRACKING that covers it
                cover = [e for e in eps if e.start - MONO0 < s1 and e.end - MONO0 > s0]
                diffs.append(sum(e.end - e.start for e in cover) - (s1 - s0) if cover else -(s1 - s0))
            expected_blind = sum(1 for s0, s1 in long if s1 - s0 > MOTION.blind_alert_s)
            learned = "never" if tr.facts.learned is None else f"{tr.facts.learned - MONO0:.1f} s"
            print(f"\n{name}: {lost_share:.1%} of frames lost; reference learned at {learned}")
            print(
                f"  time truly without a pose (stretches > {LATE_S} s) {truly:.2f} s in {len(long)}; all time "
                f"between frame sets {between:.2f} s; reported NOT TRACKING {rep:.2f} s in {len(eps)} stretch(es); "
                f"per stretch reported - true: " + (f"{min(diffs):+.2f} .. {max(diffs):+.2f} s" if diffs else "-")
            )
            print(
                f"  NOT TRACKING alerts {len(tr.blind_alerts)} (stretches longer than {MOTION.blind_alert_s:g} s: "
                f"{expected_blind}); reasons: "
                + ", ".join(sorted({r.split(" (")[0] for e in eps for r in e.reasons}))
                or "-"
            )
            firsts, extra = {}, []
            for x in alerts:  # each alert to the latest move that started before it
                before = [k for k, mv in enumerate(moves) if mv.t_start - 0.5 <= x.time]
                if before and before[-1] not in firsts:
                    firsts[before[-1]] = x
                else:
                    extra.append(x)
            for k, mv in enumerate(moves):
                x = firsts.get(k)
                if x is None:
                    print(f"  move at {mv.t_start - t_first:5.1f} s: NO ALERT")
                    continue
                print(
                    f"  move at {mv.t_start - t_first:5.1f} s: alert {x.time - mv.t_start:.2f} s after its start, "
                    f"onset {x.onset - mv.t_start:+.2f} s, start known within {x.onset_known_s:.2f} s; "
                    f"{x.move_mm:.1f} mm {x.turn_deg:.1f} deg"
                )
            print(f"  other alerts: {len(extra)}; live frames dropped {sum(tr.tap.dropped.values())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
