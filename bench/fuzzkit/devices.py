"""The devices' replies as fuzz inputs: one input is a transcript of what a device answers.

A driver parses what its device sends: the Axis camera's VAPIX replies, the trigger box's
serial lines, the function generator's SCPI replies, QATrack+'s JSON. Each device target
(bench/fuzzkit/targets.py) drives the real driver through a session a user's commands run
(identify, status, configure, start, stop, clock ...) against a scripted transport that
answers every request with the next reply of the input, and a transport whose replies have
run out answers as a silent device does (a timeout or refused connection). The seeds are
transcripts of the same sessions against the simulators, recorded by the same transports
(:func:`record_axis`, :func:`record_box`, :func:`record_fgen`, :func:`record_qatrack`), so a
seed replays its session exactly and a mutation changes one reply.

Transcript formats:

* HTTP (Axis, QATrack+): replies separated by ``SEP``; a reply may start with a status line
  ``HTTP <code> [<content type>]\\n`` (else 200 and no content type), then the body;
* serial (trigger box) and SCPI (function generator): one reply per line.
"""

from __future__ import annotations

import io
import itertools

SEP = b"\n--reply--\n"
T0 = 1_795_000_000.0


class FakeClock:
    """A host clock that moves 50 ms per reading (loops that wait on it end quickly)."""

    def __init__(self, t0: float = T0, step: float = 0.05):
        self.t = itertools.count()
        self.t0, self.step = t0, step

    def __call__(self) -> float:
        return self.t0 + next(self.t) * self.step


# ---- HTTP ----------------------------------------------------------------------------------


def http_reply(piece: bytes, method: str, url: str, params=None):
    """A :class:`requests.Response` as requests builds it, from one reply of a transcript."""
    import requests
    from requests.structures import CaseInsensitiveDict

    status, ctype, body = 200, None, piece
    if piece.startswith(b"HTTP "):
        line, _, body = piece.partition(b"\n")
        words = line.split(None, 2)
        if len(words) >= 2 and words[1].isdigit() and len(words[1]) == 3:
            status = int(words[1])
            ctype = words[2].decode("latin-1").strip() if len(words) > 2 else None
    r = requests.Response()
    r.status_code, r._content, r.reason = status, body, "Reason"
    r.raw, r._content_consumed = io.BytesIO(b""), True
    r.headers = CaseInsensitiveDict({"Content-Type": ctype} if ctype else {})
    if ctype:
        r.encoding = requests.utils.get_encoding_from_headers(r.headers)
    r.request = requests.Request(method, url, params=params).prepare()
    r.url = r.request.url
    return r


class ScriptedHTTP:
    """A requests.Session whose answers are the replies of a transcript, in order; then
    "connection refused", as a camera or a site that went away."""

    verify = True

    def __init__(self, data: bytes):
        self.replies = iter(data.split(SEP))

    def request(self, method, url, params=None, **_):
        import requests

        piece = next(self.replies, None)
        if piece is None:
            raise requests.ConnectionError("[Errno 111] Connection refused")
        return http_reply(piece, method, url, params)

    def close(self) -> None:
        pass


class RecordingHTTP:
    """A real requests.Session that keeps every final reply (after any auth challenge)."""

    def __init__(self, session):
        self.session, self.pieces = session, []
        self.verify = session.verify

    def request(self, method, url, **kw):
        r = self.session.request(method, url, **kw)
        ctype = r.headers.get("Content-Type", "")
        self.pieces.append(f"HTTP {r.status_code} {ctype}".strip().encode() + b"\n" + r.content)
        return r

    def close(self) -> None:
        self.session.close()

    def transcript(self) -> bytes:
        return SEP.join(self.pieces)


def drive_axis(s, session) -> None:
    """What `vts camera` commands ask of a camera: VAPIX version, parameters, an update, the
    LED, device info, clock offset, a snapshot."""
    import os

    from vts_hw.config import CameraConfig
    from vts_hw.drivers.registry import open_camera

    os.environ.setdefault("VTS_FUZZ_CAM1_PASSWORD", "pw")
    cam = open_camera(
        CameraConfig(
            name="cam1",
            host="127.0.0.1",
            port=9,
            password_env="VTS_FUZZ_CAM1_PASSWORD",
            timeout_s=1.0,
            resolution=(160, 120),
            compression=90,
        )
    )
    cam._session = session  # the scripted transport in place of the camera's HTTP session
    s.call(lambda: cam.vapix_version)
    s.call(cam.get_params, "Image.I0")
    s.call(cam.set_params, {"Image.I0.Appearance.Compression": 30})
    s.call(cam.led_on)
    s.call(cam.led_pulse, 300)
    s.call(cam.device_info)
    s.call(cam.clock_offset, 2)
    s.call(cam.snapshot)


def drive_qatrack(s, session) -> None:
    """What `vts qatrack push` asks of the site: a token, the assignment, an earlier instance
    with the run's key, a new instance."""
    from vts_hw.qatrack.client import QATrackClient

    client = QATrackClient("http://127.0.0.1:9/", ("login", "vts", "pw"), timeout=1.0, session=session)
    s.call(client.token)
    s.call(client.assignment, "SPECT 1", "VTS daily")
    s.call(client.instance_with_key, "vts-0123456789abcdef")
    s.call(client.create_instance, {"unit_test_collection": "u", "tests": {"drift": {"value": 0.1}}})


# ---- serial: the trigger box ------------------------------------------------------------------


class ScriptedSerial:
    """A serial port whose lines are the replies of a transcript; then silence (a timeout)."""

    baudrate = 115200
    in_waiting = 0

    def __init__(self, data: bytes):
        lines = data.split(b"\n")
        self.replies = iter([x + b"\n" for x in lines[:-1]] + ([lines[-1]] if lines[-1] else []))

    def write(self, b: bytes) -> int:
        return len(b)

    def read_until(self, term=b"\n", size=None) -> bytes:
        r = next(self.replies, b"")
        return r[:size] if size else r

    def close(self) -> None:
        pass


class BoxResponder:
    """Answers like the firmware (drivers/trigger_box_protocol.py's table) and keeps each line."""

    baudrate = 115200
    in_waiting = 0

    def __init__(self, refuse_freq: bool = False):
        self.freq, self.duty, self.width, self.on, self.us = 1.0, 0.5, 100, False, 4_000_000
        self.n, self.first, self.errors, self.lines = 0, 0, [], []
        self.refuse_freq, self._pending = refuse_freq, b""
        self.wdog = 10.0

    def write(self, b: bytes) -> int:
        self._pending = self.answer(b.decode().strip()).encode() + b"\n"
        self.lines.append(self._pending)
        return len(b)

    def read_until(self, term=b"\n", size=None) -> bytes:
        r, self._pending = self._pending, b""
        return r

    def answer(self, cmd: str) -> str:
        self.us += 1234
        if self.on:
            self.n += 1
        head, _, arg = cmd.partition(" ")
        if cmd == "*IDN?":
            return "VTS,TRIGGERBOX,0042,1.3.0"
        if cmd in ("*RST", "*CLS", "*TRG", "OUTP ON", "OUTP OFF") or head in ("PULSE", "PULSE:WIDTH"):
            if cmd == "*RST":
                self.on, self.freq, self.duty, self.width = False, 1.0, 0.5, 100
            elif cmd == "*CLS":
                self.errors.clear()
            elif cmd in ("*TRG", "OUTP ON"):
                self.on, self.n, self.first = True, 1, self.us
            elif cmd == "OUTP OFF":
                self.on = False
            elif head == "PULSE:WIDTH":
                self.width = int(arg)
            return "OK"
        if head == "WDOG" and arg:
            self.wdog = float(arg)
            return "OK"
        if cmd == "WDOG?":
            return f"{self.wdog:.6f},{'OFF' if not self.wdog else 'ARMED' if self.on else 'IDLE'},0"
        if head in ("FREQ", "DUTY") and arg:
            if self.on or (self.refuse_freq and head == "FREQ"):
                self.errors.append(-221)
                return "ERR -221 Settings conflict; output on"
            setattr(self, head.lower(), float(arg))
            return "OK"
        replies = {
            "FREQ?": f"{self.freq:.6g}",
            "DUTY?": f"{self.duty:.6g}",
            "OUTP?": "ON" if self.on else "OFF",
            "PULSE:WIDTH?": str(self.width),
            "TIME?": str(self.us),
            "EDGES?": f"{self.n},{self.first},{self.first + max(self.n - 1, 0) * 100_000}",
        }
        if cmd in replies:
            return replies[cmd]
        if cmd == "SYST:ERR?":
            return f'{self.errors.pop(0)},"Settings conflict"' if self.errors else '0,"No error"'
        self.errors.append(-100)
        return "ERR -100 Command error"

    def close(self) -> None:
        pass


def drive_box(s, ser) -> None:
    """What `vts trigger` and a scan ask of the box: identify, status, configure, a clock
    mapping, start, edges, stop, fire, a pulse, the error queue, reset."""
    from vts_hw.drivers.trigger_box import TriggerBox

    box = TriggerBox(
        "fuzz",
        timeout=0.1,
        clock=FakeClock(),
        sleep=lambda _s: None,
        serial_factory=lambda *a, **k: ser,
        heartbeat=False,
    )  # no thread reading the script
    s.call(box.identify)
    s.call(box.status)
    s.call(box.configure, 10.0, 0.5)
    s.call(lambda: box.clock_mapping(4, over_s=0.0))
    s.call(box.start)
    s.call(box.edges)
    s.call(box.device_time_us)
    s.call(box.stop)
    s.call(box.fire, 50)
    s.call(box.pulse, 2, 20)
    s.call(box.read_errors)
    s.call(box.reset)
    box.close()


# ---- SCPI: the function generator --------------------------------------------------------------


class ScriptedVisa:
    """A pyvisa message resource whose replies are the lines of a transcript, decoded as
    pyvisa decodes them (ASCII, strict); then a VISA timeout."""

    resource_name = "TCPIP::127.0.0.1::5025::SOCKET"
    timeout = 100

    def __init__(self, data: bytes):
        self.replies = iter(data.split(b"\n"))

    def write(self, cmd: str) -> int:
        return len(cmd)

    def query(self, cmd: str) -> str:
        raw = next(self.replies, None)
        if raw is None:
            raise TimeoutError("VI_ERROR_TMO (-1073807339): Timeout expired before operation completed.")
        return raw.decode("ascii")

    def close(self) -> None:
        pass


class RecordingVisa(ScriptedVisa):
    """The simulated 33500 (sim_devices/keysight_33500.py), keeping each reply."""

    def __init__(self, instrument):
        self.instrument, self.lines = instrument, []

    def write(self, cmd: str) -> int:
        self.instrument.execute(cmd)
        return len(cmd)

    def query(self, cmd: str) -> str:
        reply = self.instrument.execute(cmd) or ""
        self.lines.append(reply.encode())
        return reply


def drive_fgen(s, resource) -> None:
    """What `vts trigger` asks of a 33500: identify (on open), status, configure with levels,
    start, stop, the error queue, reset."""
    from vts_hw.drivers.function_generator import FunctionGenerator

    gen = s.call(FunctionGenerator, resource)
    if gen is None:
        return
    s.call(gen.status)
    s.call(gen.configure, 10.0, 0.5, 5.0, 0.0)
    s.call(gen.start)
    s.call(gen.stop)
    s.call(gen.check_errors)
    s.call(gen.reset)
    gen.close()


# ---- the seeds: the same sessions against the simulators ----------------------------------------


class _Quiet:
    """Scratch.call's stand-in while recording: the answers are the simulators' own."""

    handled = 0

    def call(self, fn, *args, **kw):
        from vts_hw.errors import VtsError

        try:
            return fn(*args, **kw)
        except VtsError:
            return None


def device_seeds(put) -> None:
    """Transcripts of the device sessions against the simulators, plus hand-made replies at
    the edges of each protocol."""
    import requests

    from vts_hw.sim_devices.keysight_33500 import Keysight33500
    from vts_hw.sim_devices.qatrack_server import QATrackSim
    from vts_hw.sim_devices.rig import SimRig

    for model in ("vapix3", "vapix2"):
        with SimRig(n_cameras=1, firmware=model, password="fuzz-seed") as rig:
            cfg = rig.config().cameras[0]
            from vts_hw.drivers.axis_client import _AxisAuth

            rec = RecordingHTTP(_Rebase(requests.Session(), cfg.base_url, _AxisAuth(cfg.user, "fuzz-seed")))
            drive_axis(_Quiet(), rec)
            put("axis_vapix", f"{model}.txt", rec.transcript())
    put(
        "axis_vapix",
        "refused.txt",
        SEP.join(
            [
                b"HTTP 404 text/plain\nNot found",
                b"# Error: Error -1 getting param in group 'Brand'",
                b"HTTP 200 text/plain\nroot.Brand.Brand=AXIS\n",
                b"HTTP 200 application/json\n" + b'{"apiVersion": "1.0", "data": {"dateTime": "2026-11-24T06:00:00Z"}}',
            ]
        ),
    )

    deep = b"[" * 1200 + b"]" * 1200
    js = b"HTTP 200 application/json\n"
    put(
        "axis_vapix",
        "edge-json.txt",
        SEP.join(
            [
                b"root.Brand.Brand=AXIS",
                b"OK",
                b"OK",
                b"OK",
                js + b'{"data": {"propertyList": ["Brand", "AXIS"]}}',
                js + b'{"data": {"dateTime": 1795000000}}',
                js + deep,
            ]
        ),
    )
    put(
        "qatrack",
        "edge-json.txt",
        SEP.join(
            [js + b'{"token": 5}', js + b'{"results": {"url": 1}, "next": 7}', js + b'{"results": [5, "x"]}', js + deep]
        ),
    )
    with QATrackSim(
        {"VTS daily": ["vts_drift"]}, {"SPECT 1": ["VTS daily"]}, token="t-fuzz", users={"vts": "pw"}
    ) as site:
        session = requests.Session()
        rec = RecordingHTTP(_Rebase(session, site.url))
        drive_qatrack(_Quiet(), rec)
        put("qatrack", "push.txt", rec.transcript())
        site.add_instance("vts-0123456789abcdef")
        rec = RecordingHTTP(_Rebase(requests.Session(), site.url))
        drive_qatrack(_Quiet(), rec)
        put("qatrack", "again.txt", rec.transcript())
    put(
        "qatrack",
        "refused.txt",
        SEP.join(
            [
                b'HTTP 200 application/json\n{"token": "abc"}',
                b'HTTP 200 application/json\n{"count": 2, "next": "/api/qa/unittestcollections/?page=2", '
                b'"results": [{"url": "http://127.0.0.1:9/api/qa/unittestcollections/1/"}]}',
                b'HTTP 400 application/json\n{"tests": {"drift": ["not a number"]}, "non_field_errors": ["x"]}',
                b'HTTP 403 application/json\n{"detail": "Authentication credentials were not provided."}',
            ]
        ),
    )

    for name, responder in (("session", BoxResponder()), ("refused", BoxResponder(refuse_freq=True))):
        drive_box(_Quiet(), responder)
        put("trigger_box", f"{name}.txt", b"".join(responder.lines))
    put(
        "trigger_box",
        "edges.txt",
        b"VTS,TRIGGERBOX,1,2\nON\n1000\n0.5\n18446744073709551615,0,99\n"
        b'-350,"Queue overflow"\n0,"No error"\nERR\nERR x\n',
    )

    for idn in ("Agilent Technologies,33522B,MY00000000,4.00-1.19-2.00-58-00", "Keysight Technologies,33511B,MY0,5.01"):
        rec = RecordingVisa(Keysight33500(idn=idn))
        drive_fgen(_Quiet(), rec)
        put("function_generator", f"{idn.split(',')[1]}.txt", b"\n".join(rec.lines))


class _Rebase:
    """A session that sends a driver's requests (made for 127.0.0.1:9) to the simulator."""

    def __init__(self, session, base: str, auth=None):
        self.session, self.base, self.auth = session, base.rstrip("/"), auth
        self.verify = session.verify

    def request(self, method, url, **kw):
        from urllib.parse import urlsplit

        parts = urlsplit(url)
        kw.pop("verify", None)
        if self.auth is not None:
            kw["auth"] = self.auth
        return self.session.request(method, self.base + parts.path + (f"?{parts.query}" if parts.query else ""), **kw)

    def close(self) -> None:
        self.session.close()


__all__ = [
    "SEP",
    "ScriptedHTTP",
    "ScriptedSerial",
    "ScriptedVisa",
    "drive_axis",
    "drive_box",
    "drive_fgen",
    "drive_qatrack",
    "device_seeds",
]
