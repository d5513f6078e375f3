"""The firmware-in-the-loop tests' kit: a serial link to the trigger box firmware in simavr
(tests/integration/test_firmware.py), the edges of its output pins in emulated cycles, and how they are judged."""

from __future__ import annotations

import serial

from vts_hw.sim_devices.trigger_box import F_CPU, SimTriggerBox

US = F_CPU // 1_000_000  # cycles per microsecond
# A pin change made by a timer is logged when simavr next checks its timers, at an
# instruction boundary: up to a few cycles after the exact cycle (no drift: the timer
# itself runs on the exact cycle). Per-edge comparisons allow this much.
JITTER = 5
ALIGN = 16  # *TRG: all three rising edges within 1 us


# ---------------------------------------------------------------------------- helpers
class Link:
    """A pyserial client, as a driver would be."""

    def __init__(self, box: SimTriggerBox):
        self.box = box
        self.s = serial.Serial(box.port, 115200, timeout=10)
        self.s.reset_input_buffer()

    def line(self) -> str:
        r = self.s.readline()
        assert r.endswith(b"\n"), f"no reply line (got {r!r})"
        return r[:-1].decode("ascii")

    def ask(self, cmd: str) -> str:
        self.s.write(cmd.encode("ascii") + b"\n")
        return self.line()

    def ok(self, cmd: str) -> None:
        r = self.ask(cmd)
        assert r == "OK", f"{cmd!r} answered {r!r}"

    def wait_off(self, max_seconds: float = 30.0) -> None:
        """Poll OUTP? (every 5 ms emulated) until the wave has stopped."""
        deadline = self.box.cycles_now() + int(max_seconds * F_CPU)
        while self.ask("OUTP?") != "OFF":
            assert self.box.cycles_now() < deadline, "the wave did not stop"
            self.box.wait_cycles(F_CPU // 200)

    def reset(self) -> None:
        self.ok("*RST")
        self.wait_off()
        self.ok("*CLS")

    def close(self) -> None:
        self.s.close()


def rises(edges, pin="OC1A"):
    return [e.cycle for e in edges if e.pin == pin and e.value == 1]


def falls(edges, pin="OC1A"):
    return [e.cycle for e in edges if e.pin == pin and e.value == 0]


def run_wave(link: Link, freq: str, duty: str, seconds: float, trg: bool = False):
    """Configure, start, run `seconds` of emulated time, stop; the OC1A edges of the run."""
    box = link.box
    n0 = len(box.edges("OC1A"))
    link.ok(f"FREQ {freq}")
    link.ok(f"DUTY {duty}")
    link.ok("*TRG" if trg else "OUTP ON")
    box.wait_cycles(int(seconds * F_CPU))
    link.ok("OUTP OFF")
    link.wait_off()
    return box.edges("OC1A")[n0:]


def check_whole_periods(edges, period: int, high: int):
    """The run starts rising, alternates, every period and every high time is exact
    (within the logging jitter), and it ends low after a complete high time."""
    assert edges, "no edges"
    assert edges[0].value == 1, "the wave must start with a rising edge"
    levels = [e.value for e in edges]
    assert levels == [1, 0] * (len(edges) // 2), "edges must alternate and end low"
    r, f = rises(edges), falls(edges)
    periods = [b - a for a, b in zip(r, r[1:])]
    highs = [b - a for a, b in zip(r, f)]
    assert all(abs(p - period) <= JITTER for p in periods), (min(periods), max(periods), period)
    assert all(abs(h - high) <= JITTER for h in highs), (min(highs), max(highs), high)
    return r, f


def ppm_error(r, period: float) -> float:
    measured = (r[-1] - r[0]) / (len(r) - 1)
    return (measured - period) / period * 1e6
