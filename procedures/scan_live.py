"""The live motion path of a scan session: the tracker fed from the recording, its alerts
acted on (terminal, manifest, command), its state for the live view.

:class:`LiveMotion` is given to :class:`~vts_hw.procedures.scan.ScanSession` (``live=``). The
session calls :meth:`LiveMotion.prepare` once the camera clocks are measured (the tracker needs
their offsets), hands :meth:`LiveMotion.on_frame` to its recorder (called after each frame is
written), and :meth:`LiveMotion.start` / :meth:`LiveMotion.stop` around the recording. Without
a calibration of two of the session's cameras the live path stays off (the manifest says why)
and the scan records as always.

An alert is acted on in a thread of its own, never in the worker: ``on_alert_text(text)`` (the
CLI prints the line and rings the bell), ``motion.alert_command`` started with the text as its
last argument (no shell, not waited for; a failure to start it or a non-zero exit is reported
through ``on_note`` and into the manifest, never fatal), and the event appended to the
manifest through the session's locked, atomic rewrite. There are two kinds, acted on the same
way: ``PATIENT MOVED`` (``live_motion.alerts``) and ``PATIENT NOT TRACKED``
(``live_motion.blind_alerts``: NOT TRACKING for longer than ``motion.blind_alert_s``). An alert
raised more than ``LATE_SAY_S`` after the frame that raised it (a busy host: the live path behind
its frames) says so in its line and carries ``late_s`` in the manifest: its delay after the move
is then the computer's, and reported, never passed off as the rule's.

Whether the patient is watched goes into the manifest as it changes: ``live_motion.state``
(TRACKING, REFERENCE or NOT TRACKING with its reason, since when) and each stretch NOT
TRACKING once it ends (``live_motion.not_tracking``). At the end the summary gives the time in
each status, and :attr:`LiveMotion.problem` says when the patient was not watched: no
reference learned, or NOT TRACKING for more than ``motion.blind_max_share`` of the live time
(the scan then exits 4). See docs/decisions/0048-live-tracking-when-frames-are-lost.md.

What the technologist was shown is kept in the scan's folder (docs/decisions/0092): the patient
model once learned (``live_model.json``) and every live pose, appended each second from the
alerts' thread (``live_poses.csv``: time, pose, breathing, residual, markers, cameras, alert state,
health, the frames it came from). `vts motion analyze` fits that model and compares. A folder
that cannot take them is said once (``live_motion.keep_problem``); the scan goes on.
"""

from __future__ import annotations

import datetime as _dt
import queue
import subprocess
import threading
import time
from collections.abc import Callable

from vts_hw.errors import VtsError
from vts_hw.lifeline import child_options
from vts_hw.tracking.live.estimator import LiveEstimate, LiveSettings
from vts_hw.tracking.live.pose_log import MODEL_FILE, POSES_FILE, PoseLog, save_model
from vts_hw.tracking.live.tracker import LiveTracker
from vts_hw.tracking.live.watch import TRACKING, BlindAlert, Change, Episode
from vts_hw.vision.calibration_io import read_calibration
from vts_hw.vision.camera_set import covered_names, named_cameras
from vts_hw.vision.marker_roles import TableSpace
from vts_hw.vision.registration import read_mapping

__all__ = ["LiveMotion"]

COMMAND_TIMEOUT_S = 60.0
KEEP_EVERY_S = 1.0  # the live poses appended to the scan's folder this often (a kill -9 loses at most this)
EPISODES_KEPT = 500  # NOT TRACKING stretches listed in the manifest (the rest counted)


#: an alert raised longer than this after the frame (or watch tick) that raised it says so: the
#: computer was behind (a busy host), so its delay after the move is the host's, not the rule's
LATE_SAY_S = 0.25


def late_note(late_s: float) -> str:
    return f" (raised {late_s:.1f} s after its frame: this computer is behind)" if late_s > LATE_SAY_S else ""


def _iso(t: float) -> str:
    return _dt.datetime.fromtimestamp(t, _dt.UTC).isoformat(timespec="milliseconds")


class LiveMotion:
    """``calibration``/``mapping``: a path or object (default: the rig's ``calibration.cameras``
    and ``calibration.mapping``); ``settings``: the estimator's (default reference 10 s)."""

    def __init__(
        self,
        rig,
        *,
        calibration=None,
        mapping=None,
        settings: LiveSettings | None = None,
        on_alert_text: Callable[[str], None] | None = None,
        on_note: Callable[[str], None] | None = None,
        queue_len: int = 2,
        on_names: Callable | None = None,
    ):
        self.rig = rig
        self.motion = rig.motion
        self.calibration = calibration if calibration is not None else rig.calibration.cameras
        self.mapping = mapping if mapping is not None else rig.calibration.mapping
        self.settings = settings
        self.on_alert_text = on_alert_text or (lambda text: None)
        self.on_note = on_note or (lambda text: None)
        self.queue_len = queue_len
        self.on_names = on_names  # the tracker's named patient markers per camera (a page's labels)
        self.tracker: LiveTracker | None = None
        self.off_reason = ""
        self.problem = ""  # set at stop: the patient was not watched, and why
        self.alerts: list[dict] = []
        self.blind_alerts: list[dict] = []
        self.commands: list[subprocess.Popen] = []
        self._actions: queue.Queue = queue.Queue()
        self._thread: threading.Thread | None = None
        self._waiters: list[threading.Thread] = []
        self._tracked_once = False
        self._log: PoseLog | None = None  # the live poses, kept in the scan's folder
        self._kept = 0  # poses written there so far
        self._model_saved = False
        self.keep_problem = ""  # why the live poses or model could not be kept

    # -- set-up ---------------------------------------------------------------------------------
    def prepare(self, session) -> None:
        """Build the tracker for the session's cameras (offsets measured); off with a reason
        when there is no calibration or it cannot be read."""
        names = [c.name for c in session.cameras]
        try:
            if self.calibration is None:
                raise VtsError("no camera calibration (calibration.cameras in rig.yaml)")
            cal = read_calibration(self.calibration)
            cams = named_cameras(cal, covered_names(cal, [c.name for c in self.rig.cameras]))
            cams = {n: cams[n] for n in names if n in cams}
            if len(cams) < 2:
                raise VtsError(f"the calibration covers fewer than two of the cameras {', '.join(names)}")
            mapping = read_mapping(self.mapping) if self.mapping is not None else None
        except (VtsError, OSError, ValueError) as exc:
            self.off_reason = str(exc)
            self.on_note(f"live tracking off: {exc}")
            return
        offsets = {
            n: (session.cam_notes.get(n, {}).get("clock_offset_before") or {}).get("offset_s", 0.0) for n in cams
        }
        fps = min(session.rig.camera(n).fps for n in cams)
        space = TableSpace.from_settings(self.rig.aim, mapping) if mapping is not None else None
        self.tracker = LiveTracker(
            cams,
            self.motion,
            mapping=mapping,
            clock_offsets=offsets,
            fps=fps,
            settings=self.settings,
            queue_len=self.queue_len,
            on_alert=self._queue_alert,
            on_event=self._queue_event,
            on_names=self.on_names,
            space=space,
        )

    def on_frame(self, camera: str, frame) -> None:
        if self.tracker is not None:
            self.tracker.on_frame(camera, frame)

    def start(self, session) -> None:
        m = self.motion
        entry = {
            "status": "off" if self.tracker is None else "on",
            "alerts": [],
            "alert_mm": m.alert_mm,
            "alert_deg": m.alert_deg,
            "alert_after_s": m.alert_after_s,
            "blind_alert_s": m.blind_alert_s,
            "blind_max_share": m.blind_max_share,
            **(
                {}
                if self.tracker is None
                else {
                    "state": {"status": "NOT TRACKING", "reason": "no frames yet"},
                    "blind_alerts": [],
                    "not_tracking": [],
                }
            ),
            **(
                {"off_reason": self.off_reason}
                if self.tracker is None
                else {"frame": self.tracker.estimator.frame, "cameras": self.tracker.names}
            ),
        }
        session.recorder.recording.meta["live_motion"] = entry
        if self.tracker is None:
            return
        self._thread = threading.Thread(target=self._act, args=(session,), name="live-alerts", daemon=True)
        self._thread.start()
        self.tracker.start()

    def stop(self, session) -> None:
        """The tracker stopped, pending alerts acted on, the summary into the manifest."""
        tracker = self.tracker
        if tracker is None:
            return
        tracker.stop()
        self._actions.put(None)
        if self._thread is not None:
            self._thread.join(10)
        self._keep(session)
        if self._log is not None:
            self._log.close()
        snap = tracker.snapshot()
        st = tracker.stats(last=None)
        summary = {
            k: st.get(k)
            for k in (
                "sets",
                "live_dropped",
                "tapped",
                "processed",
                "queued",
                "unmatched_frames",
                "undecodable",
                "latency_ms_p50",
                "latency_ms_p95",
                "latency_from_first_frame_ms_p50",
                "latency_from_first_frame_ms_p95",
            )
        }
        rule = tracker.estimator.rule
        if rule is not None:
            summary.update(onset_mm=round(rule.onset_mm, 3), onset_deg=round(rule.onset_deg, 3))
        summary.update(
            poses_kept=self._kept,
            phase=snap.phase,
            reference=tracker.estimator.reference_note,
            note=snap.note,
            six_dof_last=snap.six_dof,
            **({"error": st["error"]} if st.get("error") else {}),
        )
        summary["tracking"] = tracking = self._tracking_summary(tracker)
        self.problem = self._verdict(tracker, tracking, snap)
        summary["watched"] = not self.problem
        if self.problem:
            summary["problem"] = self.problem
        session.update_manifest(lambda meta: meta["live_motion"].update(summary=summary))

    def _tracking_summary(self, tracker: LiveTracker) -> dict:
        w = tracker.watch
        tot = w.totals()
        eps = w.episodes
        longest = max(eps, key=lambda e: e.duration(e.start), default=None)
        out = {k: (round(v, 3) if isinstance(v, float) else v) for k, v in tot.items()}
        out.update(not_tracking_stretches=len(eps), blind_alerts=len(tracker.blind_alerts), late_s=tracker.late_s)
        if longest is not None:
            out.update(
                longest_not_tracking_s=round(longest.duration(longest.start), 3),
                longest_reason="; ".join(longest.reasons[:3]),
            )
        return out

    def _verdict(self, tracker: LiveTracker, tracking: dict, snap: LiveEstimate) -> str:
        """Why the patient was not watched ("" when they were)."""
        est = tracker.estimator
        if est.phase != "tracking":
            why = est.note or "no patient markers seen"
            return f"the patient was not watched: no reference was learned ({why})"
        share, limit = tracking.get("not_tracking_share"), self.motion.blind_max_share
        if share is not None and share > limit:
            return (
                f"the patient was not tracked for {share:.0%} of the live time (limit {limit:.0%}): "
                f"{tracking['not_tracking_s']:.1f} s in {tracking['not_tracking_stretches']} stretch(es), "
                f"the longest {tracking.get('longest_not_tracking_s', 0):.1f} s "
                f"({tracking.get('longest_reason', '')})"
            )
        return ""

    def snapshot(self, stats: bool = True) -> LiveEstimate | None:
        """The tracker's latest estimate; ``stats=False`` leaves out the latency percentiles
        (for a caller sampling it several times a second)."""
        return None if self.tracker is None else self.tracker.snapshot(stats=stats)

    # -- alerts ---------------------------------------------------------------------------------
    def _queue_alert(self, alert, estimate: LiveEstimate) -> None:  # in the worker: no waiting
        self._actions.put(("motion", alert, estimate))

    def _queue_event(self, event) -> None:  # in the watch thread: no waiting
        self._actions.put(("event", event, None))

    def _keep(self, session) -> None:
        """The model once learned, and the poses estimated since the last call, into the scan's
        folder (never fatal: a failure to write is said once, in the notes and the manifest)."""
        if self.tracker is None or self.keep_problem:
            return
        est = self.tracker.estimator
        try:
            if est.model is not None and not self._model_saved:
                save_model(session.folder, est.model)
                self._model_saved = True
                session.update_manifest(lambda meta: meta["live_motion"].update(model_file=MODEL_FILE))
            n = len(est.poses)
            if n > self._kept:
                if self._log is None:
                    self._log = PoseLog(session.folder)
                    session.update_manifest(lambda meta: meta["live_motion"].update(poses_file=POSES_FILE))
                self._kept += self._log.write(est.poses[self._kept : n])
        except (OSError, VtsError) as exc:
            self.keep_problem = f"the live poses could not be kept in {session.folder}: {exc}"
            self.on_note(f"live motion: {self.keep_problem}")
            problem = self.keep_problem
            session.update_manifest(lambda meta: meta["live_motion"].update(keep_problem=problem))

    def _act(self, session) -> None:
        while True:
            try:
                item = self._actions.get(timeout=KEEP_EVERY_S)
            except queue.Empty:
                self._keep(session)
                continue
            if item is None:  # the alert commands started here end before this thread does:
                for w in self._waiters:  # each dies with the thread that started it (child_options)
                    w.join()
                return
            kind, what, est = item
            try:
                if kind == "motion":
                    self._motion_alert(session, what, est)
                elif isinstance(what, BlindAlert):
                    self._blind_alert(session, what)
                elif isinstance(what, Change):
                    self._change(session, what)
                elif isinstance(what, Episode):
                    self._episode(session, what)
            except Exception as exc:  # a note, never the end of acting on alerts
                self.on_note(f"live motion: {type(exc).__name__}: {exc}")

    def _say(self, text: str) -> None:
        try:
            self.on_alert_text(text)
        except Exception:
            pass

    def _motion_alert(self, session, alert, est: LiveEstimate) -> None:
        raised = time.time()
        late = max(0.0, raised - alert.time)  # the host behind its frames: the alert says by how much
        text = alert.text(self.motion.alert_mm, self.motion.alert_deg) + late_note(late)
        self._say(text)
        event = {
            "kind": "motion",
            "raised": raised,
            "raised_utc": _iso(raised),
            "late_s": round(late, 3),
            "time": alert.time,
            "time_utc": _iso(alert.time),
            "onset": alert.onset,
            "onset_utc": _iso(alert.onset),
            "onset_known_s": round(alert.onset_known_s, 3),
            "move_mm": round(alert.move_mm, 3),
            "turn_deg": round(alert.turn_deg, 3),
            "frame": est.frame,
            "six_dof": None if est.six_dof is None else [round(v, 3) for v in est.six_dof],
            "text": text,
        }
        if self.motion.alert_command:
            event["command"] = self._run_command(session, list(self.motion.alert_command) + [text])
        self.alerts.append(event)
        session.update_manifest(lambda meta: meta["live_motion"]["alerts"].append(event))

    def _blind_alert(self, session, alert: BlindAlert) -> None:
        raised = time.time()
        late = max(0.0, raised - alert.raised)
        text = alert.text() + late_note(late)
        self._say(text)
        event = {
            "kind": "not tracking",
            "raised": raised,
            "raised_utc": _iso(raised),
            "late_s": round(late, 3),
            "since": alert.start,
            "since_utc": _iso(alert.start),
            "not_tracking_s": round(alert.raised - alert.start, 3),
            "reason": alert.reason,
            "text": text,
        }
        if self.motion.alert_command:
            event["command"] = self._run_command(session, list(self.motion.alert_command) + [text])
        self.blind_alerts.append(event)
        session.update_manifest(lambda meta: meta["live_motion"]["blind_alerts"].append(event))

    def _change(self, session, c: Change) -> None:
        state = {
            "status": c.status,
            "since": c.at,
            "since_utc": _iso(c.at),
            **({"reason": c.reason} if c.reason else {}),
        }
        if c.status == TRACKING and not self._tracked_once:
            self._tracked_once = True
            note = self.tracker.estimator.reference_note if self.tracker is not None else ""
            self.on_note(f"live motion: TRACKING ({note})")
        session.update_manifest(lambda meta: meta["live_motion"].update(state=state))

    def _episode(self, session, e: Episode) -> None:
        end = e.end
        if self.tracker is None or end is None:  # an episode is sent once it has ended
            return
        host = self.tracker.host_of
        entry = {
            "start": host(e.start),
            "start_utc": _iso(host(e.start)),
            "end": host(end),
            "end_utc": _iso(host(end)),
            "duration_s": round(end - e.start, 3),
            "reasons": e.reasons,
            "alerted": e.alerted,
        }
        if e.alerted:
            self.on_note(f"live motion: tracked again after {end - e.start:.1f} s NOT TRACKING ({e.reasons[0]})")

        def add(meta):
            lm = meta["live_motion"]
            if len(lm["not_tracking"]) < EPISODES_KEPT:
                lm["not_tracking"].append(entry)
            else:
                lm["not_tracking_more"] = lm.get("not_tracking_more", 0) + 1

        session.update_manifest(add)

    def _run_command(self, session, argv: list[str]) -> str:
        try:
            proc = subprocess.Popen(
                argv,
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE,
                shell=False,
                start_new_session=True,
                **child_options(),
            )
        except OSError as exc:
            self._command_failed(session, f"alert command {argv[0]!r} could not be started: {exc.strerror or exc}")
            return "not started"
        self.commands.append(proc)
        w = threading.Thread(target=self._wait_command, args=(session, proc, argv[0]), daemon=True)
        w.start()
        self._waiters.append(w)
        return "started"

    def _wait_command(self, session, proc: subprocess.Popen, name: str) -> None:
        try:
            _, err = proc.communicate(timeout=COMMAND_TIMEOUT_S)
        except subprocess.TimeoutExpired:  # no program outlives the scan's command that started it
            proc.kill()
            proc.wait()
            self._command_failed(session, f"alert command {name!r} still running after {COMMAND_TIMEOUT_S:g} s: ended")
            return
        if proc.returncode != 0:
            why = (err or b"").decode(errors="replace").strip().splitlines()[-1:] or [""]
            self._command_failed(
                session,
                f"alert command {name!r} failed (exit {proc.returncode})" + (f": {why[0][:200]}" if why[0] else ""),
            )

    def _command_failed(self, session, text: str) -> None:
        self.on_note(text)
        session.update_manifest(lambda meta: meta["live_motion"].setdefault("command_problems", []).append(text))
