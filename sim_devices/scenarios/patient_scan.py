"""A patient scan on the simulated rig, end to end: ``vts scan start`` records the simulated
patient breathing and moving on the table, the simulated SPECT (when the rig has the trigger
box) counts the patient's heart following the trigger the box emitted, and the truth comes back
to score the motion analysis with.

For the offline motion analysis tests, its benchmark and the demo::

    rig = SimRig(n_cameras=2, trigger="triggerbox", patient=PatientOptions(seed=1, moves=2, minutes=2,
                                                                           still_s=5)).start()
    rig_yaml, _ = rig.write(folder / "rig")           # rig.yaml with the true cameras' calibration
    run = patient_scan(rig, rig_yaml, folder / "scan", 30.0)
    run.session        # the recording folder (manifest.json, cam*.mjpeg, cam*.index.csv, trigger.csv)
    run.listmode       # folder / "scan.vtslm" beside it (None without the trigger box), truth in run.spect
    run.patient        # the Patient: six_dof(t), body_transform(t), marker_truth(t), breathing, moves
    run.window         # (start, end) host UTC epoch s the recording covers: score only inside it

The rig must be a running :class:`~vts_hw.sim_devices.rig.SimRig` built with ``patient=`` (its
plan must cover the scan) whose ``write(folder)`` has been called. Nothing of the truth is
written into the session (``truth_dir``, when given, must lie outside it). Host UTC epoch
seconds throughout.

The cameras' frames for the scan are made ahead of time (``SimRig.prerender``: the scan's
duration and ``PRERENDER_MARGIN_S``), so that the recording is whole however busy the machine
is; the patient's plan starts playing with the scan's first stream (its breathing and moves
moved in time to it: read the truth from ``run.patient`` after the scan).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from vts_hw.recording.folder import load_manifest, read_index
from vts_hw.sim_devices.frame_bank import BankStats
from vts_hw.sim_devices.patient import Patient, write_truth
from vts_hw.sim_devices.patient_source import heart_source
from vts_hw.sim_devices.scenarios.sync_session import SPECT_TAIL_S, run_scan_cli
from vts_hw.sim_devices.spect_listmode import ListModeTruth, SimListModeSpect

__all__ = ["PatientScan", "patient_scan", "PRERENDER_MARGIN_S"]

# frames made ahead beyond the scan's duration: from the recording's first frame to the scan's
# start (every camera's first frame, the trigger fired) and the stop
PRERENDER_MARGIN_S = 5.0


@dataclass
class PatientScan:
    """What a simulated patient scan did."""

    session: Path  # the recording folder `vts scan start` wrote
    listmode: Path | None  # the simulated SPECT's list-mode (None: no trigger box)
    spect: ListModeTruth | None  # its truth (start delay, clock, counts' sources)
    patient: Patient  # the truth: poses, breathing, moves, marker positions
    fire_host: float  # when the trigger fired (host s)
    window: tuple[float, float]  # host s of the first and last frame recorded (any camera)
    truth_files: list[Path]  # what write_truth wrote (empty without truth_dir)
    render: BankStats | None = None  # what making the frames ahead cost (None: live)

    def moves_in_window(self) -> list:
        """The body moves that start inside :attr:`window`."""
        a, b = self.window
        return [m for m in self.patient.motion.moves if a <= m.t_start <= b]


def patient_scan(
    rig,
    rig_yaml,
    session_dir,
    duration_s: float,
    *,
    spect: bool = True,
    seed: int = 0,
    truth_dir=None,
    truth_rate_hz: float = 25.0,
    ntp_sync: bool = True,
    timeout: float | None = None,
    prerender: bool = True,
    progress=None,
) -> PatientScan:
    """Run ``vts scan start --duration D -o SESSION`` in a subprocess against the running
    ``rig`` (which has a patient), wait for it, and return the session and the truth.

    ``spect``: with the rig's trigger box, the simulated SPECT then writes the list-mode of
    the scan (``SESSION.vtslm`` beside the session, the scan less 0.6 s, counts from the
    patient's heart; ``seed`` draws its start delay, clock and counts). ``truth_dir``: also
    write the patient's truth over the recorded window (1 s margin) there, at ``truth_rate_hz``.
    ``ntp_sync``: the cameras' clocks synced first, as a clinic's are. ``prerender``: the
    frames made ahead of time (``progress(done, total)`` meanwhile); False renders them live,
    as they are asked for (on a busy machine the streams then come late or skip frames).
    ValueError when the rig
    has no patient, its plan ends before the scan would, or ``truth_dir`` is inside the
    session; RuntimeError when the scan fails (its stderr)."""
    patient = getattr(rig, "patient", None)
    if patient is None:
        raise ValueError("the rig has no patient: build it with SimRig(..., patient=PatientOptions(...))")
    session = Path(session_dir)
    plan_end = patient.breathing.t0 + patient.breathing.duration_s
    if time.time() + duration_s + 10.0 > plan_end:
        raise ValueError(
            f"the patient's plan ends {plan_end - time.time():.0f} s from now: too soon for a "
            f"{duration_s:g} s scan (give PatientOptions(minutes=...) more)"
        )
    if truth_dir is not None and _inside(Path(truth_dir), session):
        raise ValueError(f"{truth_dir}: the truth must not go into the session {session}")
    if ntp_sync:
        rig.ntp_sync()
    render = rig.prerender(duration_s + PRERENDER_MARGIN_S, progress=progress) if prerender else None
    fire = run_scan_cli(rig, rig_yaml, session, duration_s, timeout=timeout or duration_s + 90.0).fire
    window = recorded_window(session)
    listmode, spect_truth = None, None
    if spect and getattr(rig, "trigger_box", None) is not None:
        listmode = session.parent / (session.name + ".vtslm")
        spect_truth = SimListModeSpect(rig.scene, [heart_source(patient)], seed=seed).follow_trigger_box(
            rig.trigger_box, listmode, duration_s - SPECT_TAIL_S
        )
    files = []
    if truth_dir is not None:
        files = write_truth(patient, truth_dir, window[0] - 1.0, window[1] + 1.0, truth_rate_hz)
    return PatientScan(session, listmode, spect_truth, patient, fire, window, files, render)


def recorded_window(session) -> tuple[float, float]:
    """Host times of the first and last frame any camera of the session recorded."""
    manifest = load_manifest(session)
    if manifest is None:  # only with missing_ok: a folder without one raised DataError
        raise RuntimeError(f"{session}: no manifest")
    times = []
    for name in manifest.get("cameras", {}):
        rows = read_index(Path(session) / f"{name}.index.csv")
        times += [r.host_time for r in rows if r.host_time is not None]
    if not times:
        raise RuntimeError(f"{session}: the scan recorded no frame")
    return min(times), max(times)


def _inside(path: Path, folder: Path) -> bool:
    path, folder = path.resolve(), folder.resolve()
    return path == folder or folder in path.parents
