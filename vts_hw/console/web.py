"""What every page's routes share: a server-sent event, the event stream's loop, a JSON body,
a camera of the rig or 404, and the preamble of an on/off switch of a camera.

An event stream (``event_stream``) sends ``retry`` once, then, every ``tick_s`` until the
console closes, whatever its ``poll(now)`` returns (the page's own events, already made), or
a keep-alive comment after ``KEEPALIVE_S`` of nothing. ``poll`` only reads what threads made
(the hub's slots, a job's snapshot): the event loop never waits on a device or the store.
"""

from __future__ import annotations

import asyncio
import json
from typing import Awaitable, Callable

from starlette.requests import Request
from starlette.responses import JSONResponse, Response, StreamingResponse

from vts_hw.console import guard
from vts_hw.errors import UsageError

KEEPALIVE_S = 15.0
STREAM_HEADERS = {"Cache-Control": "no-store", "X-Accel-Buffering": "no"}


def sse(event: str, data) -> bytes:
    """One server-sent event: ``event`` with ``data`` as compact JSON."""
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n".encode()


def event_stream(console, tick_s: float, poll: Callable[[float], Awaitable[list[bytes]]], *,
                 opened: Callable[[], None] | None = None,
                 closed: Callable[[], None] | None = None) -> StreamingResponse:
    """The page's event stream: ``poll(now)`` (``now``: the loop's clock) every ``tick_s``;
    ``opened()`` when the stream begins, ``closed()`` when it ends (the browser gone, the console
    closing)."""

    async def stream():
        if opened is not None:
            opened()
        try:
            loop = asyncio.get_running_loop()
            last_sent = 0.0
            yield b"retry: 2000\n\n"
            while not console.closing.is_set():
                now = loop.time()
                out = await poll(now)
                if not out and now - last_sent > KEEPALIVE_S:
                    out = [b": keep-alive\n\n"]
                if out:
                    last_sent = now
                    yield b"".join(out)       # waits while the browser does not read: it then misses events
                await asyncio.sleep(tick_s)
        finally:
            if closed is not None:
                closed()

    return StreamingResponse(stream(), media_type="text/event-stream", headers=STREAM_HEADERS)


def wanted_cameras(console, request: Request) -> list[str]:
    """The cameras of ``?cameras=a,b`` that the rig has (all of them without it)."""
    names = console.hub.names
    return [n for n in request.query_params.get("cameras", ",".join(names)).split(",") if n in names]


async def json_object(request: Request, example: str = "") -> dict:
    """The request's JSON object body; {} for none. A body that is not a JSON object: {}, or,
    given an ``example`` of one, UsageError saying the body must be one like it."""
    raw = await request.body()
    if not raw.strip():
        return {}
    try:
        body = json.loads(raw)
    except ValueError:
        body = None
    if isinstance(body, dict):
        return body
    if example:
        raise UsageError(f"the body must be a JSON object, e.g. {example}")
    return {}


def no_camera(console, name: str) -> Response | None:
    """404 with a sentence when the rig has no camera ``name``; else None."""
    if name not in console.hub.names:
        return JSONResponse({"error": f"no camera {name!r} in this rig"}, status_code=404)
    return None


async def switch_asked(console, request: Request) -> tuple[str, bool, Response | None]:
    """(camera, on, None) for an operator's ``POST .../{camera}`` with ``{"on": true|false}``;
    else (camera, False, the response refusing it: guard.refuse's, 404, or 400)."""
    name = request.path_params["camera"]
    refused = guard.refuse(console, request, guard.OPERATOR) or no_camera(console, name)
    if refused is not None:
        return name, False, refused
    on = (await json_object(request)).get("on")
    if not isinstance(on, bool):
        return name, False, JSONResponse({"error": 'the body must be JSON {"on": true} or {"on": false}'},
                                         status_code=400)
    return name, on, None


__all__ = ["sse", "event_stream", "wanted_cameras", "json_object", "no_camera", "switch_asked", "KEEPALIVE_S"]
