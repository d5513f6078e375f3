"""bench/motion_under_loss.py's core (bench/losskit/): a row's figures are computed from the
truth -- which frames the simulated cameras' loss fault drops, a blind stretch injected into
the frames and whether the manifest reported it, the patient's true moves, breathing and pose --
and not from what the scan claims. The scans themselves are the bench's (minutes); these are
seconds."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))

from losskit.rows import centre_shift, frame_loss, live, offline  # noqa: E402
from losskit.scans import burst_faults, cpu_load, plan_moves  # noqa: E402
from losskit.table import verdicts  # noqa: E402
from losskit.truth import true_rate  # noqa: E402
from vts_hw.sim_devices.faults import Faults  # noqa: E402
from vts_hw.sim_devices.patient import add_patient  # noqa: E402
from vts_hw.sim_devices.scene import Scene  # noqa: E402

T0 = 1_790_000_000.0
FPS = 25.0
P = 1.0 / FPS
SPAN = (T0 + 5.0, T0 + 45.0)  # the scan: first frames .. stopped
HOLE = (T0 + 30.0, T0 + 32.0)  # no frame from any camera


@pytest.fixture(scope="module")
def patient():
    scene = Scene.reference(seed=1, start_epoch=T0)
    return add_patient(scene, T0, 120.0, seed=1, moves=plan_moves(T0, 45.0, 1))


def _times(hole=HOLE):
    g = np.arange(round(SPAN[0] / P), round(SPAN[1] / P) + 1) * P
    keep = ~((g >= hole[0]) & (g < hole[1]))
    return {"cam1": g[keep] + 0.002, "cam2": g[keep] + 0.013}


def _scan(patient, not_tracking, alerts, times=None):
    manifest = {
        "scan": {"times": {"first_frames": SPAN[0], "stopped": SPAN[1]}},
        "live_motion": {
            "alert_mm": 3.0,
            "alert_deg": 2.0,
            "alert_after_s": 1.0,
            "alerts": alerts,
            "not_tracking": [{"start": a, "end": b} for a, b in not_tracking],
            "summary": {"phase": "tracking", "tracking": {"reference_s": 10.0}},
        },
    }
    truth = SimpleNamespace(patient=patient, times=times or _times(), period=P)
    return SimpleNamespace(manifest=manifest, truth=truth, cameras=2)


def test_the_fault_s_dropped_frames_and_the_extra_ones_are_told_apart():
    f = Faults()
    f.update(burst_faults(0.2, seed=1))
    assert 0.7 <= f.lose_burst_frames * P <= 1.3
    lost = lambda cam, t: f.lost(cam, int(round(t / P)), round(t / P) * P, P)  # noqa: E731
    g = np.arange(round(T0 / P), round((T0 + 30.0) / P)) * P
    kept = np.array([t for t in g if not lost("cam1", t)])
    dropped_truth = 1.0 - kept.size / g.size
    assert 0.15 < dropped_truth < 0.25
    kept = np.delete(kept, [100, 200, 300])  # three frames lost by something else
    share, extra = frame_loss(lost, P, {"cam1": kept + 0.003})
    assert extra == 3 and share == pytest.approx(dropped_truth, abs=1.5 / g.size)


def test_an_injected_blind_stretch_is_counted_and_said_unreported_unless_the_manifest_has_it(patient):
    moves = [m for m in patient.motion.moves if SPAN[0] <= m.t_start <= SPAN[1] - 1.5]
    assert len(moves) >= 2
    alerts = [{"raised": m.t_start + 1.2, "onset": m.t_start, "onset_known_s": 0.04} for m in moves]
    told = live(_scan(patient, [(HOLE[0] - 0.02, HOLE[1] + 0.03)], alerts), moves)
    assert told["truly"] == pytest.approx(2.0, abs=0.05) and told["unreported"] < 0.05
    assert told["reported"] == pytest.approx(2.05) and told["bad"] == []
    assert [k for k, _ in told["latency"]] == ["measured"] * len(moves)
    assert max(d for _, d in told["latency"]) == pytest.approx(1.2)
    silent = live(_scan(patient, [], alerts), moves)
    assert silent["unreported"] == pytest.approx(2.0, abs=0.05) and silent["reported"] == 0
    assert any("not reported NOT TRACKING" in b for b in silent["bad"])
    # a move with no alert while the patient was watched is a miss; an alert for nothing too
    assert centre_shift(patient, moves[0])[0] > 3.6  # well over alert_mm: it must alert
    missing = live(_scan(patient, [(HOLE[0], HOLE[1])], [{"raised": SPAN[0] + 8.0}] + alerts[1:]), moves)
    assert missing["latency"][0] == ("none", None) and missing["other_alerts"] == 1
    assert f"no alert for the move at {moves[0].t_start - SPAN[0]:.1f} s" in "; ".join(missing["bad"])
    assert "1 alert(s) for no move" in missing["bad"]
    # the same move in time reported NOT TRACKING: flagged, not a miss
    blind = live(_scan(patient, [(moves[0].t_start - 1.0, moves[0].t_end + 0.2)], alerts[1:]), moves)
    assert blind["flagged"] == 1 and not any(b.startswith("no alert") for b in blind["bad"])
    rows = [
        {"seed": 1, "cameras": 2, "loss": 5.0, "load": False, "live": silent, "offline": None, "bad": silent["bad"]}
    ]
    lines, failed = verdicts(rows)
    assert failed and any(
        ln.startswith("any loss: no blind time unreported") and "missed in 1 of 1" in ln for ln in lines
    )


def _analysis(tmp_path, patient, times, *, no_frames_s, rate, events, noise_mm=0.02):
    """An analysis' JSON and motion_6dof.csv whose pose is the truth plus noise on the grid."""
    t = np.arange(SPAN[0], SPAN[1], P)
    seen = np.isin(np.round(t / P), np.round((times["cam1"] - 0.002) / P))
    rng = np.random.default_rng(3)
    export = tmp_path / "export"
    export.mkdir(exist_ok=True)
    lines = ["time_s,tx_mm,ty_mm,tz_mm,rx_deg,ry_deg,rz_deg,quality"]
    for x, ok in zip(t, seen):
        six = patient.six_dof(float(x)) + rng.normal(0, noise_mm, 6)
        lines.append(f"{x - SPAN[0]:.4f}," + (",".join(f"{v:.4f}" for v in six) + ",ok" if ok else ",,,,,,no frames"))
    (export / "motion_6dof.csv").write_text("\n".join(lines) + "\n")
    data = {
        "time_origin": SPAN[0],
        "coverage": {"share": float(seen.mean()), "no_frames_s": no_frames_s, "duration_s": SPAN[1] - SPAN[0]},
        "breathing": {"status": "measured", "rate_per_min": rate, "rate_range_per_min": [rate - 0.3, rate + 0.3]},
        "events": events,
    }
    return SimpleNamespace(analysis=json.loads(json.dumps(data)), export=export)


def test_offline_figures_are_scored_against_the_truth(tmp_path, patient):
    times = _times()
    moves = [m for m in patient.motion.moves if SPAN[0] <= m.t_start <= SPAN[1]]
    truth_rate = true_rate(patient, SPAN[0], SPAN[1])
    events = [{"t_start": m.t_start - SPAN[0] + 0.1, "start_bounds_s": None} for m in moves]
    scan = _analysis(tmp_path, patient, times, no_frames_s=2.0, rate=truth_rate + 0.2, events=events)
    scan.truth = SimpleNamespace(patient=patient, times=times, period=P)
    o = offline(scan, moves)
    assert o["true_covered"] == pytest.approx(1 - 2.0 / 40.0, abs=0.002)
    assert o["rate"]["err"] == pytest.approx(0.2) and o["rate"]["status"] == "measured"
    assert o["pose"][0] < 0.06 and o["pose"][1] < 0.06
    assert o["moves"]["found"] == len(moves) and o["moves"]["max_err"] == pytest.approx(0.1)
    assert o["bad"] == []
    # the same analysis claiming no time without frames, a wrong rate and a move 0.8 s off
    events[0]["t_start"] += 0.7
    scan = _analysis(tmp_path, patient, times, no_frames_s=0.0, rate=truth_rate + 0.9, events=events, noise_mm=0.4)
    scan.truth = SimpleNamespace(patient=patient, times=times, period=P)
    o = offline(scan, moves)
    text = "; ".join(o["bad"])
    assert "time without frames 0.0 s reported, 2.0 s truly" in text and "(measured)" in text
    assert "not found" in text and "pose" in text


def test_the_cpu_load_is_started_and_stopped():
    import os

    with cpu_load(2) as pids:
        assert len(pids) == 2 and all(os.path.exists(f"/proc/{p}") for p in pids)
    for p in pids:
        assert not os.path.exists(f"/proc/{p}") or "Z" in open(f"/proc/{p}/stat").read().split()[2]
