"""The seed corpus: real and generated valid inputs of every target, written by the code.

* MJPEG and Axis JPEG: the real frames and the real multipart capture in
  ``../shared/data/axis-frames`` (its README), plus a recording's ``.mjpeg``;
* recording index and manifest: a recording written by :class:`vts_hw.recording.writer.Recording`
  from the real frames (and the manifest a scan writes: status, gaps, notes);
* list-mode: a short acquisition of the simulated SPECT (``sim_devices/spect_listmode.py``)
  and a small file made with :class:`~vts_hw.spect.listmode.VtslmWriter`;
* Interfile, DICOM NM, .npz: small volumes of the simulated SPECT written by the code's
  writers (``sim_devices/spect.py`` → ``vts_hw/spect``);
* calibration and mapping JSON, rig.yaml: written by the simulated rig (``SimRig.write``:
  its true stereo calibration and VTS → SPECT mapping, and the rig.yaml of ``vts sim up``),
  plus rig.yaml files with the sections the simulated rig leaves out.

:func:`make_seeds` writes ``DIR/seeds/<target>/*`` and ``DIR/fixtures/<target>/*`` (files a
target keeps beside its input, e.g. the Interfile's data file).
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

RIG_EXTRA = """\
rig: spect-room-1
cameras:
  - name: cam1
    host: 192.168.10.21
    port: 80
    scheme: http
    user: root
    password_env: VTS_CAM1_PASSWORD
    led_port: 1
    resolution: 640x480
    fps: 25
    compression: 25
    locked_params: {ImageSource.I0.Sensor.Exposure: 100, WB: auto}
  - {name: cam2, host: 192.168.10.22, password_env: VTS_CAM2_PASSWORD, resolution: [640, 480]}
trigger:
  backend: visa
  address: TCPIP::192.168.10.30::5025::SOCKET
  frequency_hz: 1.0
  duty: 0.5
  high_v: 5
  low_v: 0
  lines: [Dev1/port0/line0, Dev1/port0/line1]
tolerances:
  drift_px: {action_low: -2, tolerance_low: -1, tolerance_high: 1, action_high: 2, unit: px}
calibration:
  stereo: /var/lib/vts/calibration.json
  spect: /var/lib/vts/spect_mapping.json
results:
  url: sqlite:///var/lib/vts/results.db
recordings_dir: /var/lib/vts/recordings
"""


def make_seeds(out: Path, axis_frames: Path) -> dict[str, int]:
    """Write the seed corpus under ``out``; returns the number of seeds per target."""
    seeds, fixtures = out / "seeds", out / "fixtures"
    if seeds.exists():
        shutil.rmtree(seeds)
    if fixtures.exists():
        shutil.rmtree(fixtures)

    def put(target: str, name: str, data: bytes) -> None:
        d = seeds / target
        d.mkdir(parents=True, exist_ok=True)
        (d / name).write_bytes(data)

    def fixture(target: str, name: str, data: bytes) -> None:
        d = fixtures / target
        (d / name).parent.mkdir(parents=True, exist_ok=True)
        (d / name).write_bytes(data)

    work = out / "make"
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)

    # ---- real Axis frames, and a recording written from them
    from vts_hw.recording.axis_jpeg import inspect_jpeg
    from vts_hw.recording.mjpeg import read_frames_file

    try:
        from vts_hw.recording.writer import Recording  # where the writer lives after the split
    except ImportError:
        from vts_hw.recording.folder import Recording

    capture = (axis_frames / "t.mjpg").read_bytes()
    frames = [b for b, _ in read_frames_file(axis_frames / "t.mjpg")]
    put("mjpeg", "t.mjpg", capture)
    put("mjpeg", "t-3-parts.mjpg", capture[: capture.find(b"--myboundary", capture.find(frames[3]))])
    for jpg in sorted(axis_frames.glob("*.jpg")):
        put("axis_jpeg", jpg.name, jpg.read_bytes())
        put("mjpeg", jpg.name, jpg.read_bytes())
    rec_dir = work / "rec"
    with Recording(rec_dir, ["cam1", "cam2"], {"rig": "fuzz", "config_digest": "0" * 64}) as rec:
        for i, f in enumerate(frames[:6]):
            rec.write_frame("cam1", f, inspect_jpeg(f).timestamp, 1_795_000_000.0 + i * 0.06)
        rec.add_gap("cam1", {"after_frame": 2, "camera_t0": 1.0, "camera_t1": 1.2, "missing": 3})
    put("mjpeg", "cam1.mjpeg", (rec_dir / "cam1.mjpeg").read_bytes())
    put("recording_index", "cam1.index.csv", (rec_dir / "cam1.index.csv").read_bytes())
    put("recording_index", "empty.index.csv", (rec_dir / "cam2.index.csv").read_bytes())
    put("manifest", "manifest.json", (rec_dir / "manifest.json").read_bytes())
    put("manifest", "recording.json", (rec_dir / "manifest.json").read_bytes().replace(b'"complete"', b'"recording"'))
    fixture("recording_index", "cam1.mjpeg", (rec_dir / "cam1.mjpeg").read_bytes())
    fixture("manifest", "cam1.index.csv", (rec_dir / "cam1.index.csv").read_bytes())
    fixture("manifest", "trigger.csv", b"device,event,host_time\n")  # check_session wants one

    # ---- list-mode: the simulated SPECT, and a hand-made file with every block kind
    import numpy as np

    from vts_hw.sim_devices.scene import Scene
    from vts_hw.sim_devices.spect_listmode import SimSpectSettings, TriggerEdges, write_sim_listmode
    from vts_hw.spect.listmode import VtslmWriter

    t0 = 1_795_000_000.0
    rising = t0 + np.arange(4) * 0.5
    trig = TriggerEdges(rising, rising + 0.25, t0, 5.0, 0.0, "fuzz seed")
    settings = SimSpectSettings(
        background_cps=300.0,
        gate_rate_hz=100.0,
        stop_s=0.6,
        rotate_s=0.2,
        start_delay_s=0.1,
        clock_offset_s=0.5,
        clock_skew_ppm=20.0,
    )
    write_sim_listmode(work / "sim.vtslm", Scene.reference(seed=1, start_epoch=t0), [], trig, 1.2, settings, seed=3)
    put("listmode", "sim.vtslm", (work / "sim.vtslm").read_bytes())
    with VtslmWriter(
        work / "small.vtslm", start_time=t0, duration_s=0.2, gate_rate_hz=50.0, dead_time_recorded=True, scanner="fuzz"
    ) as w:
        w.events([0.01, 0.02, 0.15], [1.0, 2.0, 3.0], [-1.0, 0.0, 1.5], [0, 1, 1])
        w.timing_marks([0.0, 0.01, 0.02])
        w.frames([0.0, 0.1], [0, 1], [0.0, 3.0])
        w.gate([0.0, 5.0, 5.0, 0.0])
        w.dead([0.05], [0.08])
    put("listmode", "small.vtslm", (work / "small.vtslm").read_bytes())
    raw = (work / "small.vtslm").read_bytes()  # its start_time made a 400-digit integer
    head = raw[16 : 16 + int.from_bytes(raw[12:16], "little")]
    huge = head.replace(b'"start_time": ', b'"start_time": 1' + b"0" * 400 + b', "was": ')
    huge += b" " * (-(16 + len(huge)) % 8)
    put("listmode", "edge-huge.vtslm", raw[:12] + len(huge).to_bytes(4, "little") + huge + raw[16 + len(head) :])

    # ---- volumes: the simulated SPECT, small, through the code's writers
    from vts_hw.sim_devices.spect import SimSpect, phantom_centres

    sim = SimSpect(matrix=(6, 8, 10), voxel_size=25.0, supersample=1, seed=2)
    centres = phantom_centres()
    h = sim.write(work / "vol.h33", centres)
    put("interfile", "vol.h33", h.read_bytes())
    fixture("interfile", "vol.img", (work / "vol.img").read_bytes())
    put("dicom", "vol.dcm", sim.write(work / "vol.dcm", centres).read_bytes())
    put("npz", "vol.npz", sim.write(work / "vol.npz", centres).read_bytes())

    # ---- the simulated rig: rig.yaml, its true calibration and VTS -> SPECT mapping
    from vts_hw.sim_devices.rig import SimRig

    rig_dir = work / "rig"
    with SimRig(n_cameras=2, seed=0, password="fuzz-seed") as rig:  # the ports are in rig.yaml
        rig.write(rig_dir)
    put("rig_yaml", "rig.yaml", (rig_dir / "rig.yaml").read_bytes())
    put("rig_yaml", "full.yaml", RIG_EXTRA.encode())
    for p in rig_dir.glob("*.json"):
        target = "mapping" if "mapping" in p.name else "calibration"
        put(target, p.name, p.read_bytes())
        if target == "calibration":  # the stereo form written before; its square size made a 400-digit integer
            put(target, "stereo-v1.json", stereo_bytes(rig_dir))
            put(target, "edge-huge.json", re.sub(rb'"square": [^,]+', b'"square": 1' + b"0" * 400, p.read_bytes()))
    # ---- a calibration file: the rig's two cameras, three cameras, and the stereo form written before
    from vts_hw.vision.calibration_io import load_calibration

    multi = load_calibration(next(p for p in rig_dir.glob("*.json") if "mapping" not in p.name))
    multi.save(work / "cameras.json")
    put("camera_calibration", "two.json", (work / "cameras.json").read_bytes())
    data = json.loads((work / "cameras.json").read_text())
    third = dict(data["cameras"][1], name="cam3")
    data["cameras"].append(third)
    put("camera_calibration", "three.json", json.dumps(data).encode())
    put("camera_calibration", "stereo.json", stereo_bytes(rig_dir))
    from fuzzkit.file_seeds import file_seeds

    file_seeds(put, fixture, work, rec_dir)
    edge_seeds(put)
    return {d.name: len(list(d.iterdir())) for d in sorted(seeds.iterdir())}


def stereo_bytes(rig_dir) -> bytes:
    """A stereo file as `vts calibrate stereo` wrote them before one calibration record (tests/data)."""
    return (Path(__file__).resolve().parents[2] / "tests" / "data" / "calibration-stereo-v1.json").read_bytes()


def edge_seeds(put) -> None:
    """Valid-looking inputs at the edges a mutation reaches only slowly: JSON nested deeper
    than Python's recursion limit, a number of 400 digits (an int no float can hold), a
    value of the wrong JSON type, a YAML bomb and deep YAML nesting."""
    deep = b"[" * 1200 + b"]" * 1200
    big = b"1" + b"0" * 400
    put("manifest", "edge-deep.json", b'{"cameras": {"cam1": {"gaps": ' + deep + b"}}}")
    put("manifest", "edge-gaps.json", b'{"cameras": {"cam1": {"gaps": [{"missing": "3"}, 5]}}}')
    put("calibration", "edge-deep.json", b'{"format": "vts-hw stereo calibration", "K1": ' + deep + b"}")
    put("mapping", "edge-deep.json", b'{"R": ' + deep + b"}")
    put("mapping", "edge-meta.json", b'{"R": [[1,0,0],[0,1,0],[0,0,1]], "t_mm": [0,0,' + big + b'], "meta": 5}')
    put("rig_yaml", "edge-deep.yaml", b"rig: x\ncameras: " + b"[" * 40 + b"]" * 40 + b"\n")
    put(
        "rig_yaml",
        "edge-bomb.yaml",
        b"a: &a [x, x, x, x, x, x, x, x, x, x]\n"
        + b"".join(b"%c: &%c [" % (98 + i, 98 + i) + b", ".join([b"*%c" % (97 + i)] * 10) + b"]\n" for i in range(9)),
    )
    put("rig_yaml", "edge-date.yaml", b"rig: x\nrecordings_dir: 2024-02-30\ncameras: []\n")
