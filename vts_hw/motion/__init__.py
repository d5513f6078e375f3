"""Patient motion from marker tracks: which markers are the patient's, the respiratory signal,
the body's rigid 6-DOF pose with the breathing taken out, body-motion events and motion states,
and their exports for reconstruction. Pure computation (no driver, procedure or simulator).

Entry point: :func:`vts_hw.motion.analysis.analyze_motion` on a :class:`MarkerSeries`
(:func:`vts_hw.motion.markers.marker_series` makes one from :class:`~vts_hw.tracking.tracks.Tracks`).
The method and its reasons: docs/decisions/0035-breathing-and-body-motion.md; the files:
docs/motion-formats.md.
"""

from vts_hw.motion.analysis import MotionResult, MotionSettings, analyze_motion
from vts_hw.motion.markers import MarkerSeries, marker_series

__all__ = ["MarkerSeries", "marker_series", "MotionResult", "MotionSettings", "analyze_motion"]
