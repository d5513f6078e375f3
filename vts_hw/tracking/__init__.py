"""Tracking: markers followed over time from a recording's frames, after the scan or live.

Above :mod:`vts_hw.vision` (detection, matching, triangulation of one instant) and
:mod:`vts_hw.recording` (the folder format and capture, which never import this package), below
the procedures. Frame sets across cameras (``frame_sets``) and marker identities
(``identities``): one rule each, run online during the scan and over the recording after it.
After the scan: the worker side (``chunks``), views brought to one instant (``time_align``), the
whole recording processed (``processing``) into :class:`~vts_hw.tracking.tracks.Tracks` and
their files (``tracks``). During the scan: ``live`` (tap, tracker, estimator, watch). See docs/decisions/0058-tracking-room-and-report-door.md.
"""
