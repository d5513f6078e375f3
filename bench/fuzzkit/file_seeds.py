"""Seeds of the files a user may hand the suite back, and of the device transcripts.

* trigger.csv: the logs the trigger box and the function generator drivers write (their
  neutral rows and wire lines) in the sessions of bench/fuzzkit/devices.py, and the same log
  with its neutral rows left out (a log written before them: converted on reading);
* SPECT points: the phantom's sphere centres as CSV (x,y,z) and as JSON;
* tracks: a synthetic patient trajectory saved by :meth:`Tracks.save` (its .csv and .json);
* positions.json: a step session's plan and positions, as :class:`StepSession` saves them;
* list-mode failure records: as :func:`write_failure_record` writes them;
* unsaved runs: the record the recorder (:mod:`vts_hw.store.recorder`) writes when the store
  refuses, through :func:`vts_hw.store.unsaved.save_unsaved`.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path


def file_seeds(put, fixture, work: Path, rec_dir: Path) -> None:
    from fuzzkit.devices import BoxResponder, FakeClock, RecordingVisa, _Quiet, device_seeds

    device_seeds(put)

    # ---- trigger.csv, written by the drivers
    from vts_hw.drivers.function_generator import FunctionGenerator
    from vts_hw.drivers.trigger import TriggerLog
    from vts_hw.drivers.trigger_box import TriggerBox
    from vts_hw.sim_devices.keysight_33500 import Keysight33500

    box_log = work / "box" / "trigger.csv"
    log = TriggerLog(box_log, clock=FakeClock())
    box = TriggerBox(
        "fuzz",
        clock=FakeClock(),
        sleep=lambda _s: None,
        log=log,
        serial_factory=lambda *a, **k: BoxResponder(),
        heartbeat=False,
    )
    q = _Quiet()
    q.call(box.configure, 10.0, 0.5)
    q.call(box.clock_mapping, 4, over_s=0.0)
    q.call(box.fire, 50)
    q.call(box.edges)
    q.call(box.stop)
    box.close()
    put("trigger_log", "box.csv", box_log.read_bytes())
    fgen_log = work / "fgen" / "trigger.csv"
    log = TriggerLog(fgen_log, clock=FakeClock())
    gen = FunctionGenerator(RecordingVisa(Keysight33500()), log=log)
    gen.configure(2.0, 0.25, 5.0, 0.0)
    gen.start()
    gen.stop()
    gen.close()
    put("trigger_log", "fgen.csv", fgen_log.read_bytes())
    neutral = (b",wave_start,", b",wave_stop,", b",clock,")
    put(
        "trigger_log",
        "legacy.csv",
        b"".join(line for line in box_log.read_bytes().splitlines(True) if not any(k in line for k in neutral)),
    )
    fixture("trigger_log", "manifest.json", (rec_dir / "manifest.json").read_bytes())
    fixture("trigger_log", "cam1.index.csv", (rec_dir / "cam1.index.csv").read_bytes())

    # ---- SPECT points (sphere centres, mm)
    from vts_hw.sim_devices.spect import phantom_centres

    pts = [[round(float(v), 3) for v in p] for p in phantom_centres()]
    put("spect_points", "points.csv", ("x,y,z\n" + "".join(f"{x},{y},{z}\n" for x, y, z in pts)).encode())
    put("spect_points", "points.json", json.dumps(pts).encode())
    put("spect_points", "points-key.json", json.dumps({"points": pts}).encode())

    # ---- a trajectory (Tracks.save writes the .csv and .json pair)
    from vts_hw.sim_devices.patient import add_patient
    from vts_hw.sim_devices.patient_tracks import synthetic_tracks
    from vts_hw.sim_devices.scene import Scene

    scene = Scene.reference(seed=1, start_epoch=1_795_000_000.0)
    patient = add_patient(scene, 1_795_000_005.0, 0.3, 1, moves=[])
    tracks, _ = synthetic_tracks(patient, 1_795_000_005.0, 0.3, fps=10.0, seed=1, wall=False)
    (work / "tracks").mkdir()
    csv_path, json_path = tracks.save(work / "tracks" / "tracks")
    put("tracks", "tracks.json", json_path.read_bytes())
    put("tracks", "tracks.csv", csv_path.read_bytes())
    fixture("tracks", "json/tracks.csv", csv_path.read_bytes())
    fixture("tracks", "csv/tracks.json", json_path.read_bytes())

    # ---- a step session's positions.json
    from vts_hw.procedures.steps import SeenPosition, step_plan

    plan = step_plan(2, 2, 10.0)
    seen = [
        SeenPosition(
            p.label,
            p.kind,
            1_795_000_000.0 + i,
            {"cam1": [[320.5, 240.25]] * 3, "cam2": [[300.0, 200.0]] * 3},
            f"vol{i}.h33",
        )
        for i, p in enumerate(plan)
    ]
    put(
        "step_positions",
        "positions.json",
        json.dumps({"plan": [asdict(p) for p in plan], "positions": [asdict(s) for s in seen]}, indent=1).encode(),
    )

    # ---- a list-mode acquisition that was not recorded
    from vts_hw.spect.listmode.failures import write_failure_record

    (work / "failed").mkdir()
    put(
        "listmode_failures",
        "scan.failed.json",
        write_failure_record(
            work / "failed",
            "scan.vtslm",
            "the disk was full",
            by="the simulated SPECT",
            start=1_795_000_000.0,
            end=1_795_000_060.0,
            log=work / "failed" / "spect.log",
        ).read_bytes(),
    )
    put(
        "listmode_failures",
        "edge-huge.json",
        b'{"format": "vts-listmode-failure/1", "by": "x", "listmode": "a", '
        b'"reason": "r", "start": null, "end": null, "failed_at": 1' + b"0" * 400 + b"}",
    )

    # ---- an unsaved run, as the recorder keeps it when the store refuses
    from vts_hw.store.unsaved import save_unsaved

    record = {
        "procedure": "drift",
        "rig": "fuzz",
        "operator": "qa",
        "config_digest": "0" * 64,
        "software_version": "0.0",
        "started": 1_795_000_000.0,
        "finished": 1_795_000_060.0,
        "state": "TOLERANCE",
        "store_error": "database is locked",
        "measurements": [
            {"subject": "cam1", "metric": "drift_px", "value": 0.4, "unit": "px", "state": "OK"},
            {"subject": "cam2", "metric": "drift_px", "value": None, "unit": "px", "state": "ACTION"},
        ],
        "artifacts": [str(work / "plot.png")],
        "results": {"drift_px": [0.4, None]},
    }
    path, _ = save_unsaved(f"sqlite:///{work / 'store' / 'results.db'}", record)
    if path is None:
        raise SystemExit("fuzz seeds: save_unsaved wrote nowhere")
    put("unsaved", "drift.json", Path(path).read_bytes())
