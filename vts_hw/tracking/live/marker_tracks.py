"""The live path's name for the one identity tracker: :class:`MarkerTracks` and :func:`assign`
live in :mod:`vts_hw.tracking.identities` (the same rule offline; decision 0090). Kept so that
``reference.py`` and ``estimator.py`` import them as they did; new code imports from
``vts_hw.tracking.identities``.
"""

from __future__ import annotations

from vts_hw.tracking.identities import MarkerTracks, assign

__all__ = ["MarkerTracks", "assign"]
