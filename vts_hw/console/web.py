"""What every page's routes share: a server-sent event, the event stream's loop, the cameras a
stream is asked for, a camera of the rig or 404, and the preamble of an on/off switch of a camera
(its body read by inputs.py, as every body is).

An event stream (``event_stream``) sends ``retry`` once, then, every ``tick_s`` until the
console closes, whatever its ``poll(now)`` returns (the page's own events, already made), or
a keep-alive comment after ``KEEPALIVE_S`` of nothing. ``poll`` only reads what threads made
(the hub's slots, a job's snapshot): the event loop never waits on a device or the store.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable

from pydantic import Field, StrictBool
from starlette.requests import Request
from starlette.responses import JSONResponse, Response, StreamingResponse

from vts_hw.console import guard
from vts_hw.console.inputs import BadInput, Body, json_body, query_text, shown

KEEPALIVE_S = 15.0
STREAM_HEADERS = {"Cache-Control": "no-store", "X-Accel-Buffering": "no"}


def sse(event: str, data) -> bytes:
    """One server-sent event: ``event`` with ``data`` as compact JSON."""
    return f"event: {event}\ndata: {json.dumps(data, separators=(',', ':'))}\n\n".encode()


def event_stream(
    console,
    tick_s: float,
    poll: Callable[[float], Awaitable[list[bytes]]],
    *,
    opened: Callable[[], None] | None = None,
    closed: Callable[[], None] | None = None,
) -> StreamingResponse:
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
                    yield b"".join(out)  # waits while the browser does not read: it then misses events
                await asyncio.sleep(tick_s)
        finally:
            if closed is not None:
                closed()

    return StreamingResponse(stream(), media_type="text/event-stream", headers=STREAM_HEADERS)


def wanted_cameras(console, request: Request) -> list[str]:
    """The cameras of ``?cameras=a,b`` (all of them without it); BadInput naming one the rig has not."""
    names = console.hub.names
    asked = query_text(request, "cameras", ",".join(names), limit=4096)
    wanted = [n for n in asked.split(",") if n]
    unknown = [n for n in wanted if n not in names]
    if unknown:
        raise BadInput(f"no camera {shown(unknown[0])} in this rig (cameras: {', '.join(names)})")
    return wanted


class Switch(Body):
    on: StrictBool = Field(description="true or false")


def no_camera(console, name: str) -> Response | None:
    """404 with a sentence when the rig has no camera ``name``; else None."""
    if name not in console.hub.names:
        return JSONResponse({"error": f"no camera {shown(name)} in this rig"}, status_code=404)
    return None


async def switch_asked(console, request: Request) -> tuple[str, bool, Response | None]:
    """(camera, on, None) for an operator's ``POST .../{camera}`` with ``{"on": true|false}``;
    else (camera, False, the response refusing it: guard.refuse's, or 404). A bad body: BadInput."""
    name = request.path_params["camera"]
    refused = guard.refuse(console, request, guard.OPERATOR) or no_camera(console, name)
    if refused is not None:
        return name, False, refused
    return name, (await json_body(request, Switch, '{"on": true}')).on, None


__all__ = ["sse", "event_stream", "wanted_cameras", "no_camera", "switch_asked", "Switch", "KEEPALIVE_S"]
