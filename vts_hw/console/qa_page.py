"""The Daily QA page: run the daily QA with its progress live, its result per camera with the
drift plot inside its windows, push it to QATrack+, set a drift baseline (confirmed).

* ``GET /qa``: the page (``templates/qa.html``, ``static/qa.js``).
* ``GET /qa/state``: the job now, the latest daily QA of the rig in the store (each camera's
  state, figures against their windows, the QATrack+ push) and the baselines in use (JSON).
* ``GET /qa/events``: the page's own event stream (server-sent events): ``qa``, the job's
  snapshot (which camera, which step, frames taken of needed, the server's clock), sent when
  it changes and every second while a job runs.
* ``POST /qa/run`` (operator) ``{"frames": N}``: the daily QA as `vts qa daily --frames N`, in
  a worker thread (qa_job.py); 409 with what runs when one is already running.
* ``POST /qa/baseline`` (physicist) ``{"confirm": true, "frames": N}``: as `vts qa drift
  --set-baseline`; refused (400) without the page's confirmation.
* ``POST /qa/push`` (operator): as `vts qa push` (every finished run of the rig not yet in
  QATrack+, through the store's outbox); each run's outcome (sent / pending / refused) with
  the peer's sentence.
* ``GET /qa/plot/{camera}.png?run=N``: the camera's drift over 60 days inside its tolerance
  and action windows as of run N, the drift report's figure drawn from the store (in a
  thread, once per camera and run: :class:`Plots`).

Every POST passes ``guard.refuse`` first; every action is logged (``console.actions``) with
who did it. No procedure logic here: qa_job.py calls what the commands call.
"""

from __future__ import annotations

import asyncio
import threading
from typing import Annotated

from pydantic import Field, StrictBool, StrictInt
from starlette.requests import Request
from starlette.responses import JSONResponse, PlainTextResponse, Response
from starlette.routing import Route

from vts_hw.console import guard
from vts_hw.console.inputs import Body, NoBody, json_body, query_id, shown
from vts_hw.console.qa_job import Busy, Jobs
from vts_hw.console.qa_view import drift_plot_png, latest_view
from vts_hw.console.web import event_stream, sse
from vts_hw.errors import ConfigError, UsageError, VtsError

DEFAULT_FRAMES = 5  # `vts qa daily --frames`'s default
MAX_FRAMES = 50
TICK_S = 0.1
RUNNING_EVERY_S = 1.0


FRAMES = Field(DEFAULT_FRAMES, description=f"a whole number from 1 to {MAX_FRAMES} (as `vts qa daily --frames`)")


class DailyBody(Body):
    frames: Annotated[StrictInt, Field(ge=1, le=MAX_FRAMES)] = FRAMES


class BaselineBody(DailyBody):
    confirm: StrictBool = Field(
        False,
        description="true, once the page has asked (a baseline changes what every later daily QA is compared with)",
    )


def _refused(exc: VtsError) -> JSONResponse:
    status = 409 if isinstance(exc, Busy) else 400 if isinstance(exc, (UsageError, ConfigError)) else 503
    return JSONResponse({"error": str(exc)}, status_code=status)


class Plots:
    """Drift plots drawn once per (camera, run): matplotlib takes seconds on a busy machine, and
    every page open after a run asks for the same ones. A plot asked for while it is being drawn
    waits for that drawing rather than drawing it again. Without a run in the URL: drawn anew."""

    KEEP = 16

    def __init__(self):
        self._lock = threading.Lock()
        self._done: dict[tuple, bytes | None] = {}
        self._drawing: dict[tuple, threading.Lock] = {}

    def get(self, key, draw):
        if key[1] is None:
            return draw()
        with self._lock:
            if key in self._done:
                return self._done[key]
            lock = self._drawing.setdefault(key, threading.Lock())
        with lock:
            with self._lock:
                if key in self._done:
                    return self._done[key]
            png = draw()
            with self._lock:
                self._done[key] = png
                self._drawing.pop(key, None)
                while len(self._done) > self.KEEP:
                    self._done.pop(next(iter(self._done)))
            return png


class QAPage:
    def __init__(self, console, templates):
        self.console = console
        self.templates = templates
        self.jobs = Jobs(console)
        self.plots = Plots()
        console.qa_jobs = self.jobs  # (the tests and a closing console can reach it)

    async def page(self, request: Request):
        user, role = guard.user_of(self.console, request)
        return self.templates.TemplateResponse(
            request,
            "qa.html",
            {
                "rig": self.console.rig_name,
                "here": "qa",
                "token": self.console.token,
                "cameras": self.jobs.cameras(),
                "frames": DEFAULT_FRAMES,
                "max_frames": MAX_FRAMES,
                "user": user,
                "physicist": guard.ROLE_RANK.get(role, 0) >= guard.ROLE_RANK[guard.PHYSICIST],
                "has_rig": self.console.rig_config is not None,
            },
        )

    async def state(self, request: Request):
        out = {"job": self.jobs.snapshot()}
        try:
            out.update(
                await asyncio.to_thread(
                    latest_view, self.console.open_store, self.console.rig_name, self.jobs.cameras()
                )
            )
        except VtsError as exc:
            out["store_error"] = f"the results store could not be read: {exc}"
        return JSONResponse(out, headers={"Cache-Control": "no-store"})

    async def events(self, request: Request):
        sent, last = None, 0.0

        async def poll(now: float) -> list[bytes]:
            nonlocal sent, last
            snap = self.jobs.snapshot()
            running = snap["state"] == "running" or snap["pushing"]
            if snap["version"] != sent or (running and now - last >= RUNNING_EVERY_S):
                sent, last = snap["version"], now
                return [sse("qa", snap)]
            return []

        return event_stream(self.console, TICK_S, poll)

    async def _start(self, request: Request, kind: str, role: str):
        refused = guard.refuse(self.console, request, role)
        if refused is not None:
            return refused
        user, _ = guard.user_of(self.console, request)
        body = await json_body(
            request,
            BaselineBody if kind == "baseline" else DailyBody,
            '{"confirm": true, "frames": 5}' if kind == "baseline" else '{"frames": 5}',
        )
        try:
            if kind == "baseline" and not (isinstance(body, BaselineBody) and body.confirm is True):
                raise UsageError(
                    "a baseline is set only when confirmed on the page (the body needs "
                    '"confirm": true): it changes what every later daily QA is compared with'
                )
            job = await asyncio.to_thread(self.jobs.start, kind, user, body.frames)
        except VtsError as exc:
            return _refused(exc)
        return JSONResponse(job, status_code=202)

    async def run(self, request: Request):
        return await self._start(request, "daily", guard.OPERATOR)

    async def baseline(self, request: Request):
        return await self._start(request, "baseline", guard.PHYSICIST)

    async def push(self, request: Request):
        refused = guard.refuse(self.console, request, guard.OPERATOR)
        if refused is not None:
            return refused
        await json_body(request, NoBody)
        user, _ = guard.user_of(self.console, request)
        try:
            got = await asyncio.to_thread(self.jobs.push, user)
        except Busy as exc:  # not tried: another push is running
            return _refused(exc)
        except VtsError as exc:
            await asyncio.to_thread(self.console.actions.record, user, "push to QATrack+ failed", {"why": str(exc)})
            return _refused(exc)
        await asyncio.to_thread(
            self.console.actions.record,
            user,
            "push to QATrack+",
            {"runs": [o["run_id"] for o in got["outcomes"]], **got["counts"]},
        )
        return JSONResponse(got)

    async def plot(self, request: Request):
        name = request.path_params["camera"]
        if name not in self.jobs.cameras():
            return PlainTextResponse(f"no camera {shown(name)} in this rig", status_code=404)
        run = query_id(request, "run", "run id")
        if self.console.open_store is None:
            return PlainTextResponse("no results store is named for this console", status_code=503)
        key = (name, run, self.jobs.ended)  # a new baseline: drawn anew
        try:
            png = await asyncio.to_thread(
                self.plots.get, key, lambda: drift_plot_png(self.console.open_store, self.console.rig_name, name)
            )
        except VtsError as exc:
            return PlainTextResponse(f"the results store could not be read: {exc}", status_code=503)
        if png is None:
            return PlainTextResponse(f"no drift of camera {name} in the store in the last 60 days", status_code=404)
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-store"})

    def routes(self) -> list[Route]:
        return [
            Route("/qa", self.page),
            Route("/qa/state", self.state),
            Route("/qa/events", self.events),
            Route("/qa/run", self.run, methods=["POST"]),
            Route("/qa/baseline", self.baseline, methods=["POST"]),
            Route("/qa/push", self.push, methods=["POST"]),
            Route("/qa/plot/{camera}.png", self.plot),
        ]


def qa_routes(console, templates) -> list[Route]:
    return QAPage(console, templates).routes()


__all__ = ["QAPage", "qa_routes", "DEFAULT_FRAMES"]
