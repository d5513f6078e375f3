"""The History page: the runs in the results store, a run's figures and files, and the reports.

Read-only. Every read is a store method (``runs_page``, ``run``, ``measurements``,
``artifacts``, ``windows``), run in a thread (``asyncio.to_thread``), never SQL here; a
procedure is named by its label from the catalog, never by a stored name written here.

* ``GET /history?procedure=LABEL&state=STATE&from=YYYY-MM-DD&to=YYYY-MM-DD&page=N``: the runs,
  newest first, ``PAGE_SIZE`` a page; dates are UTC days, ``to`` included. A filter value that
  is not one of the page's own (an unknown procedure or state, a date that is not a date,
  ``from`` after ``to``, a page that is not a number or beyond what the store can hold, a
  parameter given twice) is one sentence on the page, HTTP 400 (inputs.py reads them).
* ``GET /history/run/{id}`` (an id of 1 to 2**63-1, else 404): the run, its measures (with
  the tolerance window that judged each, when the store has one) and its artifacts: PNG plots
  inline, other files to download.
* ``GET /history/run/{id}/file/{artifact_id}``: an artifact's bytes, only for an artifact the
  store lists for that run (by its id: no path is ever taken from the URL) and whose file
  exists; 404 otherwise.
* ``GET /history/actions?from=YYYY-MM-DD&to=YYYY-MM-DD&user=NAME&page=N``: what people did on the
  console (``console.actions``: the store's log), newest first, the same date filter as the runs.
* ``GET /history/drift-report``, ``GET /history/rooms/``: rendered by the reports' builders into
  a temporary folder (history_reports.py), never into the user's folders.
"""

from __future__ import annotations

import asyncio
import datetime as dt
import os
from dataclasses import dataclass, field
from urllib.parse import urlencode

from starlette.requests import Request
from starlette.responses import FileResponse, PlainTextResponse
from starlette.routing import Route

from vts_hw import catalog
from vts_hw.console.history_reports import Reports
from vts_hw.console.inputs import BadInput, path_id, query_page, query_text
from vts_hw.errors import VtsError
from vts_hw.store.records import RUN_STATUSES

PAGE_SIZE = 50
DAY_S = 86400.0


class BadFilter(BadInput):
    """A filter value in the URL the page does not offer (one sentence, HTTP 400)."""


@dataclass
class Filters:
    """The History page's filters as the URL gives them, and what they mean for the store."""

    label: str = ""  # a catalog label ("" : every procedure)
    state: str = ""  # one of RUN_STATUSES ("" : every state)
    date_from: str = ""  # YYYY-MM-DD (UTC)
    date_to: str = ""
    page: int = 1
    names: tuple[str, ...] | None = None  # the stored names of ``label``
    start: float | None = None
    end: float | None = None
    errors: list[str] = field(default_factory=list)

    def query(self, **change) -> str:
        """This view's URL query, with ``change`` applied (the pager's and the bookmark's)."""
        q = {
            "procedure": self.label,
            "state": self.state,
            "from": self.date_from,
            "to": self.date_to,
            "page": self.page,
        }
        q.update(change)
        return urlencode({k: v for k, v in q.items() if v not in ("", None, 1)})


def _day(text: str, which: str) -> float:
    try:
        day = dt.date.fromisoformat(text)
    except (ValueError, OverflowError):
        raise BadFilter(f"the {which} date {text!r} is not a date: give it as YYYY-MM-DD (e.g. 2026-09-01)") from None
    return dt.datetime(day.year, day.month, day.day, tzinfo=dt.UTC).timestamp()


def shown_filters(request: Request) -> Filters:
    """The filters as the URL gives them, unchecked (the form shows them again with the error)."""
    text = {k: (request.query_params.get(k) or "")[:200] for k in ("procedure", "state", "from", "to")}
    return Filters(label=text["procedure"], state=text["state"], date_from=text["from"], date_to=text["to"])


def parse_filters(request: Request, keys=("procedure", "state", "from", "to", "page")) -> Filters:
    """The filters of the request's URL query (those of ``keys``); BadFilter naming the first bad value."""
    try:
        given = {k: query_text(request, k) for k in keys if k != "page"}
        page = query_page(request, PAGE_SIZE) if "page" in keys else 1
    except BadInput as exc:
        raise BadFilter(str(exc)) from None
    f = Filters(
        label=given.get("procedure", ""),
        state=given.get("state", ""),
        date_from=given.get("from", ""),
        date_to=given.get("to", ""),
        page=page,
    )
    labels = catalog.by_label()
    if f.label:
        if f.label not in labels:
            raise BadFilter(f"no procedure called {f.label!r}: pick one of {', '.join(labels)}")
        f.names = labels[f.label]
    if f.state and f.state not in RUN_STATUSES:
        raise BadFilter(f"no run state {f.state!r}: pick one of {', '.join(RUN_STATUSES)}")
    if f.date_from:
        f.start = _day(f.date_from, "from")
    if f.date_to:
        f.end = _day(f.date_to, "to") + DAY_S
    if f.start is not None and f.end is not None and f.start >= f.end:
        raise BadFilter(f"the from date {f.date_from} is after the to date {f.date_to}: nothing can be in between")
    return f


def when(t: float | None) -> str:
    """A UTC epoch time as the page shows it ('' for none)."""
    if t is None:
        return ""
    return dt.datetime.fromtimestamp(t, dt.UTC).strftime("%Y-%m-%d %H:%M:%S UTC")


def number(v: float | None) -> str:
    return "not measured" if v is None else f"{v:.6g}"


def is_plot(artifact) -> bool:
    return artifact.path.lower().endswith(".png")


def _view_run(run) -> dict:
    return {
        "id": run.id,
        "label": catalog.label(run.procedure),
        "rig": run.rig,
        "operator": run.operator,
        "started": when(run.started),
        "finished": when(run.finished),
        "status": run.status,
        "software_version": run.software_version,
        "notes": run.notes,
        "uid": run.uid,
    }


class History:
    """The History routes of ``console`` (its ``open_store`` and ``rig_name``), with ``templates``."""

    def __init__(self, console, templates):
        self.console = console
        self.templates = templates
        self.reports = console.reports = Reports(console)  # (closed with the console: serve.py)

    # -- reading the store (in a thread) ------------------------------------------------------------
    def _store(self):
        if self.console.open_store is None:
            raise VtsError("no results store is named for this console")
        return self.console.open_store()

    def read_page(self, f: Filters) -> tuple[list[dict], int]:
        with self._store() as store:
            runs, total = store.runs_page(
                procedure=f.names,
                status=f.state or None,
                start=f.start,
                end=f.end,
                limit=PAGE_SIZE,
                offset=(f.page - 1) * PAGE_SIZE,
            )
        return [_view_run(r) for r in runs], total

    def read_run(self, run_id: int) -> dict | None:
        with self._store() as store:
            try:
                run = store.run(run_id)
            except KeyError:
                return None
            measures = store.measurements(run_id=run_id)
            windows = store.windows(m.tolerance_id for m in measures)
            files = store.artifacts(run_id)
        rows = [
            {
                "subject": m.subject,
                "metric": m.metric,
                "value": number(m.value),
                "unit": m.unit,
                "state": str(m.status),
                "window": windows[m.tolerance_id].describe() if m.tolerance_id in windows else "",
            }
            for m in measures
        ]
        arts = [
            {
                "id": a.id,
                "name": os.path.basename(a.path),
                "path": a.path,
                "kind": a.kind,
                "plot": is_plot(a),
                "there": os.path.isfile(a.path),
            }
            for a in files
        ]
        return {"run": _view_run(run), "measures": rows, "artifacts": arts}

    def artifact_path(self, run_id: int, artifact_id: int) -> str | None:
        """The file of artifact ``artifact_id`` if the store lists it for run ``run_id``."""
        with self._store() as store:
            for a in store.artifacts(run_id):
                if a.id == artifact_id:
                    return a.path
        return None

    # -- pages -----------------------------------------------------------------------------------------
    def _page(self, request: Request, name: str, ctx: dict, status: int = 200):
        base = {"rig": self.console.rig_name, "here": "history"}
        return self.templates.TemplateResponse(request, name, {**base, **ctx}, status_code=status)

    async def history(self, request: Request):
        ctx = {
            "labels": list(catalog.by_label()),
            "states": RUN_STATUSES,
            "runs": [],
            "total": 0,
            "error": "",
            "page_size": PAGE_SIZE,
        }
        try:
            f = parse_filters(request)
        except BadFilter as exc:
            return self._page(request, "history.html", {**ctx, "f": shown_filters(request), "error": str(exc)}, 400)
        try:
            runs, total = await asyncio.to_thread(self.read_page, f)
        except VtsError as exc:
            return self._page(
                request, "history.html", {**ctx, "f": f, "error": f"the results store could not be read: {exc}"}, 503
            )
        pages = max(1, -(-total // PAGE_SIZE))
        return self._page(
            request,
            "history.html",
            {**ctx, "f": f, "runs": runs, "total": total, "pages": pages, "first": (f.page - 1) * PAGE_SIZE + 1},
        )

    async def run_page(self, request: Request):
        try:
            run_id = path_id(request, "run", "run")
        except BadInput as exc:
            return self._page(request, "message.html", {"message": str(exc)}, exc.status)
        try:
            got = await asyncio.to_thread(self.read_run, run_id)
        except VtsError as exc:
            return self._page(request, "message.html", {"message": f"the results store could not be read: {exc}"}, 503)
        if got is None:
            return self._page(
                request, "message.html", {"message": f"there is no run {run_id} in the results store"}, 404
            )
        return self._page(request, "history_run.html", got)

    async def artifact(self, request: Request):
        run_id, aid = path_id(request, "run", "run"), path_id(request, "artifact", "file")
        try:
            path = await asyncio.to_thread(self.artifact_path, run_id, aid)
        except VtsError as exc:
            return PlainTextResponse(f"the results store could not be read: {exc}", status_code=503)
        if path is None:
            return PlainTextResponse(f"run {run_id} has no file {aid} in the results store", status_code=404)
        if not os.path.isfile(path):
            return PlainTextResponse(f"file no longer there: {os.path.basename(path)} (run {run_id})", status_code=404)
        headers = {"X-Content-Type-Options": "nosniff", "Cache-Control": "no-store"}
        if path.lower().endswith(".png"):
            return FileResponse(path, media_type="image/png", headers=headers)
        return FileResponse(
            path, media_type="application/octet-stream", filename=os.path.basename(path), headers=headers
        )

    def read_actions(self, f: Filters, user: str) -> tuple[list[dict], int]:
        acts, total = self.console.actions.page(
            start=f.start, end=f.end, user=user or None, limit=PAGE_SIZE, offset=(f.page - 1) * PAGE_SIZE
        )
        return [
            {
                "at": when(a.at),
                "user": a.user,
                "role": a.role,
                "what": a.what,
                "rig": a.rig,
                "detail": ", ".join(f"{k}: {v}" for k, v in sorted(a.detail.items())),
            }
            for a in acts
        ], total

    async def actions(self, request: Request):
        ctx = {
            "acts": [],
            "total": 0,
            "error": "",
            "user": (request.query_params.get("user") or "")[:200],
            "page_size": PAGE_SIZE,
        }
        try:
            user = query_text(request, "user")
            f = parse_filters(request, ("from", "to", "page"))
        except BadInput as exc:
            return self._page(
                request, "history_actions.html", {**ctx, "f": shown_filters(request), "error": str(exc)}, 400
            )
        ctx["user"] = user
        try:
            acts, total = await asyncio.to_thread(self.read_actions, f, user)
        except VtsError as exc:
            return self._page(
                request,
                "history_actions.html",
                {**ctx, "f": f, "error": f"the results store could not be read: {exc}"},
                503,
            )
        pages = max(1, -(-total // PAGE_SIZE))
        return self._page(
            request,
            "history_actions.html",
            {**ctx, "f": f, "acts": acts, "total": total, "pages": pages, "first": (f.page - 1) * PAGE_SIZE + 1},
        )

    async def drift_report(self, request: Request):
        return await self.reports.drift(query_text(request, "since", "60d"))

    async def rooms_page(self, request: Request):
        return await self.reports.rooms(query_text(request, "since", "60d"))

    async def rooms_file(self, request: Request):
        return self.reports.rooms_file(request.path_params["name"])

    def routes(self) -> list[Route]:
        return [
            Route("/history", self.history),
            Route("/history/run/{run}", self.run_page),
            Route("/history/run/{run}/file/{artifact}", self.artifact),
            Route("/history/actions", self.actions),
            Route("/history/drift-report", self.drift_report),
            Route("/history/rooms/", self.rooms_page),
            Route("/history/rooms/{name}", self.rooms_file),
        ]


def history_routes(console, templates) -> list[Route]:
    return History(console, templates).routes()


__all__ = ["History", "history_routes", "parse_filters", "shown_filters", "Filters", "BadFilter", "PAGE_SIZE"]
