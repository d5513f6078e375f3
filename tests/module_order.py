"""The order the test modules are handed to the workers: longest first (tests/durations.json).

`make test` gives each of two pytest-xdist workers whole modules (--dist loadscope), the next one
in the queue as a worker frees up. pytest-xdist's own order is by the number of tests in a
module, which puts the long end-to-end modules (a few tests, a minute each) last, where one
worker runs them while the other has nothing left. Handing out the longest first (the classic
longest-processing-time rule) leaves the short modules for the end, where they even out the two
workers. The estimates are each module's seconds on an idle 2-core machine, from a timeline
(tools/timeline-report --durations); a module not in the table is estimated from its tests.

The real QATrack+'s module waits for a server that takes minutes to install the first time
(tests/conftest.py starts it in the background): it goes where half the estimated time is
already handed out, not first. docs/decisions/0077-longest-modules-first.md."""

from __future__ import annotations

import json
from pathlib import Path

TABLE = Path(__file__).with_name("durations.json")
PER_TEST_S = 0.7  # a module not in the table: its tests at the suite's median pace


def estimates() -> dict[str, float]:
    try:
        return {k: float(v) for k, v in json.loads(TABLE.read_text()).items()}
    except (OSError, ValueError, AttributeError):
        return {}


def longest_first(items: list, late: set[str] = frozenset()) -> list:
    """``items`` regrouped by module, longest module first (a module's own order kept); the
    modules in ``late`` go where half of the estimated time is handed out."""
    table = estimates()
    modules: dict[str, list] = {}
    for item in items:
        modules.setdefault(item.nodeid.split("::")[0], []).append(item)
    cost = {m: table.get(m, PER_TEST_S * len(its)) for m, its in modules.items()}
    order = sorted((m for m in modules if m not in late), key=lambda m: -cost[m])
    half, run, at = sum(cost.values()) / 2.0, 0.0, len(order)
    for i, m in enumerate(order):
        if run >= half:
            at = i
            break
        run += cost[m]
    order[at:at] = [m for m in modules if m in late]
    return [item for m in order for item in modules[m]]
