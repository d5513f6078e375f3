""" "Analyse motion" on the Scan page: what `vts motion analyze SESSION -o ... --plot ... --export
...` runs, in a worker thread, with its progress, its report and exports written into the scan
folder (``motion/``), and its result stored in the results store as the command stores it.

* The analysis is :class:`~vts_hw.procedures.motion.MotionAnalysis` with the rig's calibration
  (``calibration.cameras``, ``calibration.mapping``; a relative path is beside rig.yaml:
  config.load_rig), its ``motion:`` section and tolerances; ``workers=1`` (in this
  process: a process pool forked from a threaded server can hang, and the room's cores are the
  live path's).
* The report (``motion/motion-report.html``, the plot inline), the plot (``motion/motion.png``)
  and the export (``motion/export/``) are each written whole or not at all
  (``vts_hw.files.Outputs``); one not written is said, and the result is still stored.
* Stored through ``vts_hw.store.recorder.record`` into the console's store (the one the History
  page reads); when there is none yet, it is made where `vts motion analyze` would make it
  ($VTS_STORE, rig.yaml's ``store:``, the per-user default); a store that cannot take it: its
  figures go to the unsaved file, as the command's do, and the page says so.
* Its outcome is said once it has ended (``on_said(what, detail)``: the action log):
  ``motion analysed`` with its state and whether it was stored, or ``motion analysis failed``
  and why; never as done before it is.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from vts_hw.errors import VtsError
from vts_hw.files import Outputs, write_atomic
from vts_hw.procedures.motion import MotionAnalysis
from vts_hw.report.renderers import write_report
from vts_hw.store.recorder import record
from vts_hw.store.target import resolve_target

__all__ = ["MotionJob", "OUT_DIR", "REPORT", "PLOT", "EXPORT"]

OUT_DIR = "motion"
REPORT = "motion-report.html"
PLOT = "motion.png"
EXPORT = "export"


class MotionJob:
    """The motion analysis of the scan in ``folder`` for ``rig``; ``store_target()``: the store
    to record into (a ResultsStore or a target; raising VtsError: not stored)."""

    def __init__(self, rig, folder: Path, store_target, *, user: str = "", on_said=None):
        self.rig, self.folder, self.store_target, self.user = rig, Path(folder), store_target, user
        self.on_said = on_said
        self.state = "running"  # running | done | failed
        self.progress: tuple[int, int] | None = None
        self.stage = "reading the recording"
        self.error = ""
        self.text = ""  # the analysis's own words (what the command prints)
        self.result_state: str | None = None  # OK / TOLERANCE / ACTION
        self.files: list[str] = []  # written, relative to the scan folder
        self.not_written = ""
        self.notes: list[str] = []
        self.stored = ""
        self.started = time.time()
        self.finished: float | None = None
        self.thread = threading.Thread(target=self._run, name="console-motion", daemon=True)

    def start(self) -> MotionJob:
        self.thread.start()
        return self

    def _progress(self, done: int, total: int) -> None:
        self.progress = (int(done), int(total))

    def _run(self) -> None:
        try:
            rig = self.rig
            cal = rig.calibration.cameras
            if cal is None:
                raise VtsError("no camera calibration: set calibration.cameras in rig.yaml")
            a = MotionAnalysis(
                self.folder,
                None,
                cal,
                rig.calibration.mapping,
                motion_config=rig.motion,
                workers=1,
                progress=self._progress,
            )
            a.analyze(tolerances=rig.tolerances)
            self.stage = "writing the report and the exports"
            data = a.results_data()
            out = self.folder / OUT_DIR
            try:
                out.mkdir(exist_ok=True)
            except OSError as exc:
                raise VtsError(f"cannot write into {out}: {exc.strerror or exc}") from None
            outs = Outputs()
            exported = outs.attempt(a.export, out / EXPORT, n_bins=4)
            png = a.plot()
            plot_ok = outs.attempt(write_atomic, out / PLOT, png) is not None
            report_ok = outs.attempt(write_report, "motion", out / REPORT, data, png) is not None
            self.files = (
                ([f"{OUT_DIR}/{REPORT}"] if report_ok else [])
                + ([f"{OUT_DIR}/{PLOT}"] if plot_ok else [])
                + [str(Path(p).resolve().relative_to(self.folder.resolve())) for p in (exported or [])]
            )
            self.notes = list(a.export_notes)
            self.not_written = outs.sentence()
            self.stage = "storing the result"
            self._store(a, data, [str(out / PLOT)] if plot_ok else [], outs)
            self.text = a.results()
            self.result_state = str(a.state)
            self.state = "done"
        except VtsError as exc:
            self.error, self.state = str(exc), "failed"
        except Exception as exc:
            self.error, self.state = (
                f"the analysis stopped on an unexpected error: {type(exc).__name__}: {exc}",
                "failed",
            )
        finally:
            self.finished = time.time()
        self._say()

    def _say(self) -> None:
        if self.on_said is None:
            return
        if self.state == "done":
            what, detail = (
                "motion analysed",
                {
                    "state": self.result_state,
                    "stored": self.stored,
                    **({"not written": self.not_written} if self.not_written else {}),
                },
            )
        else:
            what, detail = "motion analysis failed", {"why": self.error}
        try:
            self.on_said(what, {"scan": self.folder.name, **detail})
        except Exception:  # (the log's own failures are its to keep: actions.StoreActions)
            pass

    def _store(self, a, data, artifacts, outs) -> None:
        notes = f"session {self.folder}" + (f"; not written: {outs.sentence()}" if outs.failed else "")
        try:
            store = self.store_target()
        except VtsError:  # none yet: made where the command would make it ($VTS_STORE, rig.yaml, per-user)
            store = resolve_target(None, None, self.rig)
        try:
            stored = record(
                store,
                a,
                rig=self.rig.rig,
                operator=self.user,
                config_digest=self.rig.digest,
                tolerances=self.rig.tolerances,
                notes=notes,
                artifacts=artifacts,
            )
        finally:
            if hasattr(store, "close"):
                store.close()
        self.stored = (
            f"stored: run {stored.run_id} in the results store"
            if stored.ok
            else f"NOT stored: {stored.error}; its figures are in {stored.unsaved} (`vts qa import` stores them later)"
            if stored.unsaved
            else f"NOT stored: {stored.error}"
        )

    def view(self) -> dict:
        return {
            "state": self.state,
            "stage": self.stage,
            "progress": list(self.progress) if self.progress else None,
            "error": self.error,
            "text": self.text,
            "result_state": self.result_state,
            "files": self.files,
            "not_written": self.not_written,
            "notes": self.notes,
            "stored": self.stored,
            "elapsed_s": round((self.finished or time.time()) - self.started, 1),
        }
