"""Where the suite's time goes: with ``VTS_TIMELINE=FILE`` pytest (conftest.py) writes a line
per test (JSON): the worker, the test, when it started and ended (wall clock), and the CPU it
took in the test process and in the child processes it waited for (``RUSAGE_CHILDREN``: `vts`
commands, simulators; not a child still running at the test's end). ``tools/timeline-report``
reads it. Nothing is written without the variable."""

from __future__ import annotations

import json
import os
import resource
import time

import pytest


def _cpu(who) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    path = os.environ.get("VTS_TIMELINE")
    if not path:
        yield
        return
    t0, s0, c0 = time.time(), _cpu(resource.RUSAGE_SELF), _cpu(resource.RUSAGE_CHILDREN)
    yield
    line = {
        "worker": os.environ.get("PYTEST_XDIST_WORKER", "main"),
        "test": item.nodeid,
        "start": t0,
        "end": time.time(),
        "self_cpu": _cpu(resource.RUSAGE_SELF) - s0,
        "child_cpu": _cpu(resource.RUSAGE_CHILDREN) - c0,
    }
    with open(path, "a", encoding="utf-8") as f:
        f.write(json.dumps(line) + "\n")
