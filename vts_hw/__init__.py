"""vts-hw: control and QA of a stereo Visual Tracking System (VTS) for SPECT."""

from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("vts-hw")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"
