"""The Daily QA page's work: the daily QA, a drift baseline and the push to QATrack+, as the
`vts qa` commands do them, in worker threads.

* **One camera job at a time** (a daily QA or a baseline: both switch the LED rings and take
  frames). Another asked meanwhile is refused with what is running (:class:`Busy`); so is one
  whose camera a recording of the console holds (a scan).
* **The same functions as the commands**: ``procedures.daily.QARun`` recorded by
  ``store.qa_record.record_qa`` (`vts qa daily`); ``procedures.baseline.take_baselines`` and
  ``store.recorder.record`` (`vts qa drift --set-baseline`); ``qatrack.select_runs`` and
  ``push_runs`` through the store's outbox (`vts qa push`). Cameras are opened from the room
  (``vts_hw.room.Room``) as the commands open them; the rig is the console's (``console.rig_config``).
* **No second stream to a camera the hub streams**: just before a camera's LED frames the hub
  steps aside for it (``hub.attach``: its own stream closed and waited for), the frames the
  procedure takes are fed to the hub (``hub.feed``: the Room page shows them, RECORDING), and
  the hub takes the camera back when the camera is done (``hub.detach``), whatever happened.
* **Progress** (:meth:`Jobs.snapshot`): which camera, which step, frames taken of needed,
  since when; ``version`` goes up at each change (the page's event stream sends it then).
* A job that fails says so in one sentence (``error``); what the store already holds stays
  (the recorder's one transaction, or its unsaved file when the store refused the run).
* The action log gets the job's outcome once it has ended, never "done" for one that failed:
  ``daily QA run`` / ``drift baseline set`` when it took, ``daily QA not stored`` when it ran
  but the store did not take it, ``daily QA failed`` / ``drift baseline not set`` and why.
"""

from __future__ import annotations

import threading
import time

from vts_hw.console.qa_view import view_of_result, view_of_run
from vts_hw.drivers.registry import check_camera_kinds
from vts_hw.errors import ConfigError, VtsError
from vts_hw.procedures.baseline import take_baselines
from vts_hw.procedures.daily import STEPS, QARun
from vts_hw.qatrack import exit_code, push_runs, select_runs
from vts_hw.room import Room
from vts_hw.store.qa_record import artifacts_dir, record_qa
from vts_hw.store.recorder import record

KINDS = {"daily": "daily QA", "baseline": "drift baseline"}
#: what the action log says of a job that ended: (took, failed)
SAID = {"daily": ("daily QA run", "daily QA failed"), "baseline": ("drift baseline set", "drift baseline not set")}


class Busy(VtsError):
    """Another camera job (or push) is running: one sentence saying which."""


class Jobs:
    """The camera jobs of one console (``console.rig_config``, ``open_store``, ``hub``,
    ``facts``, ``actions``)."""

    def __init__(self, console, clock=time.time):
        self.console = console
        self.clock = clock
        self._lock = threading.Lock()
        self._push_lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self.version = 0
        self.ended = 0  # jobs ended since the console started (a plot drawn before is old)
        self._job: dict = {"state": "idle"}

    # -- what the page reads -----------------------------------------------------------------------
    def snapshot(self) -> dict:
        with self._lock:
            return {**self._job, "version": self.version, "now": self.clock(), "pushing": self._push_lock.locked()}

    def _set(self, **changes) -> None:
        with self._lock:
            self._job.update(changes)
            self.version += 1

    @property
    def rig(self):
        rig = self.console.rig_config
        if rig is None:
            raise ConfigError("this console was started without a rig config: the QA cannot run from it")
        return rig

    def cameras(self) -> list[str]:
        rig = self.console.rig_config
        return [c.name for c in rig.cameras] if rig is not None else list(getattr(self.console.hub, "names", []))

    def _store(self):
        if self.console.open_store is None:
            raise VtsError("no results store is named for this console")
        return self.console.open_store()

    # -- starting ----------------------------------------------------------------------------------
    def start(self, kind: str, user: str, frames: int, cameras: list[str] | None = None) -> dict:
        """Start job ``kind`` (daily / baseline) for ``user``; Busy when one is running or a
        camera is held by a recording of the console."""
        _ = self.rig  # none: ConfigError (400) before anything starts
        names = list(cameras or self.cameras())
        hub = self.console.hub
        with self._lock:
            job = self._job
            if job["state"] == "running":
                raise Busy(
                    f"a {KINDS[job['kind']]} is already running (started by {job['user']} at "
                    f"{time.strftime('%H:%M:%S', time.gmtime(job['started']))} UTC): wait for it to end"
                )
            held = [n for n in names if hub is not None and n in hub.names and hub.source(n) == "fed"]
            if held:
                raise Busy(f"camera {held[0]} is recording (a scan): the {KINDS[kind]} can run once it has ended")
            self._job = {
                "state": "running",
                "kind": kind,
                "what": KINDS[kind],
                "user": user,
                "started": self.clock(),
                "cameras": names,
                "frames": frames,
                "camera": "",
                "index": 0,
                "step": "starting",
                "taken": 0,
                "needed": 0,
                "done": {},
                "error": "",
                "result": None,
                "run": None,
            }
            self.version += 1
            target = self._daily if kind == "daily" else self._baseline
            self._thread = threading.Thread(
                target=self._run, args=(target, user, frames, names), name=f"console-{kind}", daemon=True
            )
            self._thread.start()
            return dict(self._job)

    def wait(self, timeout: float | None = None) -> None:
        t = self._thread
        if t is not None:
            t.join(timeout)

    def _run(self, target, user, frames, names) -> None:
        attached: list[str] = []
        kind = self._job["kind"]
        took, failed = SAID[kind]
        try:
            detail = target(user, frames, names, attached)
            ended = {"state": "done", "step": "done", "finished": self.clock()}
            what = "daily QA not stored" if detail.get("not_stored") else took
        except VtsError as exc:
            detail, what = {"why": str(exc)}, failed
            ended = {"state": "failed", "error": str(exc), "finished": self.clock()}
        except Exception as exc:  # a bug must still end the job with its sentence, never hang the page
            detail, what = {"why": f"{type(exc).__name__}: {exc}"}, failed
            ended = {
                "state": "failed",
                "error": f"the {KINDS.get(kind, 'job')} stopped: {type(exc).__name__}: {exc}",
                "finished": self.clock(),
            }
        finally:
            self._release(attached)
        self.ended += 1
        self._set(**ended)
        self._record(user, what, {**detail, "cameras": names})
        facts = getattr(self.console, "facts", None)
        if facts is not None and hasattr(facts, "read_daily_qa"):
            try:
                facts.read_daily_qa()  # the Room page's daily QA state, now rather than in 30 s
            except Exception:
                pass

    def _record(self, user: str, what: str, detail: dict) -> None:
        try:
            self.console.actions.record(user, what, detail)
        except Exception as exc:  # the log failing costs the run nothing; the page hears of it
            self._set(log_error=f"the action could not be logged: {exc}")

    # -- the hub steps aside for a camera, and takes it back --------------------------------------
    def _take(self, name: str, attached: list[str]) -> None:
        hub = self.console.hub
        if hub is not None and name in hub.names and name not in attached:
            hub.attach([name])
            attached.append(name)

    def _give_back(self, name: str, attached: list[str]) -> None:
        if name in attached:
            attached.remove(name)
            self.console.hub.detach([name])

    def _release(self, attached: list[str]) -> None:
        for name in list(attached):
            self._give_back(name, attached)

    def _frame(self, name, frame, taken, needed, attached) -> None:
        if frame is None and taken == 0:
            self._take(name, attached)  # before the LED is switched and the first frame taken
        elif frame is not None and name in attached:
            self.console.hub.feed(name, frame)
        self._set(camera=name, step="drift", taken=taken, needed=needed)

    # -- the daily QA: `vts qa daily` ---------------------------------------------------------------
    def _daily(self, user, frames, names, attached) -> dict:
        rig = self.rig
        check_camera_kinds(rig.camera(n) for n in names)

        def on_step(st) -> None:
            if st.step == "drift":
                self._frame(st.camera, st.frame, st.taken, st.needed, attached)
                return
            if st.step == "done":
                self._give_back(st.camera, attached)
                with self._lock:
                    self._job["done"] = {**self._job["done"], st.camera: st.state}
            self._set(camera=st.camera, index=st.index, step=st.step, taken=0, needed=0)

        with self._store() as store, Room(rig, clock=self.clock) as room:  # each camera when its turn comes
            run = QARun(
                rig,
                steps=STEPS,
                cameras=names,
                n_frames=frames,
                artifacts_dir=artifacts_dir(store),
                open_camera=lambda cfg: room.camera(cfg.name),
                clock=self.clock,
                on_step=on_step,
            )
            self._set(step="reading the baselines")
            result, stored = record_qa(store, run, rig, operator=user, clock=self.clock)
            self._set(step="stored", run=result.run_id)
            problems = {c.camera: c.problems for c in result.cameras}
            if result.store_error:
                view = view_of_result(result, names)
            else:
                view = view_of_run(store, result.run_id, names, problems)
        note = ""
        if result.store_error:
            where = (
                f"its figures are below and in {stored.unsaved} (`vts qa import {stored.unsaved}` stores them later)"
                if stored.unsaved
                else "its figures are below only: no fallback file could be written either"
            )
            note = f"the daily QA ran but was NOT stored: {result.store_error}; {where}"
        self._set(result=view, note=note)
        return {"run": result.run_id, "state": str(result.state), **({"not_stored": note} if note else {})}

    # -- a drift baseline: `vts qa drift --set-baseline` --------------------------------------------
    def _baseline(self, user, frames, names, attached) -> dict:
        rig = self.rig
        cfgs = [rig.camera(n) for n in names]
        for cfg in cfgs:  # unset password variables: before anything is touched
            cfg.password()
        check_camera_kinds(cfgs)
        done: list[str] = []

        def on_frame(name, frame, taken, needed):
            if taken == 0:
                for prev in done:
                    self._give_back(prev, attached)
                done.append(name)
                self._set(index=len(done))
            self._frame(name, frame, taken, needed, attached)

        with self._store() as store, Room(rig, clock=self.clock) as room:
            cams = [room.camera(cfg.name) for cfg in cfgs]
            result = take_baselines(cams, frames=frames, clock=self.clock, on_frame=on_frame, rig=rig)
            self._release(attached)
            started = self.clock()
            stored = record(
                store,
                result,
                rig=rig.rig,
                operator=user,
                config_digest=rig.digest,
                tolerances=rig.tolerances,
                started=started,
                finished=started,
                clock=self.clock,
            )
        if not stored.ok:
            raise VtsError(
                f"the baseline was NOT stored: {stored.error}"
                + (f"; it is kept in {stored.unsaved} (`vts qa import` stores it later)" if stored.unsaved else "")
            )
        made = {b.camera: len(b.markers) for b in result.baselines}
        self._set(run=stored.run_id, result={"baseline": made, "run": stored.run_id})
        return {"run": stored.run_id, "markers": made}

    # -- the push: `vts qa push` --------------------------------------------------------------------
    def push(self, user: str) -> dict:
        """Every finished run of this rig not yet in QATrack+ (as `vts qa push`), through the
        outbox; in the calling thread (the page's request runs it in one). Busy while a push runs."""
        if not self._push_lock.acquire(blocking=False):
            raise Busy("a push to QATrack+ is already running: wait for it to end")
        try:
            self._set()
            rig = self.rig
            if rig.qatrack is None:
                raise ConfigError(
                    f"{rig._source or 'rig.yaml'}: no qatrack: section (url, unit, token_env or "
                    f"user_env/password_env, lists); see docs/operate/qatrack.md"
                )
            rig.qatrack.credentials()  # an unset variable: one sentence before anything is sent
            with self._store() as store:
                chosen = select_runs(store, rig.qatrack, rig.rig, ())
                outcomes = push_runs(store, rig.qatrack, chosen)
        finally:
            self._push_lock.release()
            self._set()
        rows = [{**o.as_dict(), "line": o.line()} for o in outcomes]
        counts = {s: sum(1 for o in outcomes if o.state == s) for s in ("sent", "pending", "refused")}
        return {
            "outcomes": rows,
            "counts": counts,
            "exit_code": exit_code(outcomes),
            "summary": (
                f"QATrack+: {counts['sent']} of {len(outcomes)} sent, {counts['pending']} pending, "
                f"{counts['refused']} refused"
            )
            if outcomes
            else "QATrack+: nothing to push",
        }


__all__ = ["Jobs", "Busy", "KINDS"]
