"""A simulated SPECT that follows the simulated trigger and writes VTSLM list-mode.

Where the trigger comes from (host UTC epoch seconds throughout):

* the trigger-box firmware in the emulator: :func:`edges_from_trigger_box` reads the output
  pins the emulator logged (``OC1A`` square wave, ``CH2`` SPECT start pulse) and maps their
  emulated cycles to host time with the anchor the harness logs as it starts
  (:meth:`SimTriggerBox.host_time`: ``t0 + cycles / 16 MHz / speed``);
* any backend that emits nothing here (the pyvisa-sim function generator, NI-DAQmx behind a
  fake port): :func:`edges_from_trigger_log` rebuilds the wave from the neutral rows of the
  session's ``trigger.csv`` (start host time, period, duty, levels, stop;
  :func:`vts_hw.recording.trigger_wave.wave_from_trigger_log`, docs/trigger-log-format.md);
* anything else: a :class:`TriggerEdges` built by hand (offline tests).

What the simulated SPECT does (:func:`write_sim_listmode`, all in one pass, so a 60 s or a
20 min acquisition takes seconds, not its duration):

* its acquisition starts ``start_delay_s`` (random 50–400 ms) after the start pulse (or,
  with no pulse, after the wave's first rising edge);
* its clock: list-mode time ``t = (h − h_start)·(1 + skew)``, its wall clock reads
  ``h + offset`` at the start (offset random ±3 s, skew random ±50 ppm);
* events: Poisson arrivals from every source (:class:`~.source_marker.SourceMarker`,
  :class:`Source`, or one that gives its own ``positions(scene, host_times)``, such as the
  patient's heart, :class:`~.patient_source.PatientSource`) at its rate, plus an optional uniform background; each on a random head,
  at the source's position at that instant (the scene's pose schedules and table, evaluated on
  a 1 ms grid) projected on the head — z axial, u transaxial for the head's angle — plus a
  Gaussian intrinsic blur (4 mm SD); nothing beyond the axial field of view (±200 mm);
* step-and-shoot: ``stop_s`` (20 s) acquiring, ``rotate_s`` (about 2 s) rotating by
  ``step_deg`` without events; the dead-time intervals go into the file (``DEAD``) unless
  ``record_dead_time`` is off;
* 10 ms timing marks, 100 ms frames (with the gantry angle), and the gating voltage: the
  square wave as sent (levels × ``gate_gain``), through a first-order low-pass (``gate_tau_s``,
  the input's front end), with noise, sampled at ``gate_rate_hz`` on the SPECT clock and
  quantised to 16 bits.

The truth (start delay, clock offset and skew, dead time, the sources' moves) goes to a
separate ``<file>.truth.json`` (:class:`ListModeTruth`) and is never in the list-mode file.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from vts_hw.files import check_target, write_json_atomic
from vts_hw.recording.trigger_wave import square_wave_edges, wave_from_trigger_log
from vts_hw.sim_devices.scene import Scene
from vts_hw.sim_devices.source_marker import SourceMarker
from vts_hw.spect.listmode.vtslm import VtslmWriter

__all__ = [
    "TriggerEdges",
    "Source",
    "SimSpectSettings",
    "ListModeTruth",
    "SimListModeSpect",
    "edges_from_trigger_box",
    "edges_from_trigger_log",
    "write_sim_listmode",
    "truth_path",
]


@dataclass
class TriggerEdges:
    """The square wave and start pulse as sent, host UTC epoch seconds; levels in volts."""

    rising: np.ndarray
    falling: np.ndarray
    start_pulse: float | None = None  # the SPECT start pulse's closing edge
    high_v: float = 5.0
    low_v: float = 0.0
    source: str = ""

    @property
    def period_s(self) -> float | None:
        return float(np.median(np.diff(self.rising))) if self.rising.size > 1 else None


@dataclass(frozen=True)
class Source:
    """A marker of a scene body that holds activity: ``rate_cps`` detected counts per second."""

    body: str
    marker_id: str
    rate_cps: float


@dataclass
class SimSpectSettings:
    """The simulated SPECT. ``None`` means drawn from the seed (range in the comment)."""

    start_delay_s: float | None = None  # 0.05–0.4 s after the start pulse
    clock_offset_s: float | None = None  # its wall clock − host: −3..3 s
    clock_skew_ppm: float | None = None  # −50..50 ppm
    blur_mm: float = 4.0  # intrinsic resolution, SD
    background_cps: float = 0.0  # uniform over the FOV
    fov_z_mm: tuple[float, float] = (-200.0, 200.0)  # axial field of view: no counts beyond
    fov_u_mm: tuple[float, float] = (-270.0, 270.0)
    heads: int = 2  # spaced evenly around the axis
    stop_s: float = 20.0  # step-and-shoot: acquiring ...
    rotate_s: float = 2.0  # ... then rotating (±10 % per step)
    step_deg: float = 6.0
    start_angle_deg: float = 0.0
    record_dead_time: bool = True
    timing_mark_s: float = 0.01
    frame_s: float = 0.1
    gate_rate_hz: float = 2000.0
    gate_gain: float = 1.0  # recorded volts per volt sent (0.5: 0/2.5 V)
    gate_offset_v: float = 0.0
    gate_noise_v: float = 0.02
    gate_tau_s: float = 0.0002  # the gating input's low-pass time constant
    gate_volts_per_count: float = 10.0 / 32768
    pose_grid_s: float = 0.001  # source positions are evaluated this often
    chunk_s: float = 2.0  # events are made and written in chunks


def truth_path(listmode_path) -> Path:
    """Where the truth of a simulated list-mode file is kept: ``<file>.truth.json``."""
    p = Path(listmode_path)
    return p.with_name(p.name + ".truth.json")


@dataclass
class ListModeTruth:
    """What the simulated SPECT did. Host times are UTC epoch s; list-mode times s."""

    listmode: str
    acquisition_start_host: float
    start_pulse_host: float | None
    wave_start_host: float | None  # the square wave's first rising edge
    start_delay_s: float  # acquisition start − start pulse (else − wave start)
    start_delay_from_wave_s: float | None  # acquisition start − the wave's first rising edge
    clock_offset_s: float  # SPECT wall clock − host, at the acquisition start
    clock_skew_ppm: float
    spect_start_time: float  # the header's start_time
    duration_s: float  # list-mode s
    dead: list[list[float]]  # [start, end) list-mode s
    period_s: float | None
    rising_edges_recorded: int  # rising edges inside the acquisition
    trigger: str
    sources: list[dict] = field(default_factory=list)
    n_events: int = 0
    seed: int = 0

    @property
    def skew(self) -> float:
        return self.clock_skew_ppm * 1e-6

    def list_time(self, host_t):
        """List-mode time (s) of host times."""
        return (np.asarray(host_t, dtype=float) - self.acquisition_start_host) * (1.0 + self.skew)

    def host_time(self, t):
        """Host time of list-mode times."""
        return self.acquisition_start_host + np.asarray(t, dtype=float) / (1.0 + self.skew)

    def save(self, path) -> Path:
        return write_json_atomic(path, asdict(self), indent=1)

    @classmethod
    def load(cls, path) -> ListModeTruth:
        return cls(**json.loads(Path(path).read_text()))


# ------------------------------------------------------------------------ following triggers


def edges_from_trigger_box(box, pulse_channel: str = "CH2") -> TriggerEdges:
    """The square wave (OC1A) and the last SPECT start pulse (CH2) the emulated box sent so
    far, in host time (:meth:`SimTriggerBox.host_time`). Levels 0/5 V (TTL)."""
    oc = box.edges("OC1A")
    rising = np.array([box.host_time(e.cycle) for e in oc if e.value == 1])
    falling = np.array([box.host_time(e.cycle) for e in oc if e.value == 0])
    pulses = [box.host_time(e.cycle) for e in box.edges(pulse_channel) if e.value == 1]
    return TriggerEdges(rising, falling, pulses[-1] if pulses else None, 5.0, 0.0, source="trigger box emulator")


def edges_from_trigger_log(path, device: str | None = None, until: float | None = None) -> TriggerEdges:
    """The square wave a ``trigger.csv`` says was sent, from its neutral rows (any backend):
    from the ``wave_start`` row's host time, at its period, duty and levels, until its
    ``wave_stop`` (or ``until`` if never stopped); the start pulse with the first edge when
    the row says ``start_pulse=yes``."""
    wave = wave_from_trigger_log(path, device)
    rising, falling = square_wave_edges(wave, until)
    return TriggerEdges(
        rising,
        falling,
        wave.start_host if wave.start_pulse else None,
        wave.high_v,
        wave.low_v,
        source=f"trigger log {path} ({wave.device})",
    )


# ------------------------------------------------------------------------------ simulation


def _as_source(s) -> Source:
    if isinstance(s, Source) or hasattr(s, "positions"):  # a source that knows where it is (the patient's)
        return s
    if isinstance(s, SourceMarker):
        return Source(s.body, s.marker_id, s.rate_cps)
    body, marker, rate = s
    return Source(body, marker, float(rate))


def _positions(scene: Scene, src: Source, h0: float, n: int, dt: float) -> np.ndarray:
    """(n, 3) positions of a source at host times h0 + (i + ½)·dt (SPECT frame, mm)."""
    if hasattr(src, "positions"):
        return src.positions(scene, h0 + (np.arange(n) + 0.5) * dt)
    body = scene.bodies[src.body]
    ids = [m.id for m in body.markers]
    if src.marker_id not in ids:
        raise ValueError(f"body {src.body!r} has no marker {src.marker_id!r}")
    k = ids.index(src.marker_id)
    out = np.empty((n, 3))
    last_key, last = None, None
    for i in range(n):
        t = h0 + (i + 0.5) * dt
        key = (scene.table.at(t), body.pose.at(t))
        if key != last_key:
            y, z = key[0]
            last = body.markers_at(t, np.array([0.0, y, z]))[k].center
            last_key = key
        out[i] = last
    return out


def _dead_intervals(duration: float, s: SimSpectSettings, rng) -> tuple[list, list]:
    """Step-and-shoot: [start, end) dead intervals (list-mode s) and (start, angle) per stop."""
    dead, stops, t, angle = [], [], 0.0, s.start_angle_deg
    while t < duration:
        stops.append((t, angle))
        t += s.stop_s
        if t >= duration or s.rotate_s <= 0:
            break
        rot = s.rotate_s * rng.uniform(0.9, 1.1)
        dead.append([t, min(t + rot, duration)])
        t += rot
        angle += s.step_deg
    return dead, stops


def _gate_volts(tg_host: np.ndarray, trig: TriggerEdges, s: SimSpectSettings, rng) -> np.ndarray:
    """The recorded gating voltage at host times: the wave as sent through the low-pass."""
    times = np.concatenate([trig.rising, trig.falling])
    levels = np.concatenate([np.ones(trig.rising.size), np.zeros(trig.falling.size)])
    order = np.argsort(times, kind="stable")
    times, levels = times[order], levels[order]
    i = np.searchsorted(times, tg_host, side="right") - 1
    level = np.where(i >= 0, levels[np.maximum(i, 0)], 0.0)
    before = np.where(i >= 1, levels[np.maximum(i - 1, 0)], 0.0)
    since = tg_host - np.where(i >= 0, times[np.maximum(i, 0)], -np.inf)
    if s.gate_tau_s > 0:
        frac = -np.expm1(-since / s.gate_tau_s)
        level = before + (level - before) * frac
    volts = trig.low_v + (trig.high_v - trig.low_v) * level
    return s.gate_offset_v + s.gate_gain * volts + rng.normal(0.0, s.gate_noise_v, tg_host.size)


def write_sim_listmode(
    path,
    scene: Scene,
    sources,
    trigger: TriggerEdges,
    duration_s: float,
    settings: SimSpectSettings | None = None,
    seed: int = 0,
    known_until: float | None = None,
) -> ListModeTruth:
    """Simulate one acquisition of ``duration_s`` (list-mode s) following ``trigger`` (host
    time) and write it as VTSLM to ``path``; the truth goes to :func:`truth_path` and is
    returned. ``sources``: :class:`~.source_marker.SourceMarker`, :class:`Source` or
    ``(body, marker_id, rate_cps)``. ``known_until``: the host time up to which ``trigger``
    is known (a trigger still running); an acquisition that would outlast it is refused
    (ValueError) rather than recorded with a wave that seems to stop. Offline: nothing here
    waits for real time."""
    s = settings or SimSpectSettings()
    rng = np.random.default_rng(seed)
    delay = s.start_delay_s if s.start_delay_s is not None else float(rng.uniform(0.05, 0.4))
    offset = s.clock_offset_s if s.clock_offset_s is not None else float(rng.uniform(-3, 3))
    skew_ppm = s.clock_skew_ppm if s.clock_skew_ppm is not None else float(rng.uniform(-50, 50))
    skew = skew_ppm * 1e-6
    wave_start = float(trigger.rising[0]) if trigger.rising.size else None
    ref = trigger.start_pulse if trigger.start_pulse is not None else wave_start
    if ref is None:
        raise ValueError("the trigger sent neither a start pulse nor a square wave: nothing to start on")
    h_start = ref + delay
    if known_until is not None and h_start + duration_s / (1.0 + skew) > known_until:
        raise ValueError(
            f"the trigger is known until {known_until - h_start:.3f} s into the "
            f"acquisition, not for all of its {duration_s} s: let it run longer"
        )
    spect_start_time = h_start + offset
    srcs = [_as_source(x) for x in sources]

    def host(t):
        return h_start + np.asarray(t, dtype=float) / (1.0 + skew)

    dead, stops = _dead_intervals(duration_s, s, rng)
    dead_arr = np.array(dead, dtype=float).reshape(-1, 2)
    path = Path(path)
    check_target(path)  # a device, FIFO or symbolic link of that name is never replaced (files.py)
    part = path.with_name(f".{path.name}.{os.getpid()}.part")  # hidden from a glob until whole
    try:
        n_events = _write(
            part, s, rng, scene, srcs, trigger, duration_s, dead, dead_arr, stops, host, spect_start_time, skew
        )
        rising_in = trigger.rising[(trigger.rising >= h_start) & (trigger.rising < host(duration_s))]
        truth = ListModeTruth(
            listmode=path.name,
            acquisition_start_host=h_start,
            start_pulse_host=trigger.start_pulse,
            wave_start_host=wave_start,
            start_delay_s=delay,
            start_delay_from_wave_s=None if wave_start is None else h_start - wave_start,
            clock_offset_s=offset,
            clock_skew_ppm=skew_ppm,
            spect_start_time=spect_start_time,
            duration_s=float(duration_s),
            dead=[list(map(float, d)) for d in dead],
            period_s=trigger.period_s,
            rising_edges_recorded=int(rising_in.size),
            trigger=trigger.source,
            sources=[x.to_json() if hasattr(x, "to_json") else asdict(_as_source(x)) for x in sources],
            n_events=int(n_events),
            seed=int(seed),
        )
        truth.save(truth_path(path))
        check_target(path)
        os.replace(part, path)
    except BaseException:
        with contextlib.suppress(OSError):
            part.unlink()
        raise
    return truth


def _write(
    path: Path,
    s: SimSpectSettings,
    rng,
    scene,
    srcs,
    trigger,
    duration_s,
    dead,
    dead_arr,
    stops,
    host,
    spect_start_time,
    skew,
) -> int:
    """The VTSLM file itself; returns the number of events."""
    n_events = 0
    with VtslmWriter(
        path,
        start_time=spect_start_time,
        duration_s=duration_s,
        gate_rate_hz=s.gate_rate_hz,
        gate_volts_per_count=s.gate_volts_per_count,
        timing_mark_s=s.timing_mark_s,
        frame_s=s.frame_s,
        heads=s.heads,
        dead_time_recorded=s.record_dead_time,
        scanner="VTS simulated SPECT",
        isotope="Tc-99m",
        acquisition="step-and-shoot",
        created_by="vts_hw.sim_devices.spect_listmode",
    ) as w:
        if s.record_dead_time and len(dead):
            w.dead(dead_arr[:, 0], dead_arr[:, 1])
        w.timing_marks(np.arange(0.0, duration_s, s.timing_mark_s))
        f_t = np.arange(0.0, duration_s, s.frame_s)
        w.frames(f_t, np.arange(f_t.size), _frame_angles(f_t, dead, stops, s.step_deg))
        n_gate = int(math.floor(duration_s * s.gate_rate_hz))
        step = max(1, int(s.chunk_s * s.gate_rate_hz))
        for i0 in range(0, n_gate, step):  # gating samples on the SPECT clock
            tg = np.arange(i0, min(n_gate, i0 + step)) / s.gate_rate_hz
            w.gate(_gate_volts(host(tg), trigger, s, rng))
        for c0 in np.arange(0.0, duration_s, s.chunk_s):  # events, only while live
            live = _live_segments(c0, min(duration_s, c0 + s.chunk_s), dead)
            if live:
                t, z, u, head = _events(scene, srcs, live, host, stops, s, rng, skew)
                w.events(t, z, u, head)
                n_events += t.size
        w.close(duration_s)
    return n_events


def _frame_angles(f_t: np.ndarray, dead: list, stops: list, step_deg: float) -> np.ndarray:
    """Head 0's angle at each frame start: the stop's, or turning linearly while dead."""
    stop_t = np.array([a for a, _ in stops])
    stop_angle = np.array([b for _, b in stops])
    angle = stop_angle[np.searchsorted(stop_t, f_t, side="right") - 1].copy()
    for (d0, d1), a in zip(dead, stop_angle):  # dead[k] follows stop k
        inside = (f_t >= d0) & (f_t < d1)
        angle[inside] = a + step_deg * (f_t[inside] - d0) / (d1 - d0)
    return angle


def _events(scene: Scene, srcs: list[Source], live: list, host, stops: list, s: SimSpectSettings, rng, skew: float):
    """Events in the live segments of one chunk (list-mode s): (t, z, u, head), time-sorted.

    Each source: Poisson arrivals at its rate (host counts/s), a random head, the source's
    position at the arrival (from a grid of ``pose_grid_s`` over the chunk's host time)
    projected on the head, plus the blur; the background is uniform over the FOV."""
    a, b = live[0][0], live[-1][1]
    h0 = float(host(a))
    n_grid = int(math.ceil((float(host(b)) - h0) / s.pose_grid_s)) + 1
    stop_t = np.array([x for x, _ in stops])
    stop_angle = np.array([y for _, y in stops])
    parts = []
    for src in srcs + ([None] if s.background_cps > 0 else []):
        rate = s.background_cps if src is None else src.rate_cps
        t = _poisson_times(rng, rate / (1.0 + skew), live)  # per list-mode second
        if t.size == 0:
            continue
        head = rng.integers(0, s.heads, t.size)
        theta = np.deg2rad(stop_angle[np.searchsorted(stop_t, t, side="right") - 1] + head * 360.0 / s.heads)
        if src is None:
            z = rng.uniform(*s.fov_z_mm, t.size)
            u = rng.uniform(*s.fov_u_mm, t.size)
        else:
            grid = _positions(scene, src, h0, n_grid, s.pose_grid_s)
            p = grid[np.clip(((host(t) - h0) / s.pose_grid_s).astype(np.int64), 0, n_grid - 1)]
            z = p[:, 2] + rng.normal(0.0, s.blur_mm, t.size)
            u = p[:, 0] * np.cos(theta) + p[:, 1] * np.sin(theta) + rng.normal(0.0, s.blur_mm, t.size)
            seen = (z >= s.fov_z_mm[0]) & (z <= s.fov_z_mm[1])  # the detectors' axial extent
            t, z, u, head = t[seen], z[seen], u[seen], head[seen]
        parts.append((t, z, u, head))
    if not parts:
        return np.empty(0), np.empty(0), np.empty(0), np.empty(0, np.uint8)
    t, z, u, head = (np.concatenate(x) for x in zip(*parts))
    order = np.argsort(t, kind="stable")
    return t[order], z[order], u[order], head[order]


def _live_segments(a: float, b: float, dead: list) -> list[tuple[float, float]]:
    segs = [(a, b)]
    for d0, d1 in dead:
        out = []
        for s0, s1 in segs:
            if d1 <= s0 or d0 >= s1:
                out.append((s0, s1))
                continue
            if s0 < d0:
                out.append((s0, d0))
            if d1 < s1:
                out.append((d1, s1))
        segs = out
    return [(s0, s1) for s0, s1 in segs if s1 > s0]


def _poisson_times(rng, rate: float, segments) -> np.ndarray:
    """Sorted arrival times of a Poisson process of ``rate`` per second over the segments."""
    out = []
    for a, b in segments:
        n = rng.poisson(rate * (b - a))
        out.append(np.sort(rng.uniform(a, b, n)))
    return np.concatenate(out) if out else np.empty(0)


class SimListModeSpect:
    """A simulated SPECT in a scene: ``follow_trigger_box``, ``follow_trigger_log`` or
    ``write`` (any :class:`TriggerEdges`) make one acquisition each and return its truth."""

    def __init__(self, scene: Scene, sources, settings: SimSpectSettings | None = None, seed: int = 0):
        self.scene = scene
        self.sources = list(sources)
        self.settings = settings or SimSpectSettings()
        self.seed = seed

    def write(self, path, trigger: TriggerEdges, duration_s: float, known_until: float | None = None) -> ListModeTruth:
        return write_sim_listmode(
            path, self.scene, self.sources, trigger, duration_s, self.settings, self.seed, known_until
        )

    def follow_trigger_box(self, box, path, duration_s: float) -> ListModeTruth:
        """Follow what the emulated trigger box sent (its pins as logged so far). While the
        emulator runs, the acquisition must end before the emulation's present (ValueError
        otherwise: wait, or stop the wave first and let it finish)."""
        edges = edges_from_trigger_box(box)
        known = None
        if box.running():  # the status file is rewritten in place: take the best of 3 reads
            known = box.host_time(max(box.cycles_now() for _ in range(3)))
        return self.write(path, edges, duration_s, known)

    def follow_trigger_log(
        self, log_path, path, duration_s: float, device: str | None = None, until: float | None = None
    ) -> ListModeTruth:
        """Follow the wave a trigger log describes, from its neutral rows (any backend)."""
        return self.write(path, edges_from_trigger_log(log_path, device, until), duration_s)
