"""The fuzz targets: one per parser of outside bytes, each a function of one input.

A target writes the input where its parser reads it (a file in a scratch folder on a RAM disk
when there is one) and calls the parser, and the parser's follow-up readers that a user's
command would call next. :class:`vts_hw.errors.VtsError` and its subclasses are the answers
the project promises for bad input: :meth:`Scratch.call` counts them as handled. Anything
else escapes the target and is a crash (bench/fuzz.py counts it and saves the input).

Nothing from ``vts_hw`` is imported at the top of this module: the fuzzing child process
imports the parsers inside ``atheris.instrument_imports`` (see :func:`import_parsers`), so
that their code is instrumented for coverage.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Target:
    name: str
    what: str  # the parser(s), for the table
    run: Callable[[bytes, Scratch], None]
    instrument: tuple[str, ...] = ("vts_hw",)  # modules atheris instruments for coverage
    max_len: int = 8192  # longest input the fuzzer makes
    tokens: tuple[bytes, ...] = ()  # a libFuzzer dictionary: pieces a mutation may insert
    fixtures: tuple[str, ...] = ()  # seed-folder files copied beside the input (read-only)
    uses: tuple[str, ...] = ()  # the names of SOURCES it calls (imported, instrumented, in its child)


class Scratch:
    """A per-process scratch folder; the input goes to a fixed file name in it."""

    def __init__(self, fixtures_dir: Path | None = None, fixtures=()):
        base = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None
        self.dir = Path(tempfile.mkdtemp(prefix="vts-fuzz-", dir=base))
        self.rec = self.dir / "rec"
        self.rec.mkdir()
        for name in fixtures:
            for d in (self.dir, self.rec):
                (d / name).parent.mkdir(parents=True, exist_ok=True)
                shutil.copy(fixtures_dir / name, d / name)
        self.handled = 0

    def file(self, name: str, data: bytes, folder: Path | None = None) -> Path:
        p = (folder or self.dir) / name
        with open(p, "wb") as f:
            f.write(data)
        return p

    def call(self, fn, *args):
        """``fn(*args)``; a typed error is a handled answer (counted), anything else escapes."""
        from vts_hw.errors import VtsError

        try:
            return fn(*args)
        except VtsError:
            self.handled += 1
            return None

    def close(self) -> None:
        shutil.rmtree(self.dir, ignore_errors=True)


P: dict = {}  # the parsers, filled by import_parsers()


# what each name in P is: (module, attribute), or (module, None) for the module itself
SOURCES: dict[str, tuple[str, str | None]] = {
    "config": ("vts_hw.config", None),
    "axis_jpeg": ("vts_hw.recording.axis_jpeg", None),
    "mjpeg": ("vts_hw.recording.mjpeg", None),
    "recording": ("vts_hw.recording.folder", None),
    "recording_info": ("vts_hw.recording.promised", None),
    "load_cameras": ("vts_hw.vision.camera_set", "load_cameras"),
    "load_calibration": ("vts_hw.vision.calibration_io", "load_calibration"),
    "read_listmode": ("vts_hw.spect.listmode", "read_listmode"),
    "check_session": ("vts_hw.procedures.sync", "check_session"),
    "available_cameras": ("vts_hw.recording.extent", "available_cameras"),
    "RigidTransform": ("vts_hw.vision.registration", "RigidTransform"),
    "read_dicom_nm": ("vts_hw.spect.dicom_nm", "read_dicom_nm"),
    "read_interfile": ("vts_hw.spect.interfile", "read_interfile"),
    "read_npz": ("vts_hw.spect.npz", "read_npz"),
    "axis": ("vts_hw.drivers.axis", None),
    "function_generator": ("vts_hw.drivers.function_generator", None),
    "trigger_box": ("vts_hw.drivers.trigger_box", None),
    "qatrack_client": ("vts_hw.qatrack.client", None),
    "trigger_log": ("vts_hw.recording.trigger_log", None),
    "trigger_wave": ("vts_hw.recording.trigger_wave", None),
    "Tracks": ("vts_hw.tracking.tracks", "Tracks"),
    "read_points": ("vts_hw.procedures.mapping_points", "read_points"),
    "load_positions": ("vts_hw.procedures.steps", "load_positions"),
    "session_span": ("vts_hw.procedures.sync_inputs", "session_span"),
    "ResultsStore": ("vts_hw.store", "ResultsStore"),
    "read_failure_records": ("vts_hw.spect.listmode.failures", "read_failure_records"),
    "load_unsaved": ("vts_hw.store.unsaved", "load_unsaved"),
    "import_unsaved": ("vts_hw.store.recorder", "import_unsaved"),
}


def import_parsers(names=None) -> None:
    """Import the parsers ``names`` (of SOURCES; all when None) into P. The fuzzing child calls
    it inside atheris.instrument_imports with its target's ``uses``: only those modules (and
    what they import) are instrumented, so a child starts in a fraction of a second."""
    import importlib

    for name in SOURCES if names is None else names:
        module, attr = SOURCES[name]
        mod = importlib.import_module(module)
        P[name] = mod if attr is None else getattr(mod, attr)


# ------------------------------------------------------------------------------- targets


def _mjpeg(data: bytes, s: Scratch) -> None:
    m = P["mjpeg"]
    s.call(m.read_frames_file, s.file("capture.mjpg", data))
    parser = m.MultipartParser(b"myboundary")
    step = 1 + len(data) % 509  # the stream arrives in pieces of any size
    for i in range(0, len(data), step):
        for part in parser.feed(data[i : i + step]):
            _ = part.complete
    parser.flush()
    s.call(m.boundary_from_content_type, data[:200].decode("latin-1"))


def _axis_jpeg(data: bytes, s: Scratch) -> None:
    a = P["axis_jpeg"]
    info = s.call(a.inspect_jpeg, data)
    if info is not None:
        _ = info.timestamp
    a.axis_timestamp(data)


def _index(data: bytes, s: Scratch) -> None:
    r = P["recording"]
    p = s.file("cam1.index.csv", data, s.rec)
    s.call(r.read_index, p)
    s.call(P["recording_info"].info, s.rec)  # `vts recording info`: the index against its .mjpeg


def _manifest(data: bytes, s: Scratch) -> None:
    s.file("manifest.json", data, s.rec)
    s.call(P["recording"].load_manifest, s.rec)
    s.call(P["check_session"], s.rec)  # `vts sync analyze`
    manifest = s.call(P["recording"].load_manifest, s.rec)
    s.call(P["available_cameras"], s.rec, manifest)  # `vts recording process` / `vts motion analyze`


def _listmode(data: bytes, s: Scratch) -> None:
    s.call(P["read_listmode"], s.file("scan.vtslm", data))


def _interfile(data: bytes, s: Scratch) -> None:
    s.call(P["read_interfile"], s.file("vol.h33", data))  # vol.img beside it is the seed's


def _dicom(data: bytes, s: Scratch) -> None:
    s.call(P["read_dicom_nm"], s.file("vol.dcm", data))


def _npz(data: bytes, s: Scratch) -> None:
    s.call(P["read_npz"], s.file("vol.npz", data))


def _calibration(data: bytes, s: Scratch) -> None:
    s.call(P["load_calibration"], s.file("calibration.json", data))


def _camera_calibration(data: bytes, s: Scratch) -> None:
    path = s.file("cameras.json", data)
    calib = s.call(P["load_calibration"], path)
    if calib is not None:  # what the readers of a loaded file then ask of it
        s.call(lambda: (calib.cameras(), calib.results()))
    s.call(P["load_cameras"], path)


def _mapping(data: bytes, s: Scratch) -> None:
    s.call(P["RigidTransform"].load, s.file("spect_mapping.json", data))


def _rig_yaml(data: bytes, s: Scratch) -> None:
    s.call(P["config"].load_rig, s.file("rig.yaml", data))


def _axis_vapix(data: bytes, s: Scratch) -> None:
    from fuzzkit.devices import ScriptedHTTP, drive_axis

    drive_axis(s, ScriptedHTTP(data))


def _qatrack(data: bytes, s: Scratch) -> None:
    from fuzzkit.devices import ScriptedHTTP, drive_qatrack

    drive_qatrack(s, ScriptedHTTP(data))


def _trigger_box(data: bytes, s: Scratch) -> None:
    from fuzzkit.devices import ScriptedSerial, drive_box

    drive_box(s, ScriptedSerial(data))


def _function_generator(data: bytes, s: Scratch) -> None:
    from fuzzkit.devices import ScriptedVisa, drive_fgen

    drive_fgen(s, ScriptedVisa(data))


def _trigger_log(data: bytes, s: Scratch) -> None:
    t = P["trigger_log"]
    p = s.file("trigger.csv", data, s.rec)
    s.call(t.read_trigger_rows, p)
    s.call(P["trigger_wave"].wave_from_trigger_log, p)
    s.call(P["session_span"], s.rec)  # `vts sync analyze`: which list-mode file is the session's


def _points(data: bytes, s: Scratch) -> None:
    s.call(P["read_points"], s.file("points.csv", data))
    s.call(P["read_points"], s.file("points.json", data))


def _tracks(data: bytes, s: Scratch) -> None:
    tracks = P["Tracks"]
    for name in ("tracks.json", "tracks.csv"):  # the other of the pair is the seed's
        d = s.dir / name.split(".")[1]
        s.file(name, data, d)
        t = s.call(tracks.load, d / name)
        if t is not None:  # what `vts motion` then asks of a loaded trajectory
            s.call(lambda t=t: [t.trajectory(m) for m in t.marker_ids()] + [t.marker_summary()])


def _step_positions(data: bytes, s: Scratch) -> None:
    s.file("positions.json", data, s.rec)
    s.call(P["load_positions"], s.rec)


def _unsaved(data: bytes, s: Scratch) -> None:
    p = s.file("run.unsaved.json", data)
    s.call(P["load_unsaved"], p)
    if not hasattr(s, "store"):  # `vts store import`: into a store of this process
        s.store = P["ResultsStore"](f"sqlite:///{s.dir / 'results.db'}")
    s.call(P["import_unsaved"], s.store, p)


def _listmode_failures(data: bytes, s: Scratch) -> None:
    s.file("scan.failed.json", data, s.rec)
    records = s.call(P["read_failure_records"], s.rec)
    if not records:  # a file that is not a record is left out: the answer the module documents
        s.handled += 1
    for r in records or ():  # `vts sync analyze` names them when no list-mode fits
        s.call(r.describe)


_JSON = (
    b'"',
    b"{",
    b"}",
    b"[",
    b"]",
    b",",
    b":",
    b"null",
    b"true",
    b"false",
    b"NaN",
    b"Infinity",
    b"-Infinity",
    b"1e999",
    b"-0",
    b"0.5",
    b"[[1,0,0],[0,1,0],[0,0,1]]",
    b": 5",
    b': "x"',
    b": []",
    b": {}",
    b"[[[[[[[[[[[[[[[[",
    b"1" + b"0" * 400,
)
_JPEG = (
    b"\xff\xd8",
    b"\xff\xd9",
    b"\xff\xda",
    b"\xff\xc0",
    b"\xff\xfe\x00\x0f\x0a\x01",
    b"\xff\xfe\x00\x0f\x0a\x00",
    b"\xff\x00",
    b"\xff\xd0",
    b"\xff\xff",
)

TARGETS: dict[str, Target] = {
    t.name: t
    for t in [
        Target(
            "mjpeg",
            "mjpeg.read_frames_file, MultipartParser, boundary_from_content_type",
            _mjpeg,
            uses=("mjpeg",),
            max_len=24000,
            tokens=_JPEG
            + (
                b"--myboundary\r\n",
                b"Content-Type: image/jpeg\r\n",
                b"Content-Length: ",
                b"\r\n\r\n",
                b"\n\n",
                b"multipart/x-mixed-replace; boundary=",
            ),
        ),
        Target(
            "axis_jpeg",
            "axis_jpeg.inspect_jpeg, axis_timestamp",
            _axis_jpeg,
            uses=("axis_jpeg",),
            max_len=12000,
            tokens=_JPEG,
        ),
        Target(
            "recording_index",
            "recording.read_index, recording.info",
            _index,
            uses=("recording", "recording_info"),
            fixtures=("cam1.mjpeg",),
            max_len=4096,
            tokens=(
                b"frame,offset,length,camera_time,host_time\n",
                b",",
                b"\n",
                b"\r\n",
                b"nan",
                b"inf",
                b"-1",
                b"1e999",
                b"\x00",
            ),
        ),
        Target(
            "manifest",
            "recording.load_manifest, sync.check_session, processing",
            _manifest,
            uses=("recording", "check_session", "available_cameras"),
            fixtures=("cam1.index.csv", "trigger.csv"),
            max_len=4096,
            tokens=_JSON + (b'"cameras"', b'"cam1"', b'"frames"', b'"status"', b'"gaps"'),
        ),
        Target(
            "listmode",
            "listmode.read_listmode (VTSLM)",
            _listmode,
            uses=("read_listmode",),
            max_len=16384,
            tokens=(
                b"\x89VTSLM\r\n",
                b"EVNT",
                b"TMRK",
                b"FRAM",
                b"GATE",
                b"DEAD",
                b"END ",
                b'"heads"',
                b'"duration_s"',
                b'"gate_rate_hz"',
                b"\xff\xff\xff\xff",
                b"\x00\x00\x00\x00",
            )
            + _JSON,
        ),
        Target(
            "interfile",
            "spect.interfile.read_interfile",
            _interfile,
            uses=("read_interfile",),
            fixtures=("vol.img",),
            max_len=4096,
            tokens=(
                b"!INTERFILE :=",
                b":=",
                b"!matrix size [1] := ",
                b"!number format := ",
                b"float",
                b"unsigned integer",
                b"signed integer",
                b"!number of bytes per pixel := ",
                b"imagedata byte order := BIGENDIAN",
                b"!name of data file := ",
                b"!data offset in bytes := ",
                b"scaling factor (mm/pixel) [3] := ",
                b"first pixel offset (mm) [2] := ",
                b"nan",
                b"inf",
                b"-1",
                b"0",
                b"\x00",
                b"99999999999",
            ),
        ),
        Target(
            "dicom",
            "spect.dicom_nm.read_dicom_nm",
            _dicom,
            uses=("read_dicom_nm",),
            instrument=("vts_hw", "pydicom"),
            max_len=12000,
            tokens=(
                b"DICM",
                b"NM",
                b"DS",
                b"IS",
                b"US",
                b"SQ",
                b"OW",
                b"UL",
                b"\xe0\x7f\x10\x00",
                b"\x28\x00\x10\x00",
                b"\x28\x00\x11\x00",
                b"\x28\x00\x08\x00",
                b"\x28\x00\x30\x00",
                b"\xfe\xff\x00\xe0",
                b"\xff\xff\xff\xff",
                b"1.2.840.10008.1.2.4.50",
            ),
        ),
        Target(
            "npz",
            "spect.npz.read_npz",
            _npz,
            uses=("read_npz",),
            max_len=8192,
            tokens=(
                b"PK\x03\x04",
                b"PK\x01\x02",
                b"PK\x05\x06",
                b"\x93NUMPY",
                b"data.npy",
                b"'descr': '<f4'",
                b"'shape': (",
                b"'fortran_order': True",
            ),
        ),
        Target(
            "calibration",
            "calibration_io.load_calibration (a stereo file written before one record)",
            _calibration,
            uses=("load_calibration",),
            max_len=8192,
            tokens=_JSON
            + (
                b'"K1"',
                b'"d2"',
                b'"R"',
                b'"T"',
                b'"per_view"',
                b'"skipped"',
                b'"image_size"',
                b'"unit"',
                b'"mm"',
                b'"squares"',
            ),
        ),
        Target(
            "camera_calibration",
            "calibration_io.load_calibration, camera_set.load_cameras",
            _camera_calibration,
            uses=("load_calibration", "load_cameras"),
            max_len=12000,
            tokens=_JSON
            + (
                b'"cameras"',
                b'"name"',
                b'"K"',
                b'"d"',
                b'"R"',
                b'"t"',
                b'"per_view"',
                b'"view_graph"',
                b'"image_size"',
                b'"unit"',
                b'"mm"',
                b'"format"',
                b'"vts-hw camera calibration"',
                b'"vts-hw stereo calibration"',
            ),
        ),
        Target(
            "mapping",
            "registration.RigidTransform.load",
            _mapping,
            uses=("RigidTransform",),
            max_len=4096,
            tokens=_JSON + (b'"R"', b'"t_mm"', b'"meta"', b'"format"'),
        ),
        Target(
            "rig_yaml",
            "config.load_rig",
            _rig_yaml,
            uses=("config",),
            instrument=("vts_hw", "yaml"),
            max_len=4096,
            tokens=(
                b"cameras:\n",
                b"  - name: ",
                b"    host: ",
                b"port: ",
                b"&a ",
                b"*a",
                b"!!",
                b"!!python/object:os.system",
                b"!!binary ",
                b"<<: *a",
                b"[",
                b"]",
                b"{",
                b"}",
                b": ",
                b"- ",
                b"\n",
                b"\t",
                b"---\n",
                b"...\n",
                b"%YAML 1.1\n",
                b"? ",
                b".nan",
                b".inf",
                b"~",
                b"0x1F",
                b"\xff\xfe",
                b"\xef\xbb\xbf",
                b"\x00",
            ),
        ),
    ]
}
TARGETS.update(
    {
        t.name: t
        for t in [
            Target(
                "axis_vapix",
                "drivers.axis: param.cgi lists, basicdeviceinfo, time.cgi, port.cgi, snapshot",
                _axis_vapix,
                uses=("axis",),
                max_len=16384,
                tokens=_JSON
                + (
                    b"\n--reply--\n",
                    b"HTTP 404 text/plain\n",
                    b"HTTP 200 application/json\n",
                    b"HTTP 401 text/plain\n",
                    b"HTTP 503 text/plain\n",
                    b"# Error: ",
                    b"OK",
                    b"root.",
                    b"=",
                    b"Brand.",
                    b"Properties.Firmware.Version=",
                    b'"data"',
                    b'"propertyList"',
                    b'"dateTime"',
                    b"2026-11-24T06:00:00",
                    b"Z",
                    b"+14:00",
                    b"-0001",
                    b"9999",
                ),
            ),
            Target(
                "qatrack",
                "qatrack.client: get-token, unittestcollections pages, instances, DRF errors",
                _qatrack,
                uses=("qatrack_client",),
                max_len=8192,
                tokens=_JSON
                + (
                    b"\n--reply--\n",
                    b"HTTP 200 application/json\n",
                    b"HTTP 400 application/json\n",
                    b"HTTP 401 application/json\n",
                    b"HTTP 302 text/html\n",
                    b"HTTP 500 text/html\n",
                    b'"token"',
                    b'"results"',
                    b'"next"',
                    b'"url"',
                    b'"site_url"',
                    b'"count"',
                    b'"detail"',
                    b'"non_field_errors"',
                    b'"http://evil.example/"',
                    b'"?page=2"',
                ),
            ),
            Target(
                "trigger_box",
                "drivers.trigger_box: *IDN?, OUTP?, FREQ?, EDGES?, TIME?, SYST:ERR?, ERR refusals",
                _trigger_box,
                uses=("trigger_box",),
                max_len=2048,
                tokens=(
                    b"\n",
                    b"\r\n",
                    b"OK\n",
                    b"ON\n",
                    b"OFF\n",
                    b"ERR ",
                    b"ERR -221 ",
                    b"VTS,TRIGGERBOX,",
                    b'0,"No error"\n',
                    b'-100,"Command error"\n',
                    b"18446744073709551615",
                    b"0,0,0\n",
                    b",",
                    b"-1",
                    b"nan",
                    b"inf",
                    b"1e308",
                    b"0",
                    b"\xff",
                    b"\x00",
                ),
            ),
            Target(
                "function_generator",
                "drivers.function_generator: *IDN?, SYST:ERR?, numeric and bool replies",
                _function_generator,
                uses=("function_generator",),
                max_len=2048,
                tokens=(
                    b"\n",
                    b"Agilent Technologies,33522B,MY1,4.00\n",
                    b'+0,"No error"\n',
                    b'-222,"Data out of range"\n',
                    b"SQU\n",
                    b"SIN\n",
                    b"1\n",
                    b"0\n",
                    b"ON\n",
                    b"+1.00000000000000E+01\n",
                    b"9.9E+37",
                    b"nan",
                    b"inf",
                    b"-0",
                    b"0",
                    b",",
                    b"\xff",
                    b"\x00",
                ),
            ),
            Target(
                "trigger_log",
                "recording.trigger_log: read_trigger_rows; trigger_wave: wave_from_trigger_log; sync session_span",
                _trigger_log,
                uses=("trigger_log", "trigger_wave", "session_span"),
                fixtures=("manifest.json",),
                max_len=4096,
                tokens=(
                    b"host_time,device_us,device,kind,text\r\n",
                    b",",
                    b"\r\n",
                    b'"',
                    b"wave_start",
                    b"wave_stop",
                    b"clock",
                    b"cmd",
                    b"reply",
                    b"period_s=",
                    b"duty=",
                    b"high_v=",
                    b"low_v=",
                    b"rising_edges=",
                    b"time=",
                    b"uncertainty_s=",
                    b"start_pulse=yes",
                    b"drift_ppm=",
                    b"OUTP ON",
                    b"FREQ ",
                    b"*TRG",
                    b"nan",
                    b"inf",
                    b"-1",
                    b"1e308",
                    b"99999999999999",
                ),
            ),
            Target(
                "spect_points",
                "procedures.mapping_points.read_points (CSV and JSON)",
                _points,
                uses=("read_points",),
                max_len=4096,
                tokens=_JSON + (b"x,y,z\n", b",", b"\n", b'"points"', b"\xef\xbb\xbf", b"nan", b"inf", b"1e999"),
            ),
            Target(
                "tracks",
                "tracking.tracks.Tracks.load (trajectory CSV and JSON)",
                _tracks,
                uses=("Tracks",),
                fixtures=("json/tracks.csv", "csv/tracks.json"),
                max_len=8192,
                tokens=_JSON
                + (
                    b'"cameras"',
                    b'"markers"',
                    b'"frames"',
                    b'"unpaired"',
                    b'"meta"',
                    b'"format"',
                    b",",
                    b"\n",
                    b"nan",
                    b"inf",
                    b"1e999",
                    b"marker",
                    b"x_mm",
                    b"frame",
                ),
            ),
            Target(
                "step_positions",
                "procedures.steps.load_positions (a step session's positions.json)",
                _step_positions,
                uses=("load_positions",),
                max_len=8192,
                tokens=_JSON + (b'"plan"', b'"positions"', b'"index"', b'"vertical_mm"', b'"axial_mm"'),
            ),
            Target(
                "unsaved",
                "store.unsaved.load_unsaved, store.recorder.import_unsaved (a run the store refused, kept as a file)",
                _unsaved,
                uses=("load_unsaved", "import_unsaved", "ResultsStore"),
                max_len=8192,
                tokens=_JSON + (b'"format"', b'"measurements"', b'"procedure"', b'"state"'),
            ),
            Target(
                "listmode_failures",
                "spect.listmode.failures.read_failure_records (*.failed.json)",
                _listmode_failures,
                uses=("read_failure_records",),
                max_len=4096,
                tokens=_JSON
                + (
                    b'"vts-listmode-failure/1"',
                    b'"failed_at"',
                    b'"start"',
                    b'"end"',
                    b'"by"',
                    b'"listmode"',
                    b'"reason"',
                    b'"log"',
                    b"1e300",
                    b"-1e300",
                ),
            ),
        ]
    }
)
