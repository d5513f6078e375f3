"""The 7-sphere step test on the rig, whole: what `vts qa steps` runs, callable from a script.

1. inputs: the stereo calibration and the VTS → SPECT mapping (given, else the rig config's),
   the folder the SPECT's reconstructions arrive in (:func:`step_test_inputs`);
2. acquire every position with the cameras given (``StepSession``), the operator moving the
   table when asked — or, with ``analyze_dir``, the positions a session saved earlier;
3. analyse against the SPECT volumes and plot (:func:`run_step_test`); the caller records the
   run (vts_hw.store.recorder).

The cameras are opened by the caller (the room's: ``room.camera(name)``), never here.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from vts_hw.errors import ConfigError, DataError, UsageError
from vts_hw.files import WriteFailed
from vts_hw.procedures.mapping_inputs import camera_calibration_for
from vts_hw.procedures.steps import (
    OperatorPositioner,
    StepPosition,
    StepSession,
    VolumeFolder,
    analyze_positions,
    load_positions,
)
from vts_hw.procedures.steps_analysis import StepAnalysis
from vts_hw.vision.registration import RigidTransform


@dataclass
class StepInputs:
    calibration: object
    mapping: object
    spect: VolumeFolder


@dataclass
class StepRun:
    analysis: StepAnalysis
    started: float
    plot: Path | None
    out: Path
    #: the plot could not be written (disk full): the run is stored without it; the caller says so (exit 3)
    plot_error: WriteFailed | None = None

    @property
    def artifacts(self) -> list[Path]:
        return [self.plot] if self.plot is not None else []


def step_test_inputs(rig, calibration_path=None, mapping_path=None, volumes=None) -> StepInputs:
    """Calibration, mapping and SPECT volume folder; ConfigError (exit 2) naming what is missing."""
    calibration = camera_calibration_for(rig, calibration_path, "the step test")
    map_path = mapping_path or rig.calibration.mapping
    if map_path is None:
        raise ConfigError(
            "no VTS -> SPECT mapping: give --mapping or set calibration.mapping in the rig "
            "config (`vts calibrate spect`)."
        )
    if not volumes:
        raise UsageError(
            "give --volumes DIR: the folder the SPECT's reconstructions of the positions are (or will be) exported to"
        )
    return StepInputs(calibration, RigidTransform.load(map_path), VolumeFolder(volumes))


def step_session(
    cameras: Sequence,
    inputs: StepInputs,
    out,
    plan: list[StepPosition],
    *,
    frames: int = 10,
    ask: Callable[[str], object] = input,
    progress=None,
) -> StepSession:
    """The acquisition on the given stereo pair, the operator answering ``ask`` at each position."""
    return StepSession(
        cameras,
        inputs.calibration,
        inputs.mapping,
        OperatorPositioner(ask),
        inputs.spect,
        out,
        plan=plan,
        frames=frames,
        progress=progress,
    )


def run_step_test(
    rig,
    inputs: StepInputs,
    out,
    plan: list[StepPosition],
    *,
    cameras: Sequence = (),
    analyze_dir=None,
    frames: int = 10,
    ask: Callable[[str], object] = input,
    progress: Callable[[str], None] | None = None,
    clock: Callable[[], float] = time.time,
) -> StepRun:
    """Acquire with ``cameras`` (or read ``analyze_dir``), analyse and plot; the caller records it."""
    say = progress or (lambda m: None)
    out = Path(out)
    started = clock()
    if analyze_dir:
        seen, plan = load_positions(analyze_dir)
    else:
        seen = step_session(cameras, inputs, out, plan, frames=frames, ask=ask, progress=say).acquire()
        say(f"the VTS part is saved in {out / 'positions.json'}")
    try:
        analysis = analyze_positions(
            seen, plan, inputs.calibration, inputs.mapping, inputs.spect, rig.tolerances, progress=say
        )
    except DataError as exc:
        raise DataError(
            f"{exc} (the VTS part is kept: run `vts qa steps --analyze {out} --volumes "
            f"{inputs.spect.folder}` when that is fixed)"
        ) from None
    png = out / "steps.png"
    try:
        analysis.plot(png)
        plot_error = None
    except WriteFailed as exc:  # a full disk costs the plot, never the analysed test
        plot_error = exc
    return StepRun(analysis, started, None if plot_error else png, out, plot_error)
