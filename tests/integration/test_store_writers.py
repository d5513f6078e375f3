"""Many writers at once into one store, on both back ends: 8 processes x 50 runs, and writers
killed with SIGKILL at random moments. No run lost, none duplicated, none half-written
(tests/store_writers.py does the writing and the checking; bench/store_writers.py the figures)."""

from __future__ import annotations

import os
import random

import pytest

from store_writers import run_writers


def _assert_whole(out, where: str) -> None:
    assert out.problems == [], f"{where}: {out.problems[:5]}"
    assert (out.lost, out.duplicated, out.half_written) == (0, 0, 0), where
    assert out.finished_reported > 0 and out.complete >= out.finished_reported, where


def test_eight_writers_at_once_lose_nothing(store_url, tmp_path):
    out = run_writers(store_url, tmp_path / "w", n_procs=8, per_proc=50)
    _assert_whole(out, "8 x 50")
    # every run ended: finished (400 less the ~5% the operator aborted) or aborted, nothing else
    assert out.complete == out.finished_reported and out.complete + out.aborted == 400
    assert out.aborted < 60


@pytest.mark.slow
def test_writers_killed_at_random_moments_lose_nothing(store_url, tmp_path):
    seed = int(os.environ.get("VTS_KILL_SEED", random.SystemRandom().randrange(1 << 30)))
    out = run_writers(store_url, tmp_path / "k", n_procs=8, per_proc=50, kills=5, seed=seed)
    _assert_whole(out, f"VTS_KILL_SEED={seed}")
    assert out.kills == 5
    # killed writers' runs: complete, or aborted on the reopen with nothing stored
    assert out.complete + out.aborted > out.finished_reported
