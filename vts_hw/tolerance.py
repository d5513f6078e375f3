"""Tolerance windows and states, after QATrack+.

A window has up to four limits: action low <= tolerance low <= tolerance high <= action high.
A value outside an action limit is ACTION, outside a tolerance limit TOLERANCE, else OK. A
missing limit is no limit. A run's state is the worst of its measurements' states.

The defaults below are what a physicist would accept for the reference rig (1.25 mm per
pixel at the wall, about 1.11 mm per pixel at the FOV centre); a rig.yaml ``tolerances:``
section overrides them per metric. docs/operate/daily-qa.md ("Tolerances") lists them.
"""

from __future__ import annotations

import enum
import math
from dataclasses import asdict, dataclass


class State(str, enum.Enum):
    OK = "OK"
    TOLERANCE = "TOLERANCE"
    ACTION = "ACTION"

    @property
    def rank(self) -> int:
        return _RANK[self]

    def __str__(self) -> str:
        return self.value


_RANK = {State.OK: 0, State.TOLERANCE: 1, State.ACTION: 2}


def worst(states) -> State:
    """The worst of some states (OK when there are none)."""
    out = State.OK
    for s in states:
        s = State(s)
        if s.rank > out.rank:
            out = s
    return out


@dataclass(frozen=True)
class Window:
    action_low: float | None = None
    tolerance_low: float | None = None
    tolerance_high: float | None = None
    action_high: float | None = None
    unit: str = ""

    def __post_init__(self):
        vals = [
            v for v in (self.action_low, self.tolerance_low, self.tolerance_high, self.action_high) if v is not None
        ]
        if vals != sorted(vals):
            raise ValueError("a tolerance window needs action_low <= tolerance_low <= tolerance_high <= action_high")

    def state(self, value: float | None) -> State:
        """The state of a value; a value that could not be measured (None or NaN) is ACTION."""
        if value is None or (isinstance(value, float) and math.isnan(value)):
            return State.ACTION
        if (self.action_low is not None and value < self.action_low) or (
            self.action_high is not None and value > self.action_high
        ):
            return State.ACTION
        if (self.tolerance_low is not None and value < self.tolerance_low) or (
            self.tolerance_high is not None and value > self.tolerance_high
        ):
            return State.TOLERANCE
        return State.OK

    def as_dict(self) -> dict:
        return asdict(self)

    def describe(self) -> str:
        """The window as a person reads it: ``OK within ±1, ACTION beyond ±2 px``, ``OK ≤ 0,
        ACTION above 1 markers``, ``ACTION below 1``, ``OK 0.99 … 1.01, ACTION outside 0.98 …
        1.02`` (one wording for every page and report; a missing bound is no bound, never ∞)."""
        tl, th, al, ah = self.tolerance_low, self.tolerance_high, self.action_low, self.action_high
        parts = []
        if tl is not None and th is not None:
            parts.append(f"OK within ±{th:g}" if th > 0 and math.isclose(tl, -th) else f"OK {tl:g} … {th:g}")
        elif th is not None:
            parts.append(f"OK ≤ {th:g}")
        elif tl is not None:
            parts.append(f"OK ≥ {tl:g}")
        if al is not None and ah is not None:
            parts.append(
                f"ACTION beyond ±{ah:g}" if ah > 0 and math.isclose(al, -ah) else f"ACTION outside {al:g} … {ah:g}"
            )
        elif ah is not None:
            parts.append(f"ACTION above {ah:g}")
        elif al is not None:
            parts.append(f"ACTION below {al:g}")
        return (", ".join(parts) + f" {self.unit or ''}").strip()

    @classmethod
    def symmetric(cls, tolerance: float, action: float, unit: str = "") -> Window:
        return cls(-action, -tolerance, tolerance, action, unit)


# metric name -> default window. Drift is the mean displacement of the wall markers from their
# baseline, per camera and axis (1 px is 1.25 mm at the wall, about 1.1 mm at the FOV centre).
DEFAULT_TOLERANCES: dict[str, Window] = {
    "drift_x_px": Window.symmetric(1.0, 2.0, "px"),
    "drift_y_px": Window.symmetric(1.0, 2.0, "px"),
    # frame-to-frame SD of the marker displacement: a shaking mount or a failing sensor
    "drift_sd_px": Window(tolerance_high=0.1, action_high=0.3, unit="px"),
    # baseline markers not found (1 is worth a look, 2 or more leave too few to trust the drift)
    "markers_missing": Window(tolerance_high=0, action_high=1, unit="markers"),
    # bright blobs that are not baseline markers (a reflection, a new object on the wall)
    "stray_blobs": Window(tolerance_high=0, unit="blobs"),
    # markers still bright with the LED switched off: the LED did not switch (or stray light)
    "led_off_visible": Window(tolerance_high=0, action_high=0, unit="markers"),
    # the camera answered (1) or not (0)
    "camera_reachable": Window(action_low=1),
    # camera clock minus host clock: scans measure and correct it, this catches a broken NTP
    "clock_offset_s": Window.symmetric(5.0, 60.0, "s"),
    # parameters that differ from the locked configuration (resolution, compression, fps)
    "params_changed": Window(tolerance_high=0, action_high=0, unit="params"),
    # 7-sphere steps, VTS against SPECT over every sphere and position. The reference system
    # reached mean differences of 0.3-0.4 mm, max 1.1-1.3 mm and rotation differences of
    # 0.1-0.6 deg; a 1 % scale error is 1 mm over the 10 cm the steps cover.
    "steps_slope": Window(0.98, 0.99, 1.01, 1.02),
    "steps_intercept_mm": Window.symmetric(1.0, 2.0, "mm"),
    "steps_r2": Window(action_low=0.995, tolerance_low=0.999),
    "steps_diff_mean_mm": Window(tolerance_high=0.6, action_high=1.0, unit="mm"),
    "steps_diff_max_mm": Window(tolerance_high=1.5, action_high=2.5, unit="mm"),
    "steps_diff_sd_mm": Window(tolerance_high=0.5, action_high=1.0, unit="mm"),
    "steps_rotation_diff_deg": Window.symmetric(0.75, 1.5, "deg"),
    "steps_translation_diff_mm": Window.symmetric(0.75, 1.5, "mm"),
    # VTS -> SPECT mapping from the 7-sphere phantom: the fit's FRE (the mapping refuses a fit
    # over 2 mm: a wrong correspondence) and the leave-one-out TRE, which predicts the error at
    # a point not used in the fit (simulated: 0.05 and 0.08 mm)
    "mapping_fre_mm": Window(tolerance_high=1.0, action_high=2.0, unit="mm"),
    "mapping_tre_rms_mm": Window(tolerance_high=1.5, action_high=3.0, unit="mm"),
    # camera calibration from checkerboards: the RMS reprojection error per camera and of the
    # whole set (corner noise gives 0.05-0.5 px; above 1 px the fit is not trusted and not
    # written without --force), and whether the bundle adjustment converged (1) or not (0)
    "calibration_rms_px": Window(tolerance_high=0.5, action_high=1.0, unit="px"),
    "calibration_converged": Window(action_low=1),
    # sync check, VTS against SPECT per motion event both saw: the project's goal is 20 ms; 100 ms
    # is what the system this replaces achieved. An event seen by one system only is worth a
    # look; no event seen by both leaves nothing checked.
    "sync_max_abs_dt_ms": Window(tolerance_high=20.0, action_high=100.0, unit="ms"),
    "sync_events_one_system": Window(tolerance_high=0, unit="events"),
    "sync_events_both": Window(action_low=1, unit="events"),
    # patient motion over a scan, breathing excluded: the largest displacement of the patient
    # markers' centroid and the largest turn from the reference pose. One SPECT pixel (~6.4 mm)
    # can already cause artefacts: half of it is worth a look, a whole one needs correction or
    # a repeat. Poses fitted in fewer than 95 % of the frames (markers hidden) are worth a look.
    "motion_body_max_mm": Window(tolerance_high=3.2, action_high=6.4, unit="mm"),
    "motion_body_max_deg": Window(tolerance_high=1.0, action_high=2.0, unit="deg"),
    "motion_pose_coverage": Window(action_low=0.8, tolerance_low=0.95, unit="fraction"),
    # commissioning's warm-up: how fast the wall markers' mean position still moves (px/min,
    # fitted over rig.yaml's warmup: window). A warming fixed camera moves some px over its first
    # 10-30 min; 0.05 px/min is 0.06 mm a minute at the wall, 3 px in an hour only if it never slows.
    "warmup_rate_px_min": Window(tolerance_high=0.05, unit="px/min"),
    # ... and how fast each camera's clock's rate against the host's still changes (ppm/min, over the same
    # window; procedures/warmup_clock.py). A 30-min scan's clock line-up, one straight line, is off by up to
    # T²/12 times it at its ends: 5 ppm/min is 22 ms there (2.5 ms for a 10-min scan), and it is what the
    # default window tells from 1 ms clock readings (±1.6 ppm/min); a room with 12 samples tells ±0.3
    "warmup_clock_change_ppm_min": Window(tolerance_high=5.0, unit="ppm/min"),
}


def merged_tolerances(overrides: dict | None, defaults: dict[str, Window]) -> dict[str, Window]:
    """``defaults`` with the rig config's windows (objects with the same fields) on top. Readers
    ask ``vts_hw.catalog.windows(overrides)``, whose defaults are this table's and the catalog
    entries' own (decision 0101)."""
    out = dict(defaults)
    for metric, w in (overrides or {}).items():
        if isinstance(w, Window):
            out[metric] = w
        else:
            d = w.model_dump() if hasattr(w, "model_dump") else dict(w)
            out[metric] = Window(**d)
    return out
