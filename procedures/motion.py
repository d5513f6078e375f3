"""Offline patient motion of one scan session: the respiratory signal, the body's 6-DOF pose
with breathing taken out, body-motion events and motion states, in the one QA result shape.

``MotionAnalysis(session, listmode=None, calibration, mapping).analyze(tolerances)`` then
``results()`` (text), ``results_data()`` (JSON-ready dict), ``plot(path)`` (PNG) and
``export(dir)`` (docs/motion-formats.md).

* **Tracks.** The recording is processed (:func:`vts_hw.tracking.processing.process_recording`,
  every camera the calibration covers). With a list-mode file, through the sync analysis
  (:class:`.sync.SyncAnalysis`): every time is then SPECT list-mode seconds since the
  acquisition start; without one, host time (seconds from the first frame in every output).
  With a VTS → SPECT mapping the positions are in the SPECT frame, else the VTS frame. Every
  output says which.
* **Motion** (:func:`vts_hw.motion.analyze_motion`; method: docs/decisions/0035).
* **Time** (issue 20): the scan's duration is what the recording's index and manifest say it
  covers (``Tracks.meta["extent"]``, :mod:`vts_hw.recording.extent`), not the frames that
  happen to be readable; time without frames or with fewer than 3 patient markers is time
  without a pose, and every output says how much and where.
* **Measures**: the largest displacement of the patient markers' centroid
  (``motion_body_max_mm``) and the largest turn (``motion_body_max_deg``) from the reference
  pose (over the time with a pose), and the share of the scan's duration with a pose
  (``motion_pose_coverage``).
"""

from __future__ import annotations

import datetime as _dt
from collections.abc import Callable
from pathlib import Path

import numpy as np

from vts_hw import __version__, catalog
from vts_hw.errors import DataError
from vts_hw.figures import figure_png
from vts_hw.files import WriteFailed, export_stopped
from vts_hw.motion import MotionResult, MotionSettings, analyze_motion, marker_series
from vts_hw.motion.agreement import Agreement
from vts_hw.motion.bands import band_names
from vts_hw.motion.exports import clock_text, coverage_json, export_motion, time_origin
from vts_hw.procedures.motion_live import LiveRecord, agreement, host_to_series, read_live
from vts_hw.procedures.motion_plot import motion_figure
from vts_hw.procedures.sync import SyncAnalysis
from vts_hw.procedures.sync_inputs import CLOCK_SLACK_S
from vts_hw.recording.folder import load_manifest
from vts_hw.results import Measure, overall_state
from vts_hw.spect.frame import frame_description
from vts_hw.tolerance import State
from vts_hw.tracking.processing import process_recording
from vts_hw.vision.calibration_io import read_calibration
from vts_hw.vision.registration import read_mapping

__all__ = ["MotionAnalysis", "METRICS", "event_time_text"]

METRICS = {"motion_body_max_mm": "mm", "motion_body_max_deg": "deg", "motion_pose_coverage": "fraction"}


def event_time_text(e: dict) -> str:
    """An event's times as said: measured, or bounded by the time without a pose it fell in."""
    if e.get("start_bounds_s"):
        a, b = e["start_bounds_s"]
        why = e.get("start_bounded_why") or "in time without a pose"
        start = f"start between {a:.2f} and {b:.2f} s ({why}: known only to within it)"
    else:
        start = f"start {e['t_start']:.2f} s"
    if e.get("end_bounds_s"):
        a, b = e["end_bounds_s"]
        end = f"end between {a:.2f} and {b:.2f} s"
    else:
        end = f"end {e['t_end']:.2f} s"
    return f"{start}, {end}"


class MotionAnalysis:
    """The motion analysis of one session (see the module). ``tracks``: already processed
    tracks (then no recording is read; ``session`` only names the run). ``settings``: a
    :class:`~vts_hw.motion.MotionSettings` (``motion_config``: a rig.yaml ``motion:`` section
    whose ``state_mm``/``state_deg`` are taken)."""

    procedure = catalog.MOTION.name

    def __init__(
        self,
        session,
        listmode=None,
        calibration=None,
        mapping=None,
        *,
        tracks=None,
        settings: MotionSettings | None = None,
        motion_config=None,
        workers: int | None = None,
        progress: Callable[[int, int], None] | None = None,
        clock_slack_s: float | None = None,
    ):
        self.session = Path(session)
        self.listmode = listmode  # a file, or several: the sync analysis takes the session's own
        self.clock_slack_s = clock_slack_s
        self.calibration = calibration
        self.mapping = mapping
        self.tracks = tracks
        if settings is None:
            settings = MotionSettings()
            if motion_config is not None:
                settings = MotionSettings(state_mm=motion_config.state_mm, state_deg=motion_config.state_deg)
        self.settings = settings
        self.workers = workers
        self.progress = progress
        self.result: MotionResult | None = None
        self.sync: SyncAnalysis | None = None
        self.problems: list[str] = []
        self.export_notes: list[str] = []  # what export() did not write, and why
        self.manifest: dict = {}
        self.live: LiveRecord | None = None  # the scan's live path read back (procedures/motion_live.py)
        self.live_agreement: Agreement | None = None  # its poses against the offline ones (vts_hw/motion/agreement.py)
        self.tolerances = catalog.windows()
        self.analyzed_at: str | None = None

    # ------------------------------------------------------------------ load
    def _load_tracks(self) -> None:
        if self.tracks is not None:
            return
        if not self.session.is_dir():
            raise DataError(f"{self.session}: no such session folder")
        if self.calibration is None:
            raise DataError(f"{self.session}: no calibration given: the markers cannot be triangulated")
        if self.listmode is not None:
            self.sync = sync = SyncAnalysis(
                self.session,
                self.listmode,
                self.calibration,
                self.mapping,
                workers=self.workers,
                progress=self.progress,
                clock_slack_s=CLOCK_SLACK_S if self.clock_slack_s is None else self.clock_slack_s,
            )
            sync.analyze()
            self.tracks = sync.tracks
            self.manifest = sync.manifest or {}
            self.problems += [f"sync: {p}" for p in sync.problems]
            return
        self.manifest = load_manifest(self.session, missing_ok=True) or {}
        if not self.manifest.get("cameras"):
            raise DataError(f"{self.session}: not a recording folder (no manifest.json with cameras)")
        self.tracks = process_recording(
            self.session,
            read_calibration(self.calibration),
            workers=self.workers,
            mapping=read_mapping(self.mapping),
            progress=self.progress,
        )
        self.problems += [f"processing: {w}" for w in self.tracks.meta.get("warnings", [])]

    def _span(self, series) -> tuple[tuple | None, list[str]]:
        """The scan's span on the series' clock and what the recording lacks, from the tracks'
        ``extent`` (None: the first and last frame set, as for tracks made without a recording)."""
        ext = (self.tracks.meta or {}).get("extent") or {}
        first, last = ext.get("first_s"), ext.get("last_s")
        if first is None or last is None:
            return None, []
        to_series = host_to_series(self.tracks, series.clock)
        if to_series is None:
            return None, list(ext.get("problems") or [])
        return (float(to_series(first)), float(to_series(last))), list(ext.get("problems") or [])

    # ------------------------------------------------------------------ analysis
    def analyze(self, tolerances: dict | None = None) -> MotionAnalysis:
        """``tolerances``: the rig's windows (rig.yaml ``tolerances:``) over the defaults."""
        self.tolerances = catalog.windows(tolerances)
        self._load_tracks()
        series = marker_series(self.tracks)
        span, missing = self._span(series)
        self.problems = [p for p in self.problems if p.split(": ", 1)[-1] not in missing]
        self.problems += [f"recording: {m}" for m in missing]
        if not self.manifest and self.session.is_dir():
            self.manifest = load_manifest(self.session, missing_ok=True) or {}
        self.live = live = read_live(self.session, self.manifest)
        self.problems += live.problems
        model = live.model
        if model is not None and model.frame != series.frame:
            self.problems.append(
                f"live model not used: it is in the {model.frame.upper()} frame, the tracks in the "
                f"{series.frame.upper()} frame (give the mapping the scan used)"
            )
            model = None
        result = None
        if model is not None:
            try:
                result = analyze_motion(series, self.settings, span=span, missing=missing, model=model)
            except DataError as exc:  # the model is not this recording's: learn one from it
                self.problems.append(f"live model not used: {exc}")
                model = None
        if result is None:
            result = analyze_motion(series, self.settings, span=span, missing=missing)
        self.result = result
        self.problems += list(result.notes)
        if model is not None:
            lm = self.manifest.get("live_motion") or {}
            try:
                self.live_agreement = agreement(
                    live, result, self.tracks, float(lm.get("alert_mm", 3.0)), float(lm.get("alert_deg", 2.0))
                )
            except DataError as exc:
                self.problems.append(f"live poses not compared: {exc}")
        for name, cam in (self.manifest.get("cameras") or {}).items():
            gaps = cam.get("gaps") or []
            if gaps:
                self.problems.append(
                    f"camera {name}: {sum(g.get('missing', 0) for g in gaps)} frame(s) missing "
                    f"in {len(gaps)} gap(s) (manifest)"
                )
        if series.frame != "spect":
            self.problems.append("no VTS -> SPECT mapping: poses are in the VTS frame (camera 1's)")
        if series.clock != "spect":
            self.problems.append("no list-mode: times are on the host clock, not the SPECT's")
        self.analyzed_at = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
        return self

    def _need(self):
        if self.result is None:
            raise RuntimeError("call analyze() first")
        return self.result

    # ------------------------------------------------------------------ figures
    def figures(self) -> dict:
        r = self._need()
        pose = r.pose
        v = pose.valid
        shift = np.linalg.norm(pose.centre_shift()[v], axis=1) if v.any() else np.array([np.nan])
        ang = pose.angle_deg()[v] if v.any() else np.array([np.nan])
        return {
            "motion_body_max_mm": float(np.max(shift)),
            "motion_body_max_deg": float(np.max(ang)),
            "motion_pose_coverage": float(r.coverage["share"]),
        }

    def _time_sentence(self) -> str:
        """ "pose known 63.2 % of 90.0 s; 33.1 s without frames in 10 gaps (...); ..."."""
        c = self._need().coverage
        parts = [f"pose known {100 * c['share']:.1f} % of {c['duration_s']:.1f} s"]
        if c["no_frames_s"]:
            parts.append(
                f"{c['no_frames_s']:.1f} s without frames in {c['no_frames_gaps']} gap(s) "
                f"(longest {c['longest_gap_s']:.1f} s)"
            )
        if c["few_markers_s"]:
            parts.append(
                f"{c['few_markers_s']:.1f} s with fewer than 3 patient markers in "
                f"{c['few_markers_stretches']} stretch(es)"
            )
        return "; ".join(parts)

    @property
    def measures(self) -> list[Measure]:
        f = self.figures()
        subject = {"motion_pose_coverage": "tracking"}
        return [Measure.judged(subject.get(m, "body"), m, f[m], METRICS[m], self.tolerances.get(m)) for m in METRICS]

    @property
    def state(self) -> State:
        return overall_state(self.measures)

    # ------------------------------------------------------------------ outputs
    def _rel(self, x):
        return float(x) - time_origin(self._need())

    def results_data(self) -> dict:
        r = self._need()
        t0 = time_origin(r)
        S, B = r.series, r.bands
        centres = [np.nanmedian(S.P[:, g].reshape(-1, 3), axis=0) for g in B.groups]
        names, naming = band_names(centres, S.frame)
        band_of = {m: names[k] for k, g in enumerate(B.groups) for m in g}
        markers = [
            {
                "marker": S.label(m),
                "number": S.number(m),
                "track_ids": [int(i) for i in S.ids[m]],
                "patient": m in B.patient,
                "band": band_of.get(m),
                "why": B.why[m],
                "seen_fraction": float(B.seen_fraction[m]),
                "breathing_rms_mm": float(B.breath_rms_mm[m]),
                "points_by_camera": S.camera_sets[m] if S.camera_sets else {},
            }
            for m in range(len(S.ids))
        ]
        resp = r.respiration
        measures = self.measures
        fig = resp.figures
        cov = r.coverage
        summary = {
            **self.figures(),
            "events": len(r.events),
            "states": len(r.states),
            "time": self._time_sentence(),
            "duration_s": cov["duration_s"],
            "pose_known_s": cov["pose_s"],
            "no_frames_s": cov["no_frames_s"],
            "no_frames_gaps": cov["no_frames_gaps"],
            "few_markers_s": cov["few_markers_s"],
            "breathing": fig.status,
            "breathing_why": fig.why,
            "breathing_cycles": len(resp.cycles),
            "breathing_rate_per_min": resp.mean_rate_per_min,
            "breathing_rate_range_per_min": fig.rate_range if resp.mean_rate_per_min is not None else None,
            "breathing_amplitude_mm": fig.amplitude_mm if fig.status != "none" else None,
            "breathing_share": fig.share,
            "events_start_bounded": sum(e.start_bounds is not None for e in r.events),
            "pose_fit_rms_mm": float(np.nanmedian(r.pose.rms_mm)) if r.pose.valid.any() else None,
            "state": str(overall_state(measures)),
        }
        tm = self.tracks.meta if self.tracks is not None else {}
        return {
            "procedure": self.procedure,
            "date": self.analyzed_at,
            "vts_hw_version": __version__,
            "session": str(self.session),
            "listmode": None if self.listmode is None else str(getattr(self.sync, "listmode_path", self.listmode)),
            "clock": clock_text(r),
            "time_origin": t0,
            "frame": frame_description(S.frame, self.spect_volume()),
            "summary": summary,
            "measures": [m.as_dict() for m in measures],
            "windows": {m: self.tolerances[m].as_dict() for m in METRICS if m in self.tolerances},
            "reference_period_s": [r.reference_period[0] - t0, r.reference_period[1] - t0],
            "bands": [{"band": name, "markers": [S.label(m) for m in g]} for name, g in zip(names, B.groups)],
            "band_naming": naming,
            "markers": markers,
            "events": [e.to_json(t0) for e in r.events],
            "states": [s.to_json(t0) for s in r.states],
            "breathing": resp.figures.to_json(),
            "coverage": coverage_json(r, t0),
            "pose_gaps_s": [[a - t0, b - t0] for a, b in r.gaps],
            "speed_thresholds_mm_s": r.thresholds,
            "cameras": {
                "names": list(S.camera_names),
                "points_by_cameras_seen": tm.get("points_by_cameras_seen"),
                "unpaired_frames": tm.get("unpaired_frames"),
                "single_camera_detections": tm.get("single_camera_detections"),
            },
            "settings": dict(vars(self.settings)) if hasattr(self.settings, "__dict__") else {},
            "live": None if self.live_agreement is None else self.live_agreement.to_json(t0),
            "problems": list(self.problems),
        }

    def results(self) -> str:
        d = self.results_data()
        s = d["summary"]
        lines = [
            f"patient motion: {self.session} ({d['date']}, vts-hw {d['vts_hw_version']})",
            f"  times: {d['clock']}",
            f"  positions: {d['frame']['definition']}",
            f"  patient markers: {len([m for m in d['markers'] if m['patient']])} in {len(d['bands'])} band(s) "
            f"({'; '.join(b['band'] + ': ' + ', '.join(b['markers']) for b in d['bands'])}); reference {d['reference_period_s'][0]:.1f}-"
            f"{d['reference_period_s'][1]:.1f} s",
            f"  time: {s['time']}",
            f"  breathing: {self._breathing_text(d['breathing'])}",
            f"  body: moved up to {s['motion_body_max_mm']:.2f} mm and {s['motion_body_max_deg']:.2f} deg from "
            f"the reference in the time with a pose"
            + (f" (fit RMS {s['pose_fit_rms_mm']:.3f} mm)" if s["pose_fit_rms_mm"] is not None else ""),
        ]
        for k, e in enumerate(d["events"], 1):
            c = e["change_6dof"]
            lines.append(
                f"  event {k}: {event_time_text(e)}, shift {e['centroid_shift_mm']:.1f} mm, "
                f"turn {e['rotation_deg']:.2f} deg (t {c[0]:+.1f} {c[1]:+.1f} {c[2]:+.1f} mm, "
                f"r {c[3]:+.2f} {c[4]:+.2f} {c[5]:+.2f} deg)"
            )
        for st in d["states"]:
            x = st["six_dof"]
            gap = f" ({st['unknown_s']:.1f} s of it without a pose, in no state)" if st["unknown_s"] else ""
            lines.append(
                f"  state {st['state']}: {st['t_start']:.2f}-{st['t_end']:.2f} s{gap}, pose t {x[0]:+.2f} "
                f"{x[1]:+.2f} {x[2]:+.2f} mm, r {x[3]:+.2f} {x[4]:+.2f} {x[5]:+.2f} deg"
            )
        for m in d["measures"]:
            lines.append(f"  {m['metric']}: {m['value']:.3g} {m['unit']} -> {m['state']}")
        if self.live_agreement is not None:
            la = self.live_agreement
            lines.append(f"  live: {la.text()}")
            for k, a in enumerate(d["live"]["alerts"], 1):
                lines.append(
                    f"  live alert {k} (onset {a['onset']:.2f} s): "
                    + (f"explained by {a['by']}" if a["explained"] else f"NOT explained offline: {a['why']}")
                )
        lines.append(f"  state: {s['state']}")
        for p in self.problems:
            lines.append(f"  note: {p}")
        return "\n".join(lines)

    @staticmethod
    def _breathing_text(b: dict) -> str:
        amp = (
            f"amplitude {b['amplitude_mm']:.1f} mm ({b['half_breaths_seen']} half breaths)"
            if b["amplitude_mm"] is not None
            else "amplitude unknown"
        )
        if b["status"] == "measured":
            return f"{b['rate_per_min']:.1f} /min, {amp} ({b['why']})"
        if b["status"] == "bounded":
            lo, hi = b["rate_range_per_min"]
            return (
                f"{b['rate_per_min']:.1f} /min, known only to {lo:.1f}-{hi:.1f} /min; {amp} "
                f"(from breaths seen whole over {b['rate_rests_on_s']:.1f} s, "
                f"{100 * b['share_of_scan']:.0f} % of the scan)"
            )
        return b["why"] + (f"; {amp}" if b["status"] == "unknown" else "")

    def figure(self):
        return motion_figure(self._need(), self.results_data())

    def plot(self, path=None) -> bytes:
        return figure_png(self.figure(), path)

    def spect_volume(self) -> dict | None:
        """What the VTS -> SPECT mapping kept of the volume it was made from (the volume that
        places the SPECT frame; vts_hw.spect.frame), if it says."""
        meta = (self.tracks.meta if self.tracks is not None else {}).get("spect_mapping")
        volume = ((meta or {}).get("meta") or {}).get("spect_volume") if isinstance(meta, dict) else None
        return volume if isinstance(volume, dict) else None

    def export(self, out, n_bins: int = 4) -> list[Path]:
        """The motion files (docs/motion-formats.md) and the marker trajectories
        (``trajectories.csv``/``.json``, docs/trajectory-format.md) into ``out``;
        :attr:`export_notes`: the files not written and why (the CASToR files and YRT-PET's LOR motion
        file need the SPECT clock and a mapping that says its volume), the motion states CASToR's
        whole seconds merge."""
        r = self._need()
        try:
            written = export_motion(
                r,
                out,
                n_bins=n_bins,
                volume=self.spect_volume(),
                extra={"session": str(self.session), "vts_hw_version": __version__},
            )
            self.export_notes = list(written.notes)
            paths = list(written)
            if self.tracks is not None:
                paths += list(self.tracks.save(Path(out) / "trajectories.csv"))
        except WriteFailed as exc:  # each file whole or absent; say what that leaves of the export
            raise export_stopped(exc, out) from None
        return paths
