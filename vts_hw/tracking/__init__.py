"""Tracking: markers followed over time from a recording's frames, after the scan or live.

Above :mod:`vts_hw.vision` (detection, matching, triangulation of one instant) and
:mod:`vts_hw.recording` (the folder format and capture, which never import this package), below
the procedures. After the scan: frame sets across cameras (``frame_sets``), the worker side
(``chunks``), views brought to one instant (``time_align``), identities (``identities``), the
whole recording processed (``processing``) into :class:`~vts_hw.tracking.tracks.Tracks` and
their files (``tracks``). During the scan: ``live`` (tap, online grouping, tracker, estimator,
watch). See docs/decisions/0058-tracking-room-and-report-door.md.
"""
