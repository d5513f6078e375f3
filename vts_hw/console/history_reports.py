"""The drift report and the rooms page, rendered from the store when the History page asks.

Through the reports' one door (:mod:`vts_hw.report.build`: ``build_drift_report``,
``build_rooms_report``, as `vts report drift` / `vts report rooms` call them) into a temporary
folder of the system's (``tempfile``), never the user's folders; the HTML is served back. The
drift report is one file, read and its folder removed at once. The rooms page links each
room's drift report written beside it: the folder of the latest rooms page is kept (one at a
time, the previous one removed) and only the files that render wrote are served from it, by
name (``GET /history/rooms/{name}``), never another path.

The period is ``since`` as the commands take it (``60d`` by default, ``all``, a UTC date); a
bad one is its sentence and HTTP 400. The drift report is the console's rig's.
"""

from __future__ import annotations

import asyncio
import tempfile
import threading
from pathlib import Path

from starlette.responses import HTMLResponse, PlainTextResponse

from vts_hw.errors import VtsError
from vts_hw.report.build import build_drift_report, build_rooms_report
from vts_hw.report.times import parse_since

DRIFT_NAME = "drift-report.html"
ROOMS_NAME = "rooms.html"


def _page(sentence: str, status: int) -> HTMLResponse:
    from html import escape

    return HTMLResponse(
        f"<!doctype html><meta charset='utf-8'><title>Report not made</title>"
        f"<p class='error'>{escape(sentence)}</p><p><a href='/history'>Back to the history</a></p>",
        status_code=status,
    )


class Reports:
    def __init__(self, console):
        self.console = console
        self._lock = threading.Lock()
        self._rooms_dir: tempfile.TemporaryDirectory | None = None
        self._rooms_files: set[str] = set()

    def _since(self, text: str) -> float | None:
        return parse_since(text)

    def _open(self):
        if self.console.open_store is None:
            raise VtsError("no results store is named for this console")
        return self.console.open_store()

    # -- in a thread -----------------------------------------------------------------------------------
    def render_drift(self, since: float | None) -> str:
        with tempfile.TemporaryDirectory(prefix="vts-console-") as tmp, self._open() as store:
            out = Path(tmp) / DRIFT_NAME
            build_drift_report(store, out, since=since, rig=self.console.rig_name)
            return out.read_text(encoding="utf-8")

    def render_rooms(self, since: float | None) -> str:
        tmp = tempfile.TemporaryDirectory(prefix="vts-console-rooms-")
        try:
            out = Path(tmp.name) / ROOMS_NAME
            with self._open() as store:
                report = build_rooms_report(store, out, since=since)
            text = out.read_text(encoding="utf-8")
        except BaseException:
            tmp.cleanup()
            raise
        with self._lock:
            old, self._rooms_dir = self._rooms_dir, tmp
            self._rooms_files = {room.drift_file for room in report.rooms if room.drift_file}
        if old is not None:
            old.cleanup()
        return text

    # -- the responses ---------------------------------------------------------------------------------
    async def _render(self, fn, since_text: str):
        try:
            since = self._since(since_text)
        except ValueError as exc:  # BadSince: its sentence
            return _page(str(exc), 400)
        try:
            return HTMLResponse(await asyncio.to_thread(fn, since), headers={"Cache-Control": "no-store"})
        except VtsError as exc:
            return _page(f"the report could not be made: {exc}", 503)

    async def drift(self, since_text: str):
        return await self._render(self.render_drift, since_text)

    async def rooms(self, since_text: str):
        return await self._render(self.render_rooms, since_text)

    def rooms_file(self, name: str):
        with self._lock:
            folder = self._rooms_dir.name if self._rooms_dir is not None else None
            known = name in self._rooms_files
        if folder is None or not known:
            return PlainTextResponse(
                f"no report {name!r} here: open the rooms page again (/history/rooms/)", status_code=404
            )
        path = Path(folder) / name
        if not path.is_file():
            return PlainTextResponse(f"report no longer there: {name}: open the rooms page again", status_code=404)
        return HTMLResponse(path.read_text(encoding="utf-8"), headers={"Cache-Control": "no-store"})

    def close(self) -> None:
        with self._lock:
            old, self._rooms_dir, self._rooms_files = self._rooms_dir, None, set()
        if old is not None:
            old.cleanup()


__all__ = ["Reports"]
