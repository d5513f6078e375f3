"""Frames made ahead of time: a stretch of every simulated camera's stream, rendered before it
is needed and served from memory when its time comes, so that the streams are whole however
busy the machine is.

A simulated camera renders each frame when its time comes (``SimCameraSource.jpeg``): about
10 ms of one core per frame for a scene with a breathing patient, so two cameras at 25 fps
take half a core, four cameras all of one; on a machine whose cores are busy the renderer falls
behind and the streams come late (then skip, as a real camera would). Real cameras cost the
host nothing. :class:`FrameBank` takes that cost out of real time:

* :meth:`FrameBank.render` renders ``seconds`` of each camera's frames on the sensor's grid
  (multiples of the frame period, as the streams send them), with the LED rings on, as JPEGs
  at the quality the streams ask for (75: the driver's default compression 25);
* the stretch starts playing at the first stream that opens after it was rendered
  (:meth:`FrameBank.play_from`): what moves in the scene on its own (the patient: its
  breathing, its moves; the SPECT heads' turning) is moved in time to that instant, so that
  what the cameras show and what the truth says stay one, and the stretch follows on from the
  stream's first frame;
* a stream's frame at grid time ``t`` is served from the bank (:meth:`FrameBank.take`) when
  the bank holds that instant at the quality asked, the camera's LED is on and nothing else
  in the scene (the table, a scheduled body) is other than when it was rendered; anything else
  is rendered live as before.

The camera drift over the shift (about 1e-4 px a minute for the reference rig) is the only
part of the scene not moved with it. ``docs/decisions/0047-sim-frame-loss.md`` says why.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from vts_hw.sim_devices.patient_rig import write_patient_truth
from vts_hw.sim_devices.render import Renderer
from vts_hw.sim_devices.scene import Scene

__all__ = ["FrameBank", "BankStats", "DEFAULT_QUALITY", "make_ahead"]

DEFAULT_QUALITY = 75  # JPEG quality of a stream at the driver's default compression (25)


@dataclass(frozen=True)
class BankStats:
    """What rendering the stretch cost: ``frames`` in all (every camera), the CPU time of the
    thread that rendered them and the wall time it took; per frame per camera, and the share
    of one core that rendering in real time would take at ``fps``."""

    cameras: int
    fps: float
    seconds: float
    frames: int
    cpu_s: float
    wall_s: float
    bytes: int

    @property
    def ms_per_frame(self) -> float:
        return 1000.0 * self.cpu_s / self.frames if self.frames else float("nan")

    @property
    def core_share(self) -> float:
        """Cores that rendering these cameras at their rate, live, would keep busy."""
        return self.ms_per_frame * self.fps * self.cameras / 1000.0

    def line(self) -> str:
        return (
            f"{self.frames} frames ({self.cameras} camera(s) x {self.seconds:g} s at {self.fps:g} fps) "
            f"rendered ahead in {self.wall_s:.1f} s: {self.ms_per_frame:.1f} ms of CPU per frame per camera, "
            f"{self.core_share:.2f} of a core to render them live; {self.bytes / 1e6:.0f} MB held"
        )


class FrameBank:
    """``seconds`` of every camera of ``scene`` (rendered by ``renderer``) made ahead of time."""

    def __init__(self, scene: Scene, renderer: Renderer, fps: float = 25.0, quality: int = DEFAULT_QUALITY):
        if not fps > 0:
            raise ValueError(f"fps must be > 0, not {fps!r}")
        self.scene, self.renderer = scene, renderer
        self.fps, self.period, self.quality = float(fps), 1.0 / float(fps), int(quality)
        self.cameras = list(scene.cameras)
        self.first = 0  # grid index of the stretch's first frame
        self.count = 0
        self.frames: dict[str, list[bytes]] = {c: [] for c in self.cameras}
        self._keys: list[tuple] = []  # what else was in the scene, per frame
        self.offset: int | None = None  # grid periods the stretch was moved by
        self.stats: BankStats | None = None
        self.served = 0
        self.missed: dict[str, int] = {}  # why frames were rendered live instead
        self._misses: list[tuple[float, str]] = []  # (grid time, why) of each
        self.on_play: list[Callable[[float], None]] = []
        self._lock = threading.Lock()

    # -- making ------------------------------------------------------------------------
    def render(
        self, seconds: float, start: float | None = None, progress: Callable[[int, int], None] | None = None
    ) -> BankStats:
        """Render ``seconds`` of frames from ``start`` (host s on the scene's time; default
        now, as ``time.time()``) on the grid; ``progress(done, total)`` now and then."""
        if not seconds > 0:
            raise ValueError(f"seconds must be > 0, not {seconds!r}")
        t_start = time.time() if start is None else float(start)
        self.first = math.ceil(t_start * self.fps - 1e-6)
        n = int(math.ceil(seconds * self.fps))
        total, done = n * len(self.cameras), 0
        cpu0, wall0 = time.thread_time(), time.monotonic()
        frames: dict[str, list[bytes]] = {c: [] for c in self.cameras}
        keys = []
        for j in range(n):
            t = (self.first + j) / self.fps
            keys.append(self._static_key(t))
            for cam in self.cameras:  # with the LED ring on, as a scan has it
                frames[cam].append(self.renderer.encode(self.renderer.render(cam, t, led=True), self.quality))
                done += 1
            if progress is not None and (j % 25 == 0 or j == n - 1):
                progress(done, total)
        size = sum(len(b) for v in frames.values() for b in v)
        with self._lock:
            self.frames, self._keys, self.count, self.offset = frames, keys, n, None
            self.served, self.missed, self._misses = 0, {}, []
        self.stats = BankStats(
            len(self.cameras), self.fps, n / self.fps, total, time.thread_time() - cpu0, time.monotonic() - wall0, size
        )
        return self.stats

    def _static_key(self, t: float) -> tuple:
        """Everything in the scene at ``t`` that the shift does not move: the table, bodies
        whose pose is scheduled (not moved in time with the stretch)."""
        s = self.scene
        return (s.table.at(t),) + tuple((n, b.pose.at(t)) for n, b in s.bodies.items() if not hasattr(b, "shift"))

    def _movers(self) -> list:
        """What moves in time with the stretch: bodies and a gantry that can be ``shift``-ed."""
        out = [b for b in self.scene.bodies.values() if hasattr(b, "shift")]
        gantry = self.scene.gantry
        return out + ([gantry] if gantry is not None and hasattr(gantry, "shift") else [])

    # -- playing -----------------------------------------------------------------------
    @property
    def playing(self) -> bool:
        return self.offset is not None

    def play_from(self, t: float) -> None:
        """A stream's first frame is at grid time ``t``: the first call after :meth:`render`
        starts the stretch there, moving the scene's moving bodies (those with ``shift``)
        in time with it; later calls change nothing."""
        with self._lock:
            if self.offset is not None or not self.count:
                return
            offset = round(t * self.fps) - self.first
            dt = offset / self.fps
            for mover in self._movers():
                mover.shift(dt)
            self.offset = offset
        for hook in list(self.on_play):
            hook(dt)

    def rewind(self) -> None:
        """Back to before :meth:`play_from`: what moved in time with the stretch is moved back
        and the next stream starts the stretch again (the same frames for another scan, as
        ``bench/motion_under_loss.py`` runs one per loss pattern); the counts start afresh.
        Nothing happens when the stretch is not playing."""
        with self._lock:
            if self.offset is None:
                return
            dt = self.offset / self.fps
            for mover in self._movers():
                mover.shift(-dt)
            self.offset = None
            self.served, self.missed, self._misses = 0, {}, []

    def take(self, cam: str, t: float, quality: int) -> bytes | None:
        """The JPEG of camera ``cam`` at grid time ``t`` from the bank, or None (render it)."""
        if self.offset is None or quality != self.quality or cam not in self.frames:
            return None
        k = round(t * self.fps)
        j = k - self.first - self.offset
        why = (
            "not on the frame grid"
            if abs(t - k / self.fps) > 1e-4
            else "outside the stretch"
            if not 0 <= j < self.count
            else "LED off"
            if not self.scene.led_on(cam, t)
            else "the scene changed"
            if self._static_key(t) != self._keys[j]
            else ""
        )
        if why:
            self._miss(t, why)
            return None
        self.served += 1
        return self.frames[cam][j]

    def _miss(self, t: float, why: str) -> None:
        with self._lock:
            self.missed[why] = self.missed.get(why, 0) + 1
            self._misses.append((t, why))

    def missed_between(self, t0: float, t1: float) -> dict[str, int]:
        """Why frames captured from ``t0`` to ``t1`` (host s) were rendered live, and how many."""
        out: dict[str, int] = {}
        with self._lock:
            for t, why in self._misses:
                if t0 <= t <= t1:
                    out[why] = out.get(why, 0) + 1
        return out

    def span(self) -> tuple[float, float] | None:
        """Host times of the first and last frame the stretch covers, once playing."""
        if self.offset is None:
            return None
        a = (self.first + self.offset) / self.fps
        return a, a + (self.count - 1) / self.fps


def make_ahead(rig, seconds: float, folder=None, say: Callable[[str], None] = print) -> BankStats:
    """``vts sim up --ahead SECONDS``: the rig's frames made ahead before it serves, said in
    one line; with a patient and a folder, its truth (``DIR/truth/``) is written again once the
    stretch starts playing (the patient's plan moved with it)."""
    say(f"making {seconds:g} s of every camera's frames ahead of time ...")
    stats = rig.prerender(seconds)
    say(f"frames made ahead: {stats.line()}; they start playing at the first stream")
    if rig.patient is not None and folder is not None:

        def rewrite(dt: float) -> None:
            threading.Thread(
                target=write_patient_truth, args=(rig.patient, folder), daemon=True, name="sim-truth"
            ).start()

        rig.on_play(rewrite)
    return stats
