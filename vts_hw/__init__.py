"""vts-hw: control and QA of a stereo Visual Tracking System (VTS) for SPECT."""

import os
from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version

# Linear algebra on one thread unless the user set it (docs/decisions/0075-one-blas-thread.md):
# vts-hw's matrices are small, and OpenBLAS's idle threads wait spinning, taking a busy machine's
# cores from the recorder and the live path. NumPy and SciPy read it when they load (after this).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

try:
    __version__ = _version("vts-hw")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"
