"""One BLAS thread unless the user says otherwise (docs/decisions/0075-one-blas-thread.md): the
OpenBLAS libraries NumPy and SciPy load are asked how many threads they run, in a process that
loads vts_hw first as `vts` does, in one whose user set the number, in one without vts_hw (the
library's own default), and in this test worker (the suite's workers load vts_hw first)."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys
from pathlib import Path

NAMES = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads", "openblas_get_num_threads")


def blas_threads_here() -> list[int]:
    """Each loaded OpenBLAS's thread count, after NumPy and SciPy have each done an SVD."""
    import numpy
    import scipy.linalg

    numpy.linalg.svd(numpy.ones((40, 30)))
    scipy.linalg.svd(numpy.ones((40, 30)))
    libs = sorted(
        {ln.split()[-1] for ln in open("/proc/self/maps") if "openblas" in ln and ln.rstrip().endswith(".so")}
    )
    counts = []
    for path in libs:
        lib = ctypes.CDLL(path)
        counts.append(getattr(lib, next(n for n in NAMES if hasattr(lib, n)))())
    assert len(counts) >= 1, libs
    return counts


def blas_threads_in_a_process(vts_first: bool, **env) -> set[int]:
    code = (
        f"import sys; sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        + ("import vts_hw\n" if vts_first else "")
        + "from test_blas_threads import blas_threads_here\nprint(*blas_threads_here())"
    )
    base = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    p = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, timeout=120, env={**base, **env}, check=True
    )
    return {int(x) for x in p.stdout.split()}


def test_vts_hw_runs_blas_on_one_thread_and_a_users_setting_wins():
    assert blas_threads_in_a_process(True) == {1}
    assert blas_threads_in_a_process(True, OPENBLAS_NUM_THREADS="2") == {2}
    # without vts_hw, OpenBLAS's own default: a thread a core (so the first figure is vts_hw's doing)
    assert blas_threads_in_a_process(False) == {min(os.cpu_count() or 1, 64)}


def test_this_test_worker_runs_blas_on_one_thread():
    assert set(blas_threads_here()) == {1}
