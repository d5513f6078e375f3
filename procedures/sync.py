"""The sync check: one scan session (recordings + trigger log) and the SPECT's list-mode, put
on one clock, with the motion of a source marker as the common ruler.

``SyncAnalysis(session_dir, listmode_path, calibration, mapping).analyze()`` then
``results()`` (text), ``results_data()`` (JSON-ready dict), ``plot(path)`` (PNG).

What it does (the reasons are in docs/decisions/0019-sync-analysis.md):

0. **Inputs** (:mod:`.sync_inputs`): the session checked; of the list-mode file(s) given (a
   shell glob may give several), the one whose acquisition overlaps the session — else one
   sentence (the files do not belong together, or the SPECT's failure record for this scan).
1. **Gating** (:mod:`vts_hw.spect.gating`): the trigger log (``trigger.csv``) gives the square
   wave's period and the host time of its first rising edge (the start pulse); the list-mode's
   gating voltage gives the edges on the SPECT clock. Fitted together: the SPECT start delay
   against the trigger, the SPECT clock's skew, list-mode time ↔ host time, and the dead time
   (head rotations: no events).
2. **VTS** (:func:`vts_hw.tracking.processing.process_recording`): every frame pair triangulated, each
   camera's stamps mapped to host time by its clock model (offset and skew fitted to the
   frames' stamp / receive-time pairs). The moving marker: the named one, else the one with
   the largest axial range (SPECT Z through the VTS → SPECT mapping, 2nd–98th percentile;
   without a mapping the largest range of motion) among those seen in at least a fifth of
   the frames the most-seen marker was. A marker whose track broke in a camera gap is re-joined (ids
   that follow each other in time and meet within ``join_mm``).
3. **SPECT**: the axial centre of mass of the counts in ``bin_s`` bins (for the plot and to
   find the steps), list-mode time mapped to host time through the gating clock.
4. **Events** (:mod:`vts_hw.timing.marker_steps`): steps found in both traces, each timed by fitting a
   smooth step to the raw samples (VTS: the marker's z per frame; SPECT: every event's z) —
   the mid-crossing, in host time. Matched by time; per event ``dt = t_vts − t_spect``; the
   overall offset is the median of dt, its spread the SD and the largest deviation. An event
   in a camera gap is reported as seen by the SPECT only.

Clocks: every time in the results is host UTC epoch seconds unless named otherwise
(``*_list_s``: list-mode seconds since the SPECT acquisition start; ``*_rel_s``: seconds since
the trigger's first edge). Positions mm, SPECT frame when a mapping is given.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vts_hw import catalog
from vts_hw.errors import DataError
from vts_hw.figures import figure_png
from vts_hw.files import WriteFailed, ensure_dir, export_stopped
from vts_hw.procedures.sync_inputs import CLOCK_SLACK_S, check_session, choose_listmode
from vts_hw.procedures.sync_plot import sync_figure
from vts_hw.procedures.sync_verdict import sync_measures, sync_verdict, sync_windows
from vts_hw.recording.trigger_wave import WaveInfo, wave_from_trigger_log
from vts_hw.results import Measure
from vts_hw.spect.gating import GatingResult, analyze_gating, axial_centre_of_mass
from vts_hw.spect.listmode import ListMode, read_listmode
from vts_hw.timing.marker_steps import StepFit, find_steps, fit_step, match_events, robust_sd
from vts_hw.tolerance import State
from vts_hw.tracking.processing import process_recording
from vts_hw.tracking.tracks import Tracks
from vts_hw.vision.calibration_io import read_calibration
from vts_hw.vision.registration import read_mapping

__all__ = [
    "SyncAnalysis",
    "SyncEvent",
    "export_trajectories",
    "check_session",
    "choose_listmode",
]

BIN_S = 0.05  # SPECT centre-of-mass bins for finding steps and for the plot
MATCH_S = 0.5  # a VTS and a SPECT step further apart than this are different events
JOIN_MM = 60.0  # track pieces meeting within this (mm) across a gap are one marker
HALF_WINDOW_S = 0.8  # samples fitted around each step


# ----------------------------------------------------------------------------- results


@dataclass
class SyncEvent:
    """One motion event: the VTS's and the SPECT's fitted step (either may be missing)."""

    vts: StepFit | None
    spect: StepFit | None
    note: str = ""

    @property
    def seen_by(self) -> str:
        return "both" if self.vts and self.spect else ("VTS only" if self.vts else "SPECT only")

    @property
    def dt_s(self) -> float | None:
        """t_vts − t_spect (s), both host time; None unless seen by both."""
        return self.vts.t_mid - self.spect.t_mid if self.vts and self.spect else None

    @property
    def t(self) -> float:
        fit = self.spect or self.vts
        if fit is None:
            raise ValueError("a motion event seen by neither system")
        return fit.t_mid


class _HostToList:
    """host UTC epoch s → SPECT list-mode s (since the acquisition start), via the gating clock."""

    def __init__(self, clock):
        self.clock = clock
        self.__doc__ = (
            "spect_time: SPECT list-mode seconds since the acquisition start, from host "
            "time through the gating clock (square-wave edges fitted: start delay "
            f"{clock.start_delay_s * 1e3:.2f} ms, skew {clock.skew_ppm:+.2f} ppm)"
        )

    def __call__(self, host_t):
        return self.clock.to_list(host_t)


def _chains(tracks, join_mm: float) -> list[list[int]]:
    """Marker ids grouped into one physical marker each: pieces that follow one another in time
    and meet within ``join_mm`` (a track broken by a camera gap), closest first."""
    t = tracks.point_time
    info = []
    for m in tracks.marker_ids():
        sel = np.flatnonzero(tracks.marker == m)
        order = sel[np.argsort(t[sel], kind="stable")]
        info.append((float(t[order[0]]), float(t[order[-1]]), tracks.xyz[order[0]], tracks.xyz[order[-1]], m))
    info.sort(key=lambda x: x[0])
    chains: list[dict] = []
    for first, last, p0, p1, m in info:
        best, best_d = None, join_mm
        for c in chains:
            if c["last"] < first:
                d = float(np.linalg.norm(c["end"] - p0))
                if d <= best_d:
                    best, best_d = c, d
        if best is None:
            chains.append({"ids": [m], "last": last, "end": p1})
        else:
            best["ids"].append(m)
            best["last"], best["end"] = last, p1
    return [c["ids"] for c in chains]


def _trace_gaps(t: np.ndarray, period: float, factor: float = 3.0) -> list[list[float]]:
    """[start, end) host s where the trace has no sample for more than ``factor`` periods."""
    if t.size < 2:
        return []
    d = np.diff(t)
    i = np.flatnonzero(d > factor * period)
    return [[float(t[k]), float(t[k + 1])] for k in i]


class SyncAnalysis:
    """The sync check of one scan session against one list-mode file (see the module).

    ``calibration``: a calibration (CameraCalibration), its file, or cameras as ``process_recording`` takes
    them. ``mapping``: VTS → SPECT (RigidTransform, its file, or an analysed SpectMapping); the
    VTS trace is then SPECT Z, else the marker's displacement along its main direction of
    motion. ``marker``: the id to follow (default: the one with the largest axial range).
    ``progress(done, total)``: frame pairs processed.
    """

    def __init__(
        self,
        session_dir,
        listmode_path,
        calibration=None,
        mapping=None,
        *,
        marker: int | None = None,
        workers: int | None = None,
        progress: Callable[[int, int], None] | None = None,
        clock_slack_s: float = CLOCK_SLACK_S,
    ):
        self.session = Path(session_dir)
        many = isinstance(listmode_path, (list, tuple))
        self.listmode_candidates = [Path(p) for p in (listmode_path if many else [listmode_path])]
        self.listmode_path = self.listmode_candidates[0]
        self.clock_slack_s = clock_slack_s
        self.calibration = calibration
        self.mapping = mapping
        self.marker = marker
        self.workers = workers
        self.progress = progress
        self.manifest: dict | None = None
        self.wave: WaveInfo | None = None
        self.gating: GatingResult | None = None
        self.lm: ListMode | None = None
        self.tracks: Tracks | None = None
        self.events: list[SyncEvent] = []
        self.problems: list[str] = []
        self.tolerances: dict | None = None
        self._done = False

    # ------------------------------------------------------------------ analysis
    def analyze(
        self,
        *,
        bin_s: float = BIN_S,
        match_s: float = MATCH_S,
        join_mm: float = JOIN_MM,
        min_step_mm: float = 4.0,
        tolerances: dict | None = None,
    ) -> SyncAnalysis:
        """``tolerances``: the rig's tolerance windows over the defaults (the ``sync_*`` ones judge)."""
        self.tolerances = tolerances

        self.manifest = check_session(self.session)
        self.listmode_path, notes = choose_listmode(
            self.session, self.listmode_candidates, manifest=self.manifest, slack_s=self.clock_slack_s
        )
        self.lm = lm = read_listmode(self.listmode_path)
        self.wave = wave = wave_from_trigger_log(self.session / "trigger.csv")
        self.gating = gating = analyze_gating(lm, period_s=wave.host_period_s, fire_host=wave.start_host)
        self.problems = notes + list(gating.problems)
        if self.calibration is None:
            raise DataError(f"{self.session}: no stereo calibration given: the marker cannot be triangulated")
        cams = read_calibration(self.calibration)
        mapping = read_mapping(self.mapping)
        self.calibration_info = {
            "stereo": str(self.calibration) if isinstance(self.calibration, (str, Path)) else "given",
            "spect": (
                str(self.mapping)
                if isinstance(self.mapping, (str, Path))
                else ("given" if mapping is not None else None)
            ),
            "note": "; ".join(
                dict.fromkeys(
                    n
                    for n in (getattr(cams, "outlier_rule", ""), (getattr(mapping, "meta", None) or {}).get("note", ""))
                    if str(n).startswith("simulated rig")
                )
            ),
        }
        self.tracks = tracks = process_recording(
            self.session,
            cams,
            workers=self.workers,
            mapping=mapping,
            host_to_spect=_HostToList(gating.clock),
            progress=self.progress,
        )
        tracks.meta.setdefault("warnings", [])
        self.problems += [f"processing: {w}" for w in tracks.meta.get("warnings", [])]
        for name, cam in self.manifest["cameras"].items():
            gaps = cam.get("gaps") or []
            if gaps:
                self.problems.append(
                    f"camera {name}: {sum(g.get('missing', 0) for g in gaps)} frame(s) "
                    f"missing in {len(gaps)} gap(s) (manifest); events there are seen "
                    f"by the SPECT only"
                )
        self._vts_trace(tracks, join_mm)
        self._spect_trace(gating, lm, bin_s)
        self._events(match_s, min_step_mm)
        self._done = True
        return self

    def _vts_trace(self, tr: Tracks, join_mm: float) -> None:
        if not tr.marker_ids():
            raise DataError(
                f"{self.session}: no marker was triangulated in the recording (LEDs off? wrong calibration?)"
            )
        chains = _chains(tr, join_mm)
        xyz_spect = tr.xyz_spect
        axial = xyz_spect is not None

        def values(ids):
            sel = np.isin(tr.marker, ids)
            t = tr.point_time[sel]
            order = np.argsort(t, kind="stable")
            if xyz_spect is not None:
                return t[order], xyz_spect[sel][order, 2]
            xyz = tr.xyz[sel][order]
            c = xyz - np.median(xyz, axis=0)
            _, _, vt = np.linalg.svd(c, full_matrices=False)
            return t[order], c @ vt[0]

        if self.marker is not None:
            pick = [c for c in chains if self.marker in c]
            if not pick:
                raise DataError(
                    f"{self.session}: no marker {self.marker} in the recording (markers: "
                    f"{', '.join(str(m) for m in tr.marker_ids())})"
                )
            chain = pick[0]
        else:
            # the largest axial range (2nd to 98th percentile: a stray point does not count)
            # among markers seen in at least a fifth of the frames the longest one was seen in
            counts = [int(np.isin(tr.marker, c).sum()) for c in chains]
            common = [c for c, n in zip(chains, counts) if n >= 0.2 * max(counts)]

            def axial_range(c):
                p2, p98 = np.percentile(values(c)[1], [2, 98])
                return float(p98 - p2)

            chain = max(common, key=axial_range)
        t, z = values(chain)
        self.marker_ids = [int(m) for m in chain]
        self.vts_t, self.vts_z = t, z
        self.vts_axial = axial
        period = float(tr.meta.get("frame_period_s") or np.median(np.diff(tr.host_time)))
        self.vts_period = period
        self.vts_gaps = _trace_gaps(t, period)
        if not axial:
            self.problems.append(
                "no VTS -> SPECT mapping: the VTS trace is the marker's displacement along "
                "its main direction of motion, not SPECT Z (sign not comparable)"
            )

    def _spect_trace(self, g: GatingResult, lm: ListMode, bin_s: float) -> None:
        t_list, z = axial_centre_of_mass(lm, bin_s=bin_s, dead=g.dead)
        self.spect_bin_s = bin_s
        self.spect_t = np.asarray(g.clock.to_host(t_list))
        self.spect_z = z
        self.event_t = np.asarray(g.clock.to_host(np.asarray(lm.t, float)))
        self.event_z = np.asarray(lm.z, float)
        self.dead_host = np.asarray(g.clock.to_host(g.dead)).reshape(-1, 2) if len(g.dead) else np.empty((0, 2))

    def _fit_all(self, cands, t, z, noise, what) -> list[StepFit]:
        out = []
        for c in cands:
            try:
                out.append(
                    fit_step(
                        t,
                        z,
                        c.t,
                        half_window_s=HALF_WINDOW_S,
                        noise_mm=noise,
                        method=f"{what}: normal-CDF edge fitted to the raw samples",
                    )
                )
            except ValueError as exc:
                self.problems.append(f"{what} step near {self._rel(c.t):.2f} s not fitted: {exc}")
        return out

    def _events(self, match_s: float, min_step_mm: float) -> None:
        vts_c = find_steps(self.vts_t, self.vts_z, min_step_mm=min_step_mm)
        spect_c = find_steps(self.spect_t, self.spect_z, min_step_mm=min_step_mm)
        self.vts_steps = self._fit_all(
            vts_c, self.vts_t, self.vts_z, robust_sd(np.diff(self.vts_z)) / math.sqrt(2), "VTS"
        )
        self.spect_steps = self._fit_all(spect_c, self.event_t, self.event_z, None, "SPECT")

        def signs(steps):  # without SPECT Z the VTS trace's sign means nothing: time alone
            return [s.step_mm if self.vts_axial else 1.0 for s in steps]

        pairs = match_events(
            [s.t_mid for s in self.vts_steps],
            signs(self.vts_steps),
            [s.t_mid for s in self.spect_steps],
            signs(self.spect_steps),
            match_s,
        )
        self.events = []
        for i, j in pairs:
            ev = SyncEvent(self.vts_steps[i] if i is not None else None, self.spect_steps[j] if j is not None else None)
            if ev.vts is None:
                inside = (
                    any(a - 0.5 <= ev.t <= b + 0.5 for a, b in self.vts_gaps)
                    or ev.t < self.vts_t[0]
                    or ev.t > self.vts_t[-1]
                )
                ev.note = "in a gap of the VTS recording" if inside else "not seen by the VTS"
            elif ev.spect is None:
                dead = any(a - 0.5 <= ev.t <= b + 0.5 for a, b in self.dead_host)
                ev.note = "in SPECT dead time (heads rotating)" if dead else "not seen by the SPECT"
            self.events.append(ev)
        if not any(e.dt_s is not None for e in self.events):
            self.problems.append("no motion event seen by both systems: the offset is not measured")

    # ------------------------------------------------------------------ figures
    def _rel(self, t):
        if self.wave is None:
            raise RuntimeError("call analyze() first")
        return np.asarray(t, float) - self.wave.start_host

    @property
    def dts(self) -> np.ndarray:
        return np.array([e.dt_s for e in self.events if e.dt_s is not None], float)

    @property
    def offset_s(self) -> float | None:
        """Median of t_vts − t_spect over the events both saw (s)."""
        d = self.dts
        return float(np.median(d)) if d.size else None

    def results_data(self) -> dict:
        """Everything as a JSON-ready dict (host UTC epoch s; see the module for the clocks)."""
        wave, g, lm, tracks = self._parts()
        d = self.dts
        off = self.offset_s
        events = []
        for k, e in enumerate(self.events, 1):
            events.append(
                {
                    "event": k,
                    "seen_by": e.seen_by,
                    "note": e.note,
                    "t_vts": e.vts.t_mid if e.vts else None,
                    "t_spect": e.spect.t_mid if e.spect else None,
                    "t_rel_s": float(self._rel(e.t)),
                    "t_list_s": float(g.clock.to_list(e.t)),
                    "dt_s": e.dt_s,
                    "step_vts_mm": e.vts.step_mm if e.vts else None,
                    "step_spect_mm": e.spect.step_mm if e.spect else None,
                    "vts_fit": e.vts.to_json() if e.vts else None,
                    "spect_fit": e.spect.to_json() if e.spect else None,
                }
            )
        summary: dict[str, Any] = {
            "events": len(self.events),
            "events_both": int(d.size),
            "events_spect_only": sum(e.seen_by == "SPECT only" for e in self.events),
            "events_vts_only": sum(e.seen_by == "VTS only" for e in self.events),
            "offset_s": off,
            "spread_sd_s": float(np.std(d, ddof=1)) if d.size > 1 else None,
            "max_abs_dt_s": float(np.max(np.abs(d))) if d.size else None,
            "max_dev_from_offset_s": float(np.max(np.abs(d - off))) if d.size else None,
            "start_delay_s": g.start_delay_s,
            "start_delay_modulo_s": g.clock.period_spect,
            "spect_clock_offset_s": g.clock_offset_s,
            "spect_skew_ppm": g.clock.skew_ppm,
        }
        windows = sync_windows(self.tolerances)
        state, reason = sync_verdict(summary, windows, self.problems)
        summary["state"], summary["state_reason"] = state.value, reason
        clock_fits = tracks.meta.get("clock_fits", {})
        return {
            "procedure": "sync check",
            "session": str(self.session),
            "listmode": str(self.listmode_path),
            "listmode_given": [str(c) for c in self.listmode_candidates],
            "clocks": "host UTC epoch s unless named: *_list_s SPECT list-mode s since its acquisition "
            "start, *_rel_s s since the trigger's first edge",
            "summary": summary,
            "events": events,
            "windows": {m: w.as_dict() for m, w in windows.items()},
            "trigger": {
                "device": wave.device,
                "start_host": wave.start_host,
                "period_s": wave.period_s,
                "host_period_s": wave.host_period_s,
                "duty": wave.duty,
                "start_pulse": wave.start_pulse,
                "how": wave.how,
                "time_source": wave.time_source,
                "uncertainty_s": wave.uncertainty_s,
                "converted_from_old_log": wave.converted,
            },
            "gating": g.to_json(),
            "dead_time_host": self.dead_host.tolist(),
            "vts": {
                "markers": self.marker_ids,
                "trace": "SPECT Z" if self.vts_axial else "main direction of motion",
                "samples": int(self.vts_t.size),
                "frame_period_s": self.vts_period,
                "gaps_host": self.vts_gaps,
                "clock_fits": clock_fits,
                "marker_summary": tracks.marker_summary(),
            },
            "spect": {"bin_s": self.spect_bin_s, "events": int(lm.n_events), "duration_s": lm.duration_s},
            "calibration": dict(self.calibration_info),
            "problems": list(self.problems),
        }

    # ------------------------------------------------------------------ the QA result shape
    procedure = catalog.SYNC.name

    @property
    def measures(self) -> list[Measure]:
        """The figures the tolerance table's sync windows judge (subject: the VTS against the SPECT)."""
        self._need()
        s = self.results_data()["summary"]
        windows = sync_windows(self.tolerances)
        units = {"sync_max_abs_dt_ms": "ms", "sync_events_one_system": "events", "sync_events_both": "events"}
        return [Measure.judged("vts-spect", m, v, units[m], windows[m]) for m, v in sync_measures(s).items()]

    @property
    def state(self) -> State:
        return State(self.results_data()["summary"]["state"])

    def results(self) -> str:
        """A short text summary for people (times relative to the trigger's first edge)."""
        self._need()
        r = self.results_data()
        s = r["summary"]
        lines = [
            f"sync check: {self.session} with {self.listmode_path.name}",
            f"  SPECT start delay {s['start_delay_s'] * 1e3:.1f} ms after the start pulse "
            f"(modulo {s['start_delay_modulo_s']:.3f} s), SPECT clock {s['spect_skew_ppm']:+.1f} ppm, "
            f"its wall clock {s['spect_clock_offset_s']:+.3f} s from host",
            "  dead time: " + (", ".join(f"{a:.2f}-{b:.2f} s" for a, b in self._rel(self.dead_host)) or "none"),
            f"  VTS marker {'+'.join(str(m) for m in self.marker_ids)} ({r['vts']['trace']}), "
            f"{r['vts']['samples']} samples"
            + (
                ", gaps "
                + ", ".join(f"{a:.2f}-{b:.2f} s" for a, b in self._rel(np.array(self.vts_gaps).reshape(-1, 2)))
                if self.vts_gaps
                else ""
            ),
        ]
        for e in r["events"]:
            dt = f"dt {e['dt_s'] * 1e3:+7.1f} ms" if e["dt_s"] is not None else f"{e['seen_by']}: {e['note']}"
            step = e["step_spect_mm"] if e["step_spect_mm"] is not None else e["step_vts_mm"]
            lines.append(f"  event {e['event']}: at {e['t_rel_s']:7.2f} s, step {step:+6.1f} mm, {dt}")
        if s["offset_s"] is not None:
            sd = f", SD {s['spread_sd_s'] * 1e3:.1f} ms" if s["spread_sd_s"] is not None else ""
            lines.append(
                f"  offset VTS - SPECT (median of {s['events_both']}): {s['offset_s'] * 1e3:+.1f} ms{sd}, "
                f"largest |dt| {s['max_abs_dt_s'] * 1e3:.1f} ms"
            )
        if self.calibration_info.get("note"):
            lines.append(f"  calibration: {self.calibration_info['note']}")
        lines.append(f"  state: {s['state']} (every event within 20 ms: OK; 100 ms: TOLERANCE)")
        for p in self.problems:
            lines.append(f"  note: {p}")
        return "\n".join(lines)

    def figure(self):
        """Both traces on one time axis, dead time shaded, VTS gaps hatched, events marked;
        below, dt per event (:func:`.sync_plot.sync_figure`)."""
        self._need()
        return sync_figure(self)

    def plot(self, path=None) -> bytes:
        """PNG of :meth:`figure`; written to ``path`` when given. Returns the bytes."""
        return figure_png(self.figure(), path)

    def _need(self) -> None:
        if not self._done:
            raise RuntimeError("call analyze() first")

    def _parts(self) -> tuple[WaveInfo, GatingResult, ListMode, Tracks]:
        """What analyze() read: the trigger's wave, the gating, the list-mode, the tracks."""
        self._need()
        if self.wave is None or self.gating is None or self.lm is None or self.tracks is None:
            raise RuntimeError("call analyze() first")  # set together by analyze()
        return self.wave, self.gating, self.lm, self.tracks


# ----------------------------------------------------------------------------- export


def export_trajectories(
    tracks, gating: GatingResult, out, mapping=None, stem: str = "trajectories"
) -> tuple[Path, Path]:
    """Write a session's marker trajectories **in the SPECT frame on SPECT time** to
    ``out/<stem>.csv`` and ``.json`` (docs/trajectory-format.md): ``spect_time`` = SPECT
    list-mode seconds since the acquisition start, from host time through ``gating``'s clock;
    ``x_spect_mm``.. through ``mapping`` (VTS → SPECT), or the tracks' own SPECT positions.
    DataError when neither gives SPECT positions."""
    mapping = read_mapping(mapping)
    if mapping is None and tracks.xyz_spect is None:
        raise DataError(
            "no VTS -> SPECT mapping: the trajectories cannot be put in the SPECT frame "
            "(give --mapping or set calibration.mapping in rig.yaml)"
        )
    out = ensure_dir(out, "export folder")
    exported = tracks.with_spect(mapping, _HostToList(gating.clock))
    c = gating.clock
    exported.meta["sync"] = {
        "spect_time": "SPECT list-mode s since the acquisition start",
        "start_delay_s": c.start_delay_s,
        "skew_ppm": c.skew_ppm,
        "t_wave_list_s": c.t_wave,
        "fire_host": c.fire_host,
        "spect_start_time": gating.start_time,
        "dead_time_list_s": np.asarray(gating.dead).tolist(),
    }
    try:
        return exported.save(out / f"{stem}.csv")
    except WriteFailed as exc:  # each file whole or absent; say what that leaves of the export
        raise export_stopped(exc, out) from None
