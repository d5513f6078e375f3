"""How precisely a SPECT motion event is timed: an edge fitted to the raw counts against the
mid-crossing interpolated between binned centres of mass (50 and 100 ms bins).

    .venv/bin/python bench/sync_edge_timing.py [--trials 100] [--seed 5]

Synthetic counts, offline: one 15 mm move along Z with the simulator's minimum-jerk profile
over 0.3 s, Poisson arrivals at 3000, 500 and 150 counts/s, 4 mm Gaussian blur; the move's
middle random in [5.0, 5.1] s, the candidate time given to the fit ±50 ms off (what
``find_steps`` hands over). The interpolation is even given the true levels (0 and 15 mm).
Prints the RMS and the largest error of each method per rate (docs/decisions/0019).
"""

from __future__ import annotations

import argparse

import numpy as np

from vts_hw.sim_devices.source_marker import min_jerk
from vts_hw.timing.marker_steps import fit_step, mid_crossing


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=100)
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args()
    rng = np.random.default_rng(args.seed)
    for rate in (3000, 500, 150):
        err = {"edge fit, raw counts": [], "interpolated, 50 ms bins": [], "interpolated, 100 ms bins": []}
        for _ in range(args.trials):
            tm = 5.0 + rng.uniform(0, 0.1)
            t = np.sort(rng.uniform(0, 10, rng.poisson(rate * 10)))
            z = 15 * min_jerk(np.clip((t - (tm - 0.15)) / 0.3, 0, 1)) + rng.normal(0, 4, t.size)
            err["edge fit, raw counts"].append(fit_step(t, z, tm + rng.uniform(-0.05, 0.05)).t_mid - tm)
            for b in (0.05, 0.1):
                n = int(round(10 / b))
                idx = np.minimum((t / b).astype(int), n - 1)
                c = np.bincount(idx, minlength=n)
                zb = np.bincount(idx, weights=z, minlength=n) / np.maximum(c, 1)
                tb = (np.arange(n) + 0.5) * b
                err[f"interpolated, {b * 1e3:.0f} ms bins"].append(mid_crossing(tb, zb, tm, 0.0, 15.0) - tm)
        parts = [
            f"{k}: RMS {1e3 * np.sqrt(np.nanmean(np.square(v))):.1f} ms, max {1e3 * np.nanmax(np.abs(v)):.1f} ms"
            for k, v in err.items()
        ]
        print(f"{rate:5d} counts/s, {args.trials} moves: " + "; ".join(parts))


if __name__ == "__main__":
    main()
