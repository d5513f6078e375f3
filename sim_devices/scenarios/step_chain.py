"""The whole measuring chain on the simulated rig, scored against the truth.

1. Stereo calibration from checkerboard views rendered by the simulator (as an operator would
   hold the board: :func:`vts_hw.sim_devices.checkerboard.render_pairs`), 30 mm squares.
2. VTS → SPECT mapping: the phantom at its placement, snapshots through the Axis driver over
   HTTP, and a SimSpect volume; :meth:`SpectMapping.from_stereo`.
3. The step test (:class:`~vts_hw.procedures.steps.StepSession`) with the simulated table
   (:class:`~vts_hw.sim_devices.step_table.SimTable`) and SPECT.
4. The scores against the truth the simulator kept:

   * ``position_rms_mm`` — the VTS's sphere positions over every position against the true
     ones after the best rigid alignment: the VTS's own 3D accuracy (shape and scale),
     whatever the mapping;
   * ``mapped_rms_mm`` — the same through the VTS → SPECT mapping as measured (the SPECT's own
     centroid errors enter through the mapping);
   * ``move_rotation_error_deg`` / ``move_translation_error_mm`` — the 6-DOF move from the
     first position to the last as the VTS saw it, against the true move (rotation angle of
     the difference; distance between the phantom-centre shifts).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from vts_hw.camera_led import light
from vts_hw.procedures.spect_mapping import SpectMapping
from vts_hw.procedures.steps import LED_SETTLE_S, SNAPSHOT_COMPRESSION, StepSession, average_centroids, step_plan
from vts_hw.procedures.steps_analysis import StepAnalysis, six_dof
from vts_hw.room import Room
from vts_hw.sim_devices import checkerboard as cb
from vts_hw.sim_devices.rig import SimRig
from vts_hw.sim_devices.spect import SimSpect
from vts_hw.sim_devices.step_table import SPECT_MATRIX, SimSpectSource, SimTable, sphere_centres
from vts_hw.store.recorder import record
from vts_hw.vision.calibration import calibrate_stereo
from vts_hw.vision.detect import detect_jpeg
from vts_hw.vision.registration import kabsch


@dataclass
class SimStepsResult:
    analysis: StepAnalysis
    calibration: object
    mapping: object
    truth: dict[str, np.ndarray]
    scores: dict
    out_dir: Path
    run_id: int | None = None
    artifacts: list[Path] = field(default_factory=list)
    stored: object = None  # where the run went (store.recorder.Stored), when a store was given


def score(analysis: StepAnalysis, truth: dict[str, np.ndarray], mapping_transform) -> dict:
    """How the VTS did against the truth (see the module's doc)."""
    true = np.array([truth[lab] for lab in analysis.labels])  # P×7×3, S1..S7
    # the analysis orders the spheres as the SPECT found them: each to its nearest true sphere
    order = np.argmin(np.linalg.norm(analysis.spect[0][:, None, :] - true[0][None, :, :], axis=2), axis=1)
    if len(set(order.tolist())) != true.shape[1]:
        raise RuntimeError("the SPECT centroids do not pair one-to-one with the true spheres")
    true = true[:, order]
    vts = analysis.vts
    vts_own = mapping_transform.inverse().apply(vts.reshape(-1, 3))  # back in the VTS frame
    fit = kabsch(vts_own, true.reshape(-1, 3))
    rigid_err = np.linalg.norm(fit.apply(vts_own) - true.reshape(-1, 3), axis=1)
    mapped_err = np.linalg.norm(vts - true, axis=2)
    mv_vts, mv_true = six_dof(vts[0], vts[-1]), six_dof(true[0], true[-1])
    d_rot = mv_vts.transform.R @ mv_true.transform.R.T
    angle = float(np.degrees(np.arccos(np.clip((np.trace(d_rot) - 1) / 2, -1.0, 1.0))))
    spect_err = np.linalg.norm(analysis.spect - true, axis=2)
    return {
        "position_rms_mm": float(np.sqrt(np.mean(rigid_err**2))),
        "position_max_mm": float(rigid_err.max()),
        "mapped_rms_mm": float(np.sqrt(np.mean(mapped_err**2))),
        "move_rotation_error_deg": angle,
        "move_translation_error_mm": float(np.linalg.norm(mv_vts.translation_mm - mv_true.translation_mm)),
        "true_move": {
            "rotation_xyz_deg": mv_true.rotation_xyz_deg.tolist(),
            "translation_mm": mv_true.translation_mm.tolist(),
        },
        "spect_centroid_rms_mm": float(np.sqrt(np.mean(spect_err**2))),
    }


def run_sim_steps(
    out_dir,
    seed: int = 0,
    *,
    frames: int = 10,
    n_vertical: int = 10,
    n_axial: int = 10,
    poses: int = 20,
    store=None,
    tolerances=None,
    operator: str = "sim",
    progress: Callable[[str], None] | None = None,
    plot: bool = True,
    rig=None,
    compression: int | None = None,
    rig_name: str | None = None,
) -> SimStepsResult:
    """Calibrate, map and run the step test on a simulated rig (``rig``, a running SimRig, or
    one of its own); score it."""
    import contextlib
    import time

    say = progress or (lambda m: None)
    compression = SNAPSHOT_COMPRESSION if compression is None else compression
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with contextlib.ExitStack() as stack:
        if rig is None:
            rig = stack.enter_context(SimRig(n_cameras=2, seed=seed))
        stack.enter_context(rig.env())
        cfg = rig.config()
        scene = rig.scene
        if "phantom" not in scene.bodies:
            scene.add_phantom()
        clock = rig.clock.now
        say(f"stereo calibration from {poses} rendered checkerboard views")
        pairs, names = cb.render_pairs(scene, n=poses, seed=seed, t=clock())
        calib = calibrate_stereo(
            pairs, square=cb.SQUARE_MM, unit="mm", names=names, cameras=tuple(c.name for c in cfg.cameras[:2])
        )
        calib.save(out / "calibration.json")
        own = [c.rms for c in calib.camera_fits]
        say(f"  RMS {own[0]:.3f} / {own[1]:.3f} / {calib.rms:.3f} px")
        with Room(cfg, clock=clock) as room:  # its cameras closed with it
            cams = [room.camera(c.name) for c in cfg.cameras[:2]]
            for cam in cams:
                light(cam)  # a simulated rig's cameras are Axis cameras, with their LED
            time.sleep(LED_SETTLE_S)
            say("VTS -> SPECT mapping from the phantom at its placement")
            pts = [
                average_centroids([detect_jpeg(cam.snapshot(compression).jpeg) for _ in range(frames)]) for cam in cams
            ]
            vol = SimSpect(matrix=SPECT_MATRIX, seed=seed * 1009 + 999).write(
                out / "mapping-volume.npz", sphere_centres(scene, clock())
            )
            mapping = SpectMapping.from_stereo(calib, pts[0], pts[1], vol).analyze()
            mapping.save(out / "spect_mapping.json")
            say(f"  FRE {mapping.fre_mm:.2f} mm, leave-one-out TRE {mapping.fitted().tre.rms:.2f} mm")
            # a virtual clock moves on a little per position, as the table would take time
            settle = (lambda: rig.clock.advance(20.0)) if hasattr(rig.clock, "advance") else None
            table = SimTable(scene, clock, seed=seed, settle=settle)
            spect = SimSpectSource(scene, clock, out / "spect", seed=seed)
            started = clock()
            session = StepSession(
                cams,
                calib,
                mapping.transform,
                table,
                spect,
                out,
                plan=step_plan(n_vertical, n_axial),
                frames=frames,
                progress=say,
                clock=clock,
                compression=compression,
            )
            session.acquire()
    analysis = session.analyze(tolerances)
    result = SimStepsResult(
        analysis, calib, mapping, dict(table.truth), score(analysis, spect.truth, mapping.transform), out
    )
    if plot:
        png = out / "steps.png"
        analysis.plot(png)
        result.artifacts.append(png)
    if store is not None:
        result.stored = record(
            store,
            analysis,
            tolerances=tolerances,
            rig=rig_name or cfg.rig,
            operator=operator,
            started=started,
            config_digest=cfg.digest,
            artifacts=result.artifacts,
            clock=clock,
        )
        result.run_id = result.stored.run_id
    return result
