"""What a run becomes in QATrack+: a test list instance's values, times, comment and attachments.

Everything here reads our store and the rig config; nothing talks to QATrack+. A run that
cannot be mapped (a measurement with no macro and no ``ignore`` pattern) is refused here with
one sentence, before anything is posted: no list goes half-filled by accident.
"""

from __future__ import annotations

import base64
import fnmatch
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

from vts_hw import catalog
from vts_hw import report as reports  # its builders and plots load when first used (vts_hw/report/__init__.py)
from vts_hw.errors import VtsError
from vts_hw.figures import figure_png
from vts_hw.site_time import WALL_FORMAT, RepeatedWallTime, site_zone, wall_clock

#: what QATrack+ hears about a run that was pushed: its key (QATrack+'s ``user_key``)
KEY_PREFIX = "vts-run-"
#: run statuses that are results (the others: running, aborted, error)
PUSHABLE_STATUSES = ("OK", "TOLERANCE", "ACTION")
DRIFT_PROCEDURES = catalog.family(catalog.DAILY.key)


class NotMapped(VtsError):
    """A run the rig config's ``qatrack.lists`` cannot map (refused before posting)."""

    exit_code = 4


def run_key(run) -> str:
    """The idempotency key of a run in QATrack+: ``vts-run-<uid>`` (its identity across stores)."""
    return KEY_PREFIX + run.uid


class RepeatedHour(NotMapped):
    """A run whose start or end falls in the hour the site's clocks repeat (refused before posting)."""


def work_instants(run) -> tuple[int, int]:
    """The run's start and end as whole seconds (epoch) as they are sent: the start's second,
    and the end's second, but at least one second after the start: QATrack+ moves an end equal
    to its start 60 s on (TestListInstance.save), so a run within one second ends at the next
    second (less than a second after its true end). An end stored before the start (QATrack+
    would refuse it) is sent the same way."""
    start = int(run.started // 1)
    end = int((run.finished if run.finished is not None else run.started) // 1)
    return start, max(end, start + 1)


def work_times(qcfg, run) -> tuple[str, str]:
    """The run's start and end (:func:`work_instants`) as the QATrack+ site's wall clock shows
    them (``YYYY-MM-DD hh:mm:ss`` in ``qatrack.time_zone``; QATrack+ reads naive times in its own
    zone and accepts no offset); RepeatedHour when one of them happens twice there (see
    vts_hw/site_time.py)."""
    zone = site_zone(qcfg.time_zone)
    out = []
    for what, t in zip(("start", "end"), work_instants(run)):
        try:
            out.append(wall_clock(t, zone).strftime(WALL_FORMAT))
        except RepeatedWallTime as exc:
            raise RepeatedHour(
                f"the run's {what} time, {exc}: QATrack+ reads times in its own zone and cannot "
                f"be told which is meant, so it is not pushed (enter it in QATrack+ by hand)"
            ) from None
    return out[0], out[1]


def measurement_name(m) -> str:
    return f"{m.subject}/{m.metric}" if m.subject else m.metric


@dataclass
class Payload:
    """A test list instance to post, and what it is made of (for --dry-run and the outcome)."""

    run_id: int
    key: str
    test_list: str
    data: dict  # the JSON body, minus unit_test_collection until it is known
    values: dict[str, object]  # macro -> value (None: skipped, not measured)
    attachments: list[str] = field(default_factory=list)  # file names

    def body(self, utc_url: str) -> dict:
        return {"unit_test_collection": utc_url, **self.data}


def tests_of(store, qcfg, run) -> tuple[str, dict[str, dict], dict[str, object]]:
    """(test list name, QATrack+ ``tests`` dict, macro -> value) for ``run``; NotMapped when a
    measurement has neither a macro nor an ignore pattern, or a macro has nothing to send."""
    lst = qcfg.lists.get(run.procedure)
    if lst is None:
        raise NotMapped(f"rig.yaml has no qatrack.lists.{run.procedure} entry (mapped: {', '.join(qcfg.lists)})")
    by_name = {measurement_name(m): m for m in store.measurements(run_id=run.id)}
    unmapped = sorted(
        n
        for n in by_name
        if n not in lst.macros
        and n.rsplit("/", 1)[-1] not in lst.macros
        and not any(fnmatch.fnmatchcase(n, p) for p in lst.ignore)
    )
    if unmapped:
        shown = ", ".join(unmapped[:5]) + (f" and {len(unmapped) - 5} more" if len(unmapped) > 5 else "")
        raise NotMapped(
            f"no macro for {shown} in "
            f"qatrack.lists.{run.procedure}.macros (map each, or match it with an ignore pattern)"
        )
    tests: dict[str, dict] = {}
    values: dict[str, object] = {}
    for name, macro in lst.macros.items():
        m = by_name.get(name)
        if m is None and "/" not in name:  # a bare METRIC: the run's only measurement of it
            same = [x for n, x in by_name.items() if n.rsplit("/", 1)[-1] == name]
            if len(same) > 1:
                raise NotMapped(
                    f"{name} (macro {macro}) is measured for {len(same)} subjects; map SUBJECT/{name} instead"
                )
            m = same[0] if same else None
        if m is None or m.value is None:
            tests[macro] = {"skipped": True, "comment": f"{name}: not measured by the VTS in this run"}
            values[macro] = None
        else:
            tests[macro] = {"value": m.value}
            values[macro] = m.value
    return lst.test_list, tests, values


def comment_of(run) -> str:
    return (
        f"VTS {run.procedure} run {run.id} on rig {run.rig or '-'}: {run.status}. "
        f"Pushed by vts-hw {run.software_version or ''}".rstrip()
        + f"; key {run_key(run)}"
    )


def build_payload(store, qcfg, run, attach: bool = True, workdir: str | Path | None = None) -> Payload:
    """The payload of ``run`` (attachments read or rendered when ``attach``; else only named)."""
    test_list, tests, values = tests_of(store, qcfg, run)
    started, completed = work_times(qcfg, run)
    data = {
        "day": 0,
        "in_progress": False,
        "include_for_scheduling": True,
        "work_started": started,
        "work_completed": completed,
        "user_key": run_key(run),
        "comment": comment_of(run),
        "tests": tests,
    }
    if attach:
        files = attachments(store, qcfg, run, workdir)
        data["attachments"] = [
            {"filename": name, "value": base64.b64encode(blob).decode("ascii"), "encoding": "base64"}
            for name, blob in files
        ]
        names = [name for name, _ in files]
    else:
        names = list(planned_attachments(store, qcfg, run))
    return Payload(run.id, run_key(run), test_list, data, values, names)


def _stored_plots(store, run) -> list[Path]:
    return [Path(a.path) for a in store.artifacts(run.id) if a.kind == "plot" and Path(a.path).is_file()]


def planned_attachments(store, qcfg, run) -> list[str]:
    """The names of the files a push of ``run`` would attach (nothing is rendered)."""
    names = []
    if qcfg.plots:
        stored = _stored_plots(store, run)
        if stored:
            names += [p.name for p in stored]
        elif run.procedure in DRIFT_PROCEDURES:
            cams = sorted({m.subject for m in store.measurements(run_id=run.id) if m.subject and "/" not in m.subject})
            names += [f"vts-drift-run{run.id}-{c}.png" for c in cams]
    if qcfg.report != "none":
        names.append(f"vts-report-run{run.id}.{qcfg.report}")
    return names


def attachments(store, qcfg, run, workdir=None) -> list[tuple[str, bytes]]:
    """The files to attach: the run's drift plot(s) (its stored plots, else rendered from the
    store per camera for a drift/daily run) and the drift report as of the run's end. The
    report's builders and plotting libraries load here, on the first push that posts: a dry run,
    or a run refused before posting, never loads them."""
    plots: list[tuple[str, bytes]] = []
    files: list[tuple[str, bytes]] = []
    now = run.finished if run.finished is not None else run.started
    report = None  # the drift report as of the run's end, collected once for the report and the plots
    if qcfg.report != "none":
        with tempfile.TemporaryDirectory(prefix="vts-qatrack-", dir=workdir) as tmp:
            path = Path(tmp) / f"vts-report-run{run.id}.{qcfg.report}"
            report = reports.build_drift_report(store, path, now=now, rig=run.rig or None)
            files.append((path.name, path.read_bytes()))
    if qcfg.plots:
        stored = _stored_plots(store, run)
        if stored:
            plots += [(p.name, p.read_bytes()) for p in stored]
        elif run.procedure in DRIFT_PROCEDURES:
            report = report or reports.collect(store, now=now, rig=run.rig or None)
            cams = {m.subject for m in store.measurements(run_id=run.id) if m.subject and "/" not in m.subject}
            for name, cam in sorted(report.cameras.items()):
                if name in cams and cam.points:
                    plots.append((f"vts-drift-run{run.id}-{name}.png", figure_png(reports.camera_figure(report, cam))))
    return plots + files
