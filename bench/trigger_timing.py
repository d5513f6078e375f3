"""Trigger box timing, on the real firmware in the emulator through the real serial driver.

    .venv/bin/python bench/trigger_timing.py [--seconds 60] [--fires 10]

Prints, measured in one run:
1. the latency from the host writing ``*TRG`` to the first rising edge of the square wave:
   on the device (the emulated cycle the command's last byte arrived → the edge, exact) and
   host to edge (the edge's device time mapped to host time by the fitted clock mapping);
2. the error of the host↔device clock mapping over ``--seconds``: a mapping fitted in the
   first 2 s predicts the host time of later ``TIME?`` replies; printed is the prediction
   minus the round trip's midpoint (which is itself only known to ± half the round trip).
"""

from __future__ import annotations

import argparse
import statistics
import time

from vts_hw.drivers.trigger_box import TriggerBox
from vts_hw.sim_devices.trigger_box import F_CPU, SimTriggerBox


def fire_latency(box: SimTriggerBox, drv: TriggerBox, fires: int) -> tuple[list[float], list[float]]:
    device_us, host_ms = [], []
    drv.configure(100.0, 0.5)
    drv.fire_pulse_ms = 5
    for _ in range(fires):
        n_edges = len(box.edges("OC1A"))
        n_uart = len(box.uart())
        t_send = time.time()
        drv.fire()
        box.wait_cycles(int(0.05 * F_CPU))
        edge = next(e for e in box.edges("OC1A")[n_edges:] if e.value == 1)
        rx = [u for u in box.uart()[n_uart:] if u.direction == "RX"]
        text = bytes(u.value for u in rx)
        end_of_trg = rx[text.index(b"*TRG\n") + 4].cycle  # the newline that completes *TRG
        device_us.append((edge.cycle - end_of_trg) / F_CPU * 1e6)
        host_ms.append((drv.mapping.to_host(edge.cycle / (F_CPU / 1e6)) - t_send) * 1e3)
        drv.stop()
    return device_us, host_ms


def mapping_error(drv: TriggerBox, seconds: float, every: float = 5.0):
    """Round trips every ``every`` s; errors of the 2-s mapping and of the whole-run mapping."""
    early = drv.clock_mapping(samples=20, over_s=2.0, history=False)
    t0 = time.time()
    trips = []
    while time.time() - t0 < seconds:
        time.sleep(every)
        sent = time.time()
        us = drv.device_time_us()
        received = time.time()
        trips.append((sent, received, us))
        drv.clock_mapping(samples=6, over_s=0.2)  # keeps adding to the whole-run fit
    final = drv.mapping
    rows = [
        (r - t0, (early.to_host(us) - (s + r) / 2) * 1e6, (final.to_host(us) - (s + r) / 2) * 1e6, (r - s) * 1e6)
        for s, r, us in trips
    ]
    return rows, final


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--fires", type=int, default=10)
    args = ap.parse_args()
    with SimTriggerBox() as box, TriggerBox(box.port) as drv:
        drv.identify()
        drv.clock_mapping(samples=20, over_s=2.0, history=False)
        dev, host = fire_latency(box, drv, args.fires)
        print(f"*TRG -> first rising edge, {args.fires} fires at 100 Hz:")
        print(
            f"  on the device (last command byte in -> edge): median {statistics.median(dev):.1f} us, "
            f"max {max(dev):.1f} us"
        )
        print(
            f"  host write -> edge (via the clock mapping):   median {statistics.median(host):.3f} ms, "
            f"max {max(host):.3f} ms  (5 bytes at 115200 baud alone are 0.434 ms)"
        )
        rows, final = mapping_error(drv, args.seconds)
        print(
            f"clock mapping checked for {args.seconds:g} s on fresh TIME? round trips (error = mapped host time "
            f"minus the round trip's midpoint):"
        )
        print(f"  {'t (s)':>7} {'fit on first 2 s (us)':>22} {'fit on the whole run (us)':>26} {'round trip (us)':>16}")
        for t, e_early, e_final, rtt in rows:
            print(f"  {t:7.1f} {e_early:22.1f} {e_final:26.1f} {rtt:16.1f}")
        rtt = statistics.median(r for *_, r in rows)
        w_early = max(abs(r[1]) for r in rows)
        w_final = max(abs(r[2]) for r in rows)
        print(
            f"  largest |error|: {w_early:.0f} us extrapolating a 2-s fit over {rows[-1][0]:.0f} s, "
            f"{w_final:.0f} us with the fit over the whole run; median round trip {rtt:.0f} us "
            f"(whole-run error / half round trip = {w_final / (rtt / 2):.2f})"
        )
        print(
            f"  whole-run fit: drift {final.drift_ppm:+.3f} ppm (the emulator is paced by this host's clock, "
            f"so 0 is the truth), residual {final.residual_s * 1e6:.1f} us, {final.samples} samples"
        )


if __name__ == "__main__":
    main()
