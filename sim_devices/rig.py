"""The simulated rig: one scene, a simulated Axis camera per scene camera, on 127.0.0.1.

From Python (tests)::

    with SimRig(n_cameras=2) as rig:
        cfg = rig.config()            # a RigConfig pointing at the simulated cameras
        with rig.env():               # the password variables it names, set for the block
            with Room.open(cfg) as room:   # vts_hw.room
                cam = room.camera("cam1")

From the shell: ``vts sim up`` (foreground, Ctrl-C stops) or ``vts sim up --detach --dir DIR``
which writes ``DIR/rig.yaml`` and ``DIR/sim.env`` and runs this module in the background;
``vts sim down --dir DIR`` stops it (both through :mod:`vts_hw.sim_devices.rig_detached`, which
loads none of the scene and its devices).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import secrets
import signal
import sys
import threading
import time
from pathlib import Path

from vts_hw.config import RigConfig, dump_rig, parse_rig
from vts_hw.errors import UsageError, VtsError
from vts_hw.files import WriteFailed, ensure_dir, os_reason, write_atomic, write_secret
from vts_hw.sim_devices.announce import Announcer
from vts_hw.sim_devices.axis_camera import SimAxisCamera
from vts_hw.sim_devices.camera_source import SimCameraSource
from vts_hw.sim_devices.clock import RealClock, VirtualClock
from vts_hw.sim_devices.clock_warmup import declare_warm_starts
from vts_hw.sim_devices.frame_bank import DEFAULT_QUALITY, FrameBank, make_ahead
from vts_hw.sim_devices.optics import set_optics
from vts_hw.sim_devices.patient_rig import TRUTH_DIR, PatientOptions, put_patient, write_patient_truth
from vts_hw.sim_devices.patient_source import heart_source
from vts_hw.sim_devices.qatrack_rig import TOKEN_ENV, section, start_site
from vts_hw.sim_devices.render import Renderer

# the rig run detached (rig_detached.py); load_env_file is re-exported for the callers of before
from vts_hw.sim_devices.rig_detached import FOLDER, PID_FILE, already_running, is_running, load_env_file, pid_of  # noqa: F401
from vts_hw.sim_devices.rig_log import FAILED, one_line
from vts_hw.sim_devices.scene import CameraDrift, Scene
from vts_hw.sim_devices.scpi_server import SimFunctionGenerator
from vts_hw.sim_devices.spect_follower import SpectFollower
from vts_hw.sim_devices.sync_truth import write_true_calibration, write_true_cameras
from vts_hw.sim_devices.tls import self_signed
from vts_hw.sim_devices.trigger_box import SimTriggerBox

FGEN_LOG = "fgen_output.csv"  # the simulated function generator's output changes (host times)
TRIGGERS = ("none", "triggerbox", "visa")
GANTRY_DWELL_S, GANTRY_MOVE_S, GANTRY_STEPS = 2.0, 1.0, 1_000_000  # turning for ~35 days


def password_var(cam: str) -> str:
    return f"VTS_SIM_{cam.upper().replace('-', '_').replace('.', '_')}_PASSWORD"


class SimRig:
    """A running simulated rig. ``faults`` of each camera: ``rig.servers[name].faults``."""

    def __init__(
        self,
        n_cameras: int = 2,
        seed: int = 0,
        *,
        user: str = "root",
        password: str | None = None,
        firmware: str = "vapix3",
        clock=None,
        fps: float = 25.0,
        clock_warmup: bool | dict = False,
        drift_px_per_60_days: dict[str, float] | None = None,
        trigger: str = "none",
        tls: tuple[str, str] | None = None,
        gantry: bool = False,
        patient=None,
        qatrack: bool = False,
        announce: bool = False,
        optics: dict[str, dict] | None = None,
        warmup_drift: bool | dict = False,
    ):
        if trigger not in TRIGGERS:
            raise ValueError(f"trigger must be one of {', '.join(TRIGGERS)}, not {trigger!r}")
        self.trigger = trigger
        self.trigger_box: SimTriggerBox | None = None  # the firmware in the emulator, when trigger == "triggerbox"
        self.function_generator: SimFunctionGenerator | None = None  # a 33522B on a TCP socket, when trigger == "visa"
        self.qatrack = qatrack  # a simulated QATrack+ beside the rig (qatrack_rig.py)
        self.qatrack_site = None
        self.clock = clock or RealClock()
        # gantry: the SPECT heads in the room, turning step-and-shoot from the start (3 deg steps,
        # a stop of GANTRY_DWELL_S) and on for as long as the rig runs; without it there are none
        self.scene = Scene.reference(seed=seed, n_cameras=n_cameras, start_epoch=self.clock.now(), gantry=gantry)
        if self.scene.gantry is not None:  # (given gantry)
            self.scene.gantry.step_and_shoot(
                self.scene.start_epoch, 3.0, GANTRY_STEPS, GANTRY_DWELL_S, GANTRY_MOVE_S, start_deg=0.0
            )
        # patient: a PatientOptions (sim_devices/patient_rig.py): the simulated patient on the table
        # from now, before any camera serves; rig.patient is its truth (None without one)
        self.patient = None
        if patient is not None:
            self.patient = put_patient(self.scene, patient, self.scene.start_epoch)
        for i, (cam, px) in enumerate(sorted((drift_px_per_60_days or {}).items())):
            # a camera that drifts faster than the reference rig's (the demo's bad camera)
            self.scene.drifts[cam] = CameraDrift.reference(
                self.scene.cameras[cam].focal, seed * 7919 + i, self.scene.start_epoch, px
            )
        # declared, minutes after a camera starts: its picture drifts (sim_devices/warmup.py), its clock's rate departs
        declare_warm_starts(self.scene, seed, warmup_drift, clock_warmup)
        self.renderer = Renderer(self.scene)
        # optics: {camera: {focus_blur_px, yaw_deg, pitch_deg}}, a lens out of focus, a mount turned
        # (sim_devices/optics.py; at run time: sources[name].set_optics or POST /sim/optics)
        for cam, changes in (optics or {}).items():
            set_optics(self.scene, self.renderer, cam, **changes)
        self.user = user
        self.password = password or secrets.token_urlsafe(12)
        self.fps = fps
        self.sources = {
            name: SimCameraSource(self.scene, self.renderer, name, self.clock) for name in self.scene.cameras
        }
        # firmware: the camera model (p1375, axis211; vapix3/vapix2 name them too). tls=(cert, key):
        # HTTPS cameras with basic authentication, the certificate named in config() as ca_cert
        self.tls = tls
        # firmware: one model for every camera, or one per camera in order (e.g. ["p1375", "axis211"])
        models = [firmware] * len(self.sources) if isinstance(firmware, str) else list(firmware)
        if len(models) != len(self.sources):
            raise ValueError(f"firmware names {len(models)} models for {len(self.sources)} cameras")
        self.servers = {
            name: SimAxisCamera(
                src,
                user=user,
                password=self.password,
                model=model,
                clock=self.clock,
                tls=tls,
                auth="basic" if tls else "digest",
            )
            for (name, src), model in zip(self.sources.items(), models)
        }
        # announce: the cameras announce themselves on loopback (mDNS and SSDP, sim_devices/announce.py)
        self.announce = announce
        self.announcer: Announcer | None = None
        for name, srv in self.servers.items():  # each camera's shutter time, from its model profile
            self.renderer.exposure[name] = srv.profile.exposure_ms / 1000.0
        self.bank: FrameBank | None = None  # frames made ahead of time (prerender)
        self._on_play: list = []
        self._started = False

    # -- life cycle --------------------------------------------------------------------
    def start(self) -> SimRig:
        for srv in self.servers.values():
            srv.start()
        if self.trigger == "triggerbox":
            self.trigger_box = SimTriggerBox().start()
        if self.trigger == "visa":
            self.function_generator = SimFunctionGenerator(clock=self.clock.now).start()
        if self.qatrack:
            self.qatrack_site = start_site(list(self.servers))
        if self.announce:
            self.announcer = Announcer(self.servers.values()).start()
        self._started = True
        return self

    def stop(self) -> None:
        if self.announcer is not None:
            self.announcer.stop()
            self.announcer = None
        for srv in self.servers.values():
            srv.stop()
        if self.trigger_box is not None:
            self.trigger_box.stop()
            self.trigger_box = None
        if self.function_generator is not None:
            self.function_generator.stop()
            self.function_generator = None
        if self.qatrack_site is not None:
            self.qatrack_site.down()
            self.qatrack_site = None
        self._started = False

    def __enter__(self) -> SimRig:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def prerender(self, seconds: float, *, quality: int | None = None, progress=None):
        """Make ``seconds`` of every camera's frames ahead of time (sim_devices/frame_bank.py):
        they start playing at the first stream opened after this, and the patient's plan (its
        breathing, its moves) is moved in time to that instant; until then, and after the
        stretch, frames are rendered when their time comes. Streams served from it stay whole
        however busy the machine is. Returns what rendering cost (``BankStats``);
        ``self.bank`` is the bank. ``quality``: the JPEG quality the streams will ask
        (default: 100 - the compression the cameras' config gives)."""
        bank = FrameBank(self.scene, self.renderer, self.fps, DEFAULT_QUALITY if quality is None else quality)
        stats = bank.render(seconds, start=self.clock.now(), progress=progress)
        bank.on_play.extend(self._on_play)
        self.bank = bank
        for src in self.sources.values():
            src.bank = bank
        return stats

    def on_play(self, hook) -> None:
        """``hook(dt)`` runs when frames made ahead start playing (the patient moved ``dt`` s
        later), from the stream's thread: it must return at once."""
        self._on_play.append(hook)
        if self.bank is not None:
            self.bank.on_play.append(hook)

    def ntp_sync(self, at: float | None = None) -> None:
        """The cameras' NTP sync: each clock keeps its residual offset, and its skew starts
        accumulating afresh from ``at`` (default now). Without it a clock runs free, gaining
        its skew (tens of ppm: seconds a day) for as long as the simulation runs."""
        at = self.clock.now() if at is None else at
        for name, c in list(self.scene.clocks.items()):
            self.scene.clocks[name] = dataclasses.replace(c, ref_epoch=at)

    # -- what a client needs -------------------------------------------------------------
    def config(
        self, rig_name: str = "sim", calibration: dict | None = None, results_url: str | None = None
    ) -> RigConfig:
        cams = [
            {
                "name": name,
                "host": "127.0.0.1",
                "port": srv.port,
                "user": self.user,
                "password_env": password_var(name),
                "fps": self.fps,
            }
            | ({"scheme": "https", "ca_cert": str(Path(self.tls[0]).resolve())} if self.tls else {})
            for name, srv in self.servers.items()
        ]
        data = {"rig": rig_name, "cameras": cams, "trigger": self.trigger_config()}
        if calibration:
            data["calibration"] = calibration
            # the table stops 50 mm short of the scene's walls (nearer than a real room's): decision 0086
            z = [float(m.center[2]) for m in self.scene.wall_markers]
            data["aim"] = {
                "table_z_mm": [
                    max([-1200.0] + [v + 50 for v in z if v < 0]),
                    min([900.0] + [v - 50 for v in z if v > 0]),
                ]
            }
        if results_url:
            data["store"] = {"url": results_url}
        if self.qatrack_site is not None:
            data["qatrack"] = section(self.qatrack_site, list(self.servers))
        return parse_rig(data, "simulated rig")

    def trigger_config(self) -> dict:
        """The rig config's trigger section for the simulated trigger generator."""
        if self.trigger == "triggerbox" and self.trigger_box is not None:
            return {"backend": "triggerbox", "address": self.trigger_box.port}
        if self.trigger == "visa" and self.function_generator is not None:
            # reached as a real 33500 on the LAN is: a VISA SOCKET resource (pyvisa-py)
            return {"backend": "visa", "address": self.function_generator.resource, "high_v": 2.5, "low_v": 0.0}
        return {"backend": "none"}

    def env_vars(self) -> dict[str, str]:
        """The variables rig.yaml names: each camera's password (and the simulated QATrack+'s token)."""
        out = {password_var(name): self.password for name in self.servers}
        if self.qatrack_site is not None:
            out[TOKEN_ENV] = self.qatrack_site.token
        return out

    @contextlib.contextmanager
    def env(self):
        """Set the password variables for the duration of a block (tests)."""
        old = {k: os.environ.get(k) for k in self.env_vars()}
        os.environ.update(self.env_vars())
        try:
            yield
        finally:
            for k, v in old.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v

    def write(self, folder: str | Path) -> tuple[Path, Path]:
        """Write ``rig.yaml`` and ``sim.env`` (mode 600: it holds the password), and the true
        cameras' ``calibration.json`` and ``spect_mapping.json`` (sim_devices/sync_truth.py; with
        two cameras or more), named in rig.yaml's ``calibration:`` section (absolute paths), and
        with three or more ``cameras.json``: every true camera (the N-camera form
        ``vts_hw.vision.camera_set.load_cameras`` reads)."""
        folder = ensure_dir(folder, FOLDER, mode=0o700)
        calibration = None
        if len(self.scene.cameras) >= 2:  # a stereo pair: the first two cameras
            cal, mp = write_true_calibration(self.scene, folder)
            calibration = {"cameras": str(cal.resolve()), "mapping": str(mp.resolve())}
        if len(self.scene.cameras) >= 3:
            write_true_cameras(self.scene, folder)
        env_path = folder / "sim.env"
        env = ["# source this file: the passwords of the simulated cameras (and the simulated QATrack+'s token)"]
        env += [f"export {k}='{v}'" for k, v in self.env_vars().items()]
        env.append(f"export VTS_CONFIG='{(folder / 'rig.yaml').resolve()}'")
        write_secret(env_path, "\n".join(env) + "\n")  # 0600, in a folder of this user's (files.py)
        rig_path = folder / "rig.yaml"  # written last: once all is up
        store = f"sqlite:///{(folder / 'results.sqlite').resolve()}"
        write_atomic(
            rig_path,
            "# the simulated rig written by `vts sim up`; calibration: the scene's true "
            "cameras; results: its own store, never the user's\n"
            + dump_rig(self.config(calibration=calibration, results_url=store)),
        )
        return rig_path, env_path


# -- running in the foreground or detached ----------------------------------------------------
def serve(
    folder: str | Path | None,
    n_cameras: int,
    seed: int,
    firmware: str = "vapix3",
    rate: float = 1.0,
    on_ready=None,
    trigger: str = "none",
    spect: bool = False,
    https: bool = False,
    gantry: bool = False,
    patient=None,
    qatrack: bool = False,
    ahead: float = 0.0,
    warmup_drift: bool = False,
    announce: bool = False,
) -> None:
    """Run a rig until SIGINT/SIGTERM. With ``folder``: write rig.yaml, sim.env and sim.pid.
    ``announce``: the cameras announce themselves on loopback as Axis cameras do (mDNS and SSDP:
    ``vts discover --interface 127.0.0.1`` finds them).
    ``qatrack``: a simulated QATrack+ beside it, named in rig.yaml (its token in sim.env).
    ``spect``: a simulated SPECT records every scan the trigger box starts, into
    ``folder/spect`` (:class:`~vts_hw.sim_devices.spect_follower.SpectFollower`).
    ``patient``: a :class:`~vts_hw.sim_devices.patient_rig.PatientOptions`: the simulated
    patient on the table, its truth in ``folder/truth``; the SPECT then counts its heart.
    ``ahead``: seconds of frames made ahead of time before serving (``SimRig.prerender``).
    ``warmup_drift``: every camera just switched on (uptime 0), its picture drifting (warmup.py)."""
    if spect and (trigger != "triggerbox" or folder is None):
        raise VtsError(
            "the simulated SPECT needs --trigger triggerbox and --dir (it writes its list-mode files into DIR/spect)"
        )
    if patient is not None:
        try:
            patient.check()
        except ValueError as e:  # a plan that cannot be (too short for its moves)
            raise UsageError(f"simulated patient: {e}") from None
    if folder is not None:
        folder = ensure_dir(folder, FOLDER, mode=0o700)  # before anything starts: a folder we cannot use stops here
        if is_running(folder) and pid_of(folder) != os.getpid():
            raise already_running(folder)
    clock = RealClock() if rate == 1.0 else VirtualClock(time.time(), rate=rate)
    stop = threading.Event()

    def _stop(*_):
        stop.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    tls: tuple[str, str] | None = None
    if https:  # a self-signed certificate beside rig.yaml (or in a folder of its own)
        from tempfile import mkdtemp

        cert, key = self_signed(folder if folder is not None else mkdtemp(prefix="vts-sim-tls-"))
        tls = (str(cert), str(key))
    rig = SimRig(
        n_cameras=n_cameras,
        seed=seed,
        firmware=firmware,
        clock=clock,
        trigger=trigger,
        tls=tls,
        gantry=gantry,
        patient=patient,
        qatrack=qatrack,
        warmup_drift=warmup_drift,
        announce=announce,
    )
    for srv in rig.servers.values() if warmup_drift else ():  # started now: the drift counts from here
        srv.reboot()
    follower = None
    if spect and folder is not None:  # (a SPECT without a folder was refused above)
        sources = None
        if rig.patient is not None:
            sources = [heart_source(rig.patient)]
        follower = SpectFollower(
            rig, Path(folder) / "spect", seed=seed, sources=sources, log=lambda m: print(m, flush=True)
        )  # the scene, before cameras serve
    if ahead > 0:
        make_ahead(rig, ahead, folder, say=lambda m: print(m, flush=True))
    try:
        with rig:
            if follower is not None:
                follower.start()
            if folder is not None:
                write_atomic(folder / PID_FILE, f"{os.getpid()}\n")
                if rig.function_generator is not None:
                    try:
                        rig.function_generator.log_to(folder / FGEN_LOG)
                    except OSError as e:
                        raise WriteFailed(folder / FGEN_LOG, os_reason(e)) from None
                if rig.patient is not None:
                    try:
                        write_patient_truth(rig.patient, folder)
                    except OSError as e:
                        raise WriteFailed(folder / TRUTH_DIR, os_reason(e)) from None
                rig.write(folder)
            if on_ready:
                on_ready(rig)
            while not stop.wait(0.5):
                pass
            if follower is not None:
                follower.stop()
    finally:
        if folder is not None:
            with contextlib.suppress(FileNotFoundError):
                (folder / PID_FILE).unlink()


def _main(argv: list[str]) -> int:
    """The detached process: serve until stopped; on failure, one last line saying why."""
    folder, n, seed, fw, rate, trigger = argv[:6]
    try:
        patient = next((PatientOptions.from_arg(a) for a in argv[6:] if a.startswith("patient=")), None)
        ahead = next((float(a.split("=", 1)[1]) for a in argv[6:] if a.startswith("ahead=")), 0.0)
        serve(
            folder,
            int(n),
            int(seed),
            fw,
            float(rate),
            trigger=trigger,
            spect="spect" in argv[6:],
            https="https" in argv[6:],
            gantry="gantry" in argv[6:],
            patient=patient,
            qatrack="qatrack" in argv[6:],
            ahead=ahead,
            warmup_drift="warmup" in argv[6:],
            announce="announce" in argv[6:],
        )
    except VtsError as e:
        with contextlib.suppress(OSError):  # a full disk takes the log too: the exit code still tells
            print(f"{FAILED}{e}", file=sys.stderr, flush=True)
        return e.exit_code
    except Exception as e:
        import traceback

        with contextlib.suppress(OSError):
            traceback.print_exc()
            print(f"{FAILED}{one_line(e)}", file=sys.stderr, flush=True)
        return 1
    return 0


if __name__ == "__main__":  # the detached process
    sys.exit(_main(sys.argv[1:]))
