"""The Scan page: start and stop a patient scan (as `vts scan start --live`), watch it live,
acknowledge its alerts, then analyse its motion (as `vts motion analyze`) in one click.

* ``GET /scan``: the page. ``GET /scan/events``: its own server-sent events (never ``/events``:
  watching the Room's cameras would open the hub's streams): ``scan`` (the scan's state every
  ``STATE_EVERY_S``: the live status, bands, 6-DOF, frames, traces, alerts, summary,
  analysis), ``alert`` (an alert the moment it reaches the console) and ``frame`` (a camera
  the recording feeds has a new picture: fetched from ``/frame/{camera}`` as the Room page does).
* ``POST /scan/start`` (``{"reference_s": 10, "duration_s": null}``: each more than 0 s, the
  reference at most ``MAX_REFERENCE_S``, the duration at most ``MAX_DURATION_S`` or null),
  ``POST /scan/stop``, ``POST /scan/alert/{id}/ack``, ``POST /scan/analyse`` (no body, or
  ``{}``): each passes ``guard.refuse`` first, its body is read by inputs.py (a bad one: 400
  with a sentence, nothing started), and it is recorded with ``console.actions.record`` (who,
  what). A scan's start is recorded with its outcome, by the scan's worker (scan_run.py):
  ``scan started`` once it records, ``scan not started`` and why when it could not.
* ``GET /scan/files/{scan}/{n}``: output number ``n`` of the motion analysis of the scan
  ``scan`` (the report, the plot, the exports: the files the analysis wrote and listed, as the
  page lists them), by number: no path is ever taken from the URL; only while that scan is the
  page's, and only a regular file inside the scan's folder (resolved: no link out of it),
  else 404. docs/decisions/0079-console-network.md.

The scan and the analysis run in worker threads (scan_run.py, scan_analysis.py); the event
loop only reads their state. docs/decisions/0065-console-scan.md.
"""

from __future__ import annotations

import asyncio
import threading
import time
from pathlib import Path

from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse
from starlette.routing import Route

from vts_hw import __version__
from vts_hw.console import guard
from vts_hw.console.inputs import BadInput, Body, NoBody, Seconds, json_body, path_id, seconds, shown
from vts_hw.console.scan_analysis import MotionJob
from vts_hw.console.scan_run import ScanRun, clean
from vts_hw.console.web import event_stream, sse
from vts_hw.errors import VtsError
from vts_hw.procedures.scan import default_folder
from vts_hw.room import Room
from vts_hw.store.errors import StoreError

STATE_EVERY_S = 0.25
TICK_S = 0.02  # how often an event stream looks for alerts, frames and a new view
#: a camera's "new picture" event at most this often per page: the page fetches at most 2 pictures
#: a second (scan.js: thumbnails; the Room page is the live view), and an event per frame (100 a
#: second for 4 cameras) cost the browsers and the live path beside them for nothing (bench/console.py)
FRAME_EVENT_S = 0.5
MAX_REFERENCE_S = 120.0
MAX_DURATION_S = 86400.0  # a day: a scan is minutes long; more is a typing error, not a scan
DEFAULT_REFERENCE_S = 10.0


class StartBody(Body):
    reference_s: Seconds = seconds(
        MAX_REFERENCE_S,
        (
            f"a number of seconds more than 0 and at most {MAX_REFERENCE_S:g} (the still period learned first), "
            f"or null for {DEFAULT_REFERENCE_S:g}"
        ),
    )
    duration_s: Seconds = seconds(
        MAX_DURATION_S,
        (f"a number of seconds more than 0 and at most {MAX_DURATION_S:g} (a day), or null to scan until stopped"),
    )


class ScanDesk:
    """The console's one scan at a time, and its analysis. ``rig``: the RigConfig; ``scans``:
    the folder new scans go into (each ``scan-YYYYmmddTHHMMSSZ``, as `vts scan start` names it)."""

    def __init__(self, console, rig, scans: Path):
        self.console, self.rig, self.scans = console, rig, Path(scans)
        self.run: ScanRun | None = None
        self.job: MotionJob | None = None
        # the view, made once for every viewer by a thread of its own (never on the event loop,
        # which then only copies bytes: an alert or a frame is never behind a slow view)
        self.published: tuple[int, bytes] = (0, b"")
        self.viewers = 0
        threading.Thread(target=self._publish, name="console-scan-view", daemon=True).start()

    def _publish(self) -> None:
        n = 0
        while not self.console.closing.is_set():
            if self.viewers > 0:
                try:
                    data = sse("scan", self.view())
                except Exception as exc:  # said on the page; the publisher goes on
                    data = sse("scan", {"phase": "failed", "error": f"the page's view failed: {exc}"})
                n += 1
                self.published = (n, data)
            time.sleep(STATE_EVERY_S)

    def busy(self) -> bool:
        return self.run is not None and self.run.phase in ("starting", "running", "stopping")

    def start(self, user: str, reference_s: float, duration: float | None, role: str = "") -> ScanRun:
        def said(what: str, detail: dict) -> None:  # the scan's worker: its outcome, in the action log
            self.console.actions.record(user, what, detail, role=role)

        run = ScanRun(
            self.rig,
            default_folder(parent=self.scans),
            self.console.hub,
            lambda: Room(self.rig),
            user=user,
            reference_s=reference_s,
            duration=duration,
            marker_names=self.console.names,
            on_said=said,
        )
        self.run, self.job = run, None
        return run.start()

    def analyse(self, user: str, role: str = "") -> MotionJob:
        if self.run is None:  # the page refuses it before (409)
            raise RuntimeError("no scan to analyse")
        self.job = MotionJob(
            self.rig,
            self.run.folder,
            self.console.open_store or _no_store,
            user=user,
            on_said=lambda what, detail: self.console.actions.record(user, what, detail, role=role),
        )
        return self.job.start()

    def view(self) -> dict:
        out = {"phase": "idle", "scans": str(self.scans)} if self.run is None else self.run.view()
        out["scans"] = str(self.scans)
        out["analysis"] = None if self.job is None else self.job.view()
        out["fed"] = [n for n in self.console.hub.names if self.console.hub.source(n) == "fed"]
        try:
            out["actions"] = [] if self.run is None else self.actions(self.run.folder.name)
        except VtsError as exc:  # the store away (a full disk): the scan's view goes on without
            out["actions"], out["actions_error"] = [], f"the action log could not be read: {exc}"
        return out

    def actions(self, scan: str) -> list[dict]:
        """Who did what to this scan (console.actions), newest first."""
        return [
            clean({"at": a.at, "user": a.user, "what": a.what, "detail": dict(a.detail)})
            for a in self.console.actions.recent(200)
            if (a.detail or {}).get("scan") == scan
        ]


def _no_store():
    raise StoreError("the console was given no results store")


def scan_routes(console, templates):
    """The Scan page's routes. ``console.scan_desk`` is made here when the console has a rig
    (``console.rig_config``); its scans go into ``console.scans_dir``."""
    desk = getattr(console, "scan_desk", None)
    if desk is None and console.rig_config is not None:
        desk = console.scan_desk = ScanDesk(console, console.rig_config, Path(console.scans_dir or "."))

    def no_desk():
        return JSONResponse({"error": "this console was started without a rig to scan with"}, status_code=503)

    async def page(request: Request):
        return templates.TemplateResponse(
            request,
            "scan.html",
            {
                "rig": console.rig_name,
                "cameras": console.hub.names,
                "token": console.token,
                "here": "scan",
                "version": __version__,
                "scans": str(desk.scans) if desk else "",
            },
        )

    async def state(request: Request):
        if desk is None:
            return no_desk()
        return JSONResponse(await asyncio.to_thread(desk.view))

    async def events(request: Request):
        if desk is None:
            return no_desk()
        sent_alerts, sent_view, sent_seq = -1, -1, {n: None for n in console.hub.names}
        sent_at = {n: float("-inf") for n in console.hub.names}

        async def poll(now: float) -> list[bytes]:
            nonlocal sent_alerts, sent_view
            out: list[bytes] = []
            run = desk.run
            if run is not None and len(run.alerts) != sent_alerts:
                sent_alerts = len(run.alerts)
                out.extend(sse("alert", a) for a in run.alerts[-3:])
            n, data = desk.published
            if n != sent_view and data:
                sent_view = n
                out.append(data)
            for name in sent_seq:
                if now - sent_at[name] < FRAME_EVENT_S:  # the page shows at most 2 a second
                    continue
                lt = console.hub.latest(name)
                if lt is not None and lt.seq != sent_seq[name] and console.hub.source(name) == "fed":
                    sent_seq[name], sent_at[name] = lt.seq, now
                    out.append(sse("frame", {"camera": name, "seq": lt.seq, "arrival": lt.arrival}))
            return out

        def opened():
            desk.viewers += 1

        def closed():
            desk.viewers -= 1

        return event_stream(console, TICK_S, poll, opened=opened, closed=closed)

    async def start(request: Request):
        refused = guard.refuse(console, request, guard.OPERATOR)
        if refused is not None:
            return refused
        if desk is None:
            return no_desk()
        body = await json_body(request, StartBody, '{"reference_s": 10, "duration_s": null}')
        if desk.busy():
            return JSONResponse(
                {"error": f"a scan is already running ({desk.run.folder.name}): stop it first"}, status_code=409
            )
        user, role = guard.user_of(console, request)
        run = desk.start(user, body.reference_s or DEFAULT_REFERENCE_S, body.duration_s, role)
        return JSONResponse({"scan": run.folder.name, "phase": run.phase})

    async def stop(request: Request):
        refused = guard.refuse(console, request, guard.OPERATOR)
        if refused is not None:
            return refused
        await json_body(request, NoBody)
        if desk is None or not desk.busy():
            return JSONResponse({"error": "no scan is running"}, status_code=409)
        user, _ = guard.user_of(console, request)
        desk.run.request_stop()
        await asyncio.to_thread(console.actions.record, user, "scan stopped", {"scan": desk.run.folder.name})
        return JSONResponse({"scan": desk.run.folder.name, "phase": "stopping"})

    async def ack(request: Request):
        refused = guard.refuse(console, request, guard.OPERATOR)
        if refused is not None:
            return refused
        try:
            alert_id = path_id(request, "alert", "alert")
        except BadInput:
            alert_id = None  # no such alert: said as any other that is not there
        await json_body(request, NoBody)
        user, _ = guard.user_of(console, request)
        got = None if desk is None or desk.run is None or alert_id is None else desk.run.acknowledge(alert_id, user)
        if got is None:
            return JSONResponse(
                {"error": f"no alert {shown(request.path_params['alert'])} in this scan"}, status_code=404
            )
        await asyncio.to_thread(
            console.actions.record,
            user,
            "alert acknowledged",
            {"scan": desk.run.folder.name, "alert": got["text"], "raised": got["raised"]},
        )
        return JSONResponse(got)

    async def analyse(request: Request):
        refused = guard.refuse(console, request, guard.OPERATOR)
        if refused is not None:
            return refused
        await json_body(request, NoBody)
        if desk is None or desk.run is None or desk.run.phase != "stopped":
            return JSONResponse({"error": "no finished scan to analyse"}, status_code=409)
        if desk.job is not None and desk.job.state == "running":
            return JSONResponse({"error": "the motion analysis is running already"}, status_code=409)
        user, role = guard.user_of(console, request)
        job = desk.analyse(user, role)  # its outcome is recorded when it ends (scan_analysis.py)
        return JSONResponse(job.view())

    async def file(request: Request):
        if desk is None:
            return no_desk()
        run, job, n = desk.run, desk.job, request.path_params["n"]
        path = None
        if (
            run is not None
            and job is not None
            and run.folder.name == request.path_params["scan"]
            and job.state == "done"
            and n < len(job.files)
            and not run.folder.is_symlink()
        ):
            path = inside(run.folder, job.files[n])
        if path is None:
            return PlainTextResponse("no such file in that scan", status_code=404)
        return FileResponse(path, filename=path.name, content_disposition_type="inline")

    return [
        Route("/scan", page),
        Route("/scan/state", state),
        Route("/scan/events", events),
        Route("/scan/start", start, methods=["POST"]),
        Route("/scan/stop", stop, methods=["POST"]),
        Route("/scan/alert/{alert}/ack", ack, methods=["POST"]),
        Route("/scan/analyse", analyse, methods=["POST"]),
        Route("/scan/files/{scan}/{n:int}", file),
    ]


def inside(folder: Path, rel: str) -> Path | None:
    """The regular file ``rel`` (a path the console wrote, relative to ``folder``) inside
    ``folder``; None when it is not one (no such file, not a regular file, ``..`` or a link
    leading out of the folder)."""
    try:
        root = Path(folder).resolve(strict=True)
        path = (root / rel).resolve(strict=True)
    except (OSError, RuntimeError, ValueError):
        return None
    if not path.is_relative_to(root) or not path.is_file():
        return None
    return path


__all__ = ["scan_routes", "ScanDesk", "StartBody", "inside"]
