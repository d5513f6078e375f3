"""The catalog of QA procedures: each one's stored name, label, measures and units, report
figures, and whether it judges the room or a patient. Everything that names a procedure reads
it here: the procedures themselves, the drift report's history, the rooms page, the step-test
report, the QATrack+ mapping's check of its ``lists:`` keys.

A procedure's ``name`` is what its runs are stored under and is never changed once runs exist
(stores hold it: history is never rewritten). A spelling stored by an older version that must
still read as a procedure goes in its ``aliases``. Adding a procedure that is stored, reported
and pushed is its module, one :class:`Procedure` below, and its command
(docs/decisions/0057-one-recorder-one-catalog.md).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from vts_hw.tolerance import DEFAULT_TOLERANCES, Window, merged_tolerances

#: what a procedure's runs judge: the room's QA ("attention", open ACTION items on the rooms
#: page), a patient's scan (never the room's state), or nothing (a record without a state)
JUDGES = ("room", "patient", "none")


@dataclass(frozen=True)
class Figure:
    """A figure of a procedure in the reports: a metric (of one subject, or the largest over
    its subjects), its label and format."""

    metric: str
    label: str
    fmt: str
    subject: str | None = None  # None: the largest value over the subjects
    exclude: str | None = None  # with subject None: a subject left out (the set's figure)


@dataclass(frozen=True)
class Procedure:
    name: str  # as stored (runs.procedure)
    label: str  # one run, as a person says it ("step test")
    judges: str  # one of JUDGES
    measures: tuple[tuple[str, str], ...]  # (metric, unit) of its measurements
    figures: tuple[Figure, ...] = ()  # report figures; the first is the trend's
    family: str = ""  # procedures that count as one check share it ("" : its name)
    history: str = ""  # the title of its section in the drift report's history
    aliases: tuple[str, ...] = ()  # spellings stored earlier that read as this procedure
    windows: tuple[tuple[str, Window], ...] = ()  # (metric, default window) of a metric of its own

    def __post_init__(self):
        if self.judges not in JUDGES:
            raise ValueError(f"{self.name}: judges is one of {JUDGES}, not {self.judges!r}")
        measured = {m for m, _ in self.measures}
        for metric, _ in self.windows:
            if metric not in measured:
                raise ValueError(f"{self.name}: a window for {metric!r}, which it does not measure")

    @property
    def key(self) -> str:
        """The check it counts as (its family, else its name)."""
        return self.family or self.name

    @property
    def stored_as(self) -> tuple[str, ...]:
        """Every name its runs may be stored under (the name, then the older spellings)."""
        return (self.name, *self.aliases)

    def unit(self, metric: str) -> str | None:
        return dict(self.measures).get(metric)


_DRIFT = (
    ("drift_x_px", "px"),
    ("drift_y_px", "px"),
    ("drift_x_mm", "mm"),
    ("drift_y_mm", "mm"),
    ("drift_sd_px", "px"),
    ("markers_missing", "markers"),
    ("stray_blobs", "blobs"),
    ("led_off_visible", "markers"),
)
_CALIBRATION_FIGURES = (
    Figure("calibration_rms_px", "RMS of the set px", ".3f", subject="set"),
    Figure("calibration_rms_px", "worst camera px", ".3f", exclude="set"),
    Figure("calibration_converged", "converged", "g", subject="set"),
)
_CALIBRATION = (("calibration_rms_px", "px"), ("calibration_converged", ""))

DAILY = Procedure(
    "daily",
    "daily QA",
    "room",
    (("camera_reachable", ""), ("params_changed", "params"), ("clock_offset_s", "s"), *_DRIFT),
    family="daily",
)
DRIFT = Procedure("drift", "daily QA", "room", _DRIFT, family="daily")
BASELINE = Procedure(
    "drift-baseline",
    "drift baseline",
    "none",
    (("baseline_markers", "markers"), ("baseline_x_px", "px"), ("baseline_y_px", "px")),
)
STEPS = Procedure(
    "sphere-steps",
    "step test",
    "room",
    (
        ("steps_slope", ""),
        ("steps_intercept_mm", "mm"),
        ("steps_r2", ""),
        ("steps_diff_max_mm", "mm"),
        ("steps_diff_mean_mm", "mm"),
        ("steps_diff_sd_mm", "mm"),
        ("steps_rotation_diff_deg", "deg"),
        ("steps_translation_diff_mm", "mm"),
    ),
    figures=(
        Figure("steps_slope", "regression slope", ".5f"),
        Figure("steps_intercept_mm", "regression intercept (mm)", "+.3f"),
        Figure("steps_r2", "regression R²", ".6f"),
        Figure("steps_diff_max_mm", "VTS–SPECT distance, max (mm)", ".3f"),
        Figure("steps_diff_mean_mm", "VTS–SPECT distance, mean (mm)", ".3f"),
        Figure("steps_diff_sd_mm", "VTS–SPECT distance, SD (mm)", ".3f"),
        Figure("steps_rotation_diff_deg", "6-DOF move, rotation VTS − SPECT (°)", "+.3f"),
        Figure("steps_translation_diff_mm", "6-DOF move, translation VTS − SPECT (mm)", "+.3f"),
    ),
)
SYNC = Procedure(
    "sync",
    "sync check",
    "room",
    (("sync_max_abs_dt_ms", "ms"), ("sync_events_one_system", "events"), ("sync_events_both", "events")),
    figures=(
        Figure("sync_max_abs_dt_ms", "max |Δt| ms", ".1f"),
        Figure("sync_events_both", "events seen by both", "g"),
        Figure("sync_events_one_system", "seen by one only", "g"),
    ),
    history="Sync checks (VTS against SPECT)",
)
MAPPING = Procedure(
    "spect_mapping",
    "SPECT mapping",
    "room",
    (("mapping_fre_mm", "mm"), ("mapping_tre_rms_mm", "mm")),
    figures=(Figure("mapping_tre_rms_mm", "TRE RMS mm", ".3f"), Figure("mapping_fre_mm", "FRE mm", ".3f")),
    history="SPECT mappings (VTS → SPECT)",
)
#: one calibration of N cameras, the stereo pair among them (decision 0056); N-camera runs were
#: stored as "calibration_cameras" before it
CALIBRATION = Procedure(
    "calibration",
    "camera calibration",
    "room",
    _CALIBRATION,
    figures=_CALIBRATION_FIGURES,
    history="Camera calibrations",
    aliases=("calibration_cameras",),
)
MOTION = Procedure(
    "motion",
    "motion analysis",
    "patient",
    (("motion_body_max_mm", "mm"), ("motion_body_max_deg", "deg"), ("motion_pose_coverage", "fraction")),
    figures=(
        Figure("motion_body_max_mm", "max shift mm", ".2f"),
        Figure("motion_body_max_deg", "max turn °", ".2f"),
        Figure("motion_pose_coverage", "pose known (share of time)", ".3f"),
    ),
    history="Motion analyses (patient scans)",
)

#: commissioning a room (decision 0069): each step of the sequence recorded as a run of
#: ``commission-step`` (the step is its subject: ``commission_id`` names the commissioning,
#: ``step_run`` the step's own run when it is a procedure of its own, ``step_passed``), and the
#: commissioning's report as a run of ``commissioning`` (operator: who signed it off). Records,
#: not checks of the room: the steps that measure are stored as their own procedures' runs.
COMMISSION_STEP = Procedure(
    "commission-step",
    "commissioning step",
    "none",
    (
        ("commission_id", ""),
        ("step_passed", ""),
        ("step_run", ""),
        ("step_skipped", ""),
        ("camera_confirmed", ""),
        ("params_locked", "params"),
        ("trigger_answered", ""),
        ("aim_adjust", "items"),
        ("uptime_min", "min"),
        ("warming_up", ""),
    ),
)
COMMISSIONING = Procedure(
    "commissioning", "commissioning", "none", (("commission_id", ""), ("step_run", ""), ("signed_off", ""))
)
#: the steps of commissioning, in their order: (name, label); procedures/commission.py says how each
#: runs, the store's ledger and the reports name them from here
COMMISSION_STEPS: tuple[tuple[str, str], ...] = (
    ("cameras", "discover and set up the cameras"),
    ("trigger", "trigger box"),
    ("aim", "aim and focus"),
    ("warmup", "warm-up"),
    ("calibration", "calibration"),
    ("mapping", "VTS → SPECT mapping"),
    ("steps", "step test"),
    ("sync", "sync check"),
    ("baseline", "drift baseline"),
)

#: every procedure, in the order the reports list them
PROCEDURES: tuple[Procedure, ...] = (
    DAILY,
    DRIFT,
    BASELINE,
    STEPS,
    SYNC,
    MAPPING,
    CALIBRATION,
    MOTION,
    COMMISSION_STEP,
    COMMISSIONING,
)

#: a QA run of a chosen set of the daily checks is stored as ``qa:STEP+STEP`` (qa_set_name)
QA_SET_PREFIX = "qa:"
_QA_SET_RE = r"qa:[a-z+]+"


def qa_set_name(steps, all_steps) -> str:
    """The name a QA run of the daily ``steps`` is stored under: ``daily`` for all of them,
    ``drift`` for the drift alone, else ``qa:STEP+STEP``."""
    steps = tuple(steps)
    if set(steps) == set(all_steps):
        return DAILY.name
    if steps == ("drift",):
        return DRIFT.name
    return QA_SET_PREFIX + "+".join(steps)


def by_name() -> dict[str, Procedure]:
    """Every stored name (names and aliases) -> its procedure; read at each call, so that an
    entry added to :data:`PROCEDURES` is seen everywhere. ValueError when one name is given twice."""
    out: dict[str, Procedure] = {}
    for p in PROCEDURES:
        for n in p.stored_as:
            if n in out:
                raise ValueError(f"the catalog names the stored name {n!r} twice ({out[n].label}, {p.label})")
            out[n] = p
    return out


def find(name: str) -> Procedure | None:
    """The procedure whose runs are stored as ``name`` (a name or an alias); None for a name
    the catalog does not hold (a ``qa:`` set, or a procedure of another version)."""
    return by_name().get(name)


def label(name: str) -> str:
    """How a person calls a run stored as ``name`` (the name itself when not in the catalog)."""
    p = find(name)
    return p.label if p is not None else name


def by_label() -> dict[str, tuple[str, ...]]:
    """Every label -> the stored names of the runs it names, in the catalog's order (daily and
    drift QA are both "daily QA"): what a person picks to see one kind of run."""
    out: dict[str, tuple[str, ...]] = {}
    for p in PROCEDURES:
        out[p.label] = out.get(p.label, ()) + p.stored_as
    return out


def family(key: str) -> tuple[str, ...]:
    """Every stored name of the procedures that count as the check ``key`` (daily and drift QA
    are one check)."""
    return tuple(n for p in PROCEDURES if p.key == key for n in p.stored_as)


def not_room_checks() -> tuple[str, ...]:
    """The stored names whose runs never judge the room (a patient's scan, a baseline)."""
    return tuple(n for p in PROCEDURES if p.judges != "room" for n in p.stored_as)


def windows(overrides: dict | None = None) -> dict[str, Window]:
    """Every metric's default tolerance window: the table of vts_hw/tolerance.py and the windows
    the catalog's entries bring for metrics of their own, with the rig's ``tolerances:``
    (``overrides``: Windows or objects with their fields) on top. Read at each call, so that an
    entry added to :data:`PROCEDURES` is judged, stored and overridden in rig.yaml like the rest.
    ValueError when an entry's window names a metric that already has one."""
    out = dict(DEFAULT_TOLERANCES)
    for p in PROCEDURES:
        for metric, w in p.windows:
            if metric in out and out[metric] != w:
                raise ValueError(f"the catalog gives {metric!r} a second default window ({p.label})")
            out[metric] = w
    return merged_tolerances(overrides, out)


def stored_name_pattern() -> str:
    """A regular expression matching every name runs are stored under (QATrack+'s ``lists:`` keys)."""
    names = sorted(by_name(), key=lambda n: (-len(n), n))
    return "^(" + "|".join(re.escape(n) for n in names) + "|" + _QA_SET_RE + ")$"


def stored_names_text() -> str:
    """The stored names, for a sentence (``daily, drift, ..., qa:STEP+STEP``)."""
    return ", ".join([*(p.name for p in PROCEDURES), QA_SET_PREFIX + "STEP+STEP"])


def sections() -> list[tuple[str, str, tuple[str, ...], Procedure]]:
    """The drift report's history sections: (key, title, stored names, first procedure) per
    check that has a history title, in the catalog's order."""
    out: dict[str, tuple] = {}
    for p in PROCEDURES:
        if p.history and p.key not in out:
            out[p.key] = (p.key, p.history, family(p.key), p)
    return list(out.values())


by_name()  # a catalog naming one stored name twice fails at import
windows()  # ... and so does one giving a metric a second default window


__all__ = [
    "Procedure",
    "Figure",
    "PROCEDURES",
    "JUDGES",
    "by_name",
    "by_label",
    "find",
    "label",
    "family",
    "not_room_checks",
    "qa_set_name",
    "sections",
    "stored_name_pattern",
    "stored_names_text",
    "windows",
]
