"""The Room page's "Aim & focus" switch per camera: its routes (the checks: aim_checks.py).

* ``POST /aim/{camera}`` ``{"on": true|false}`` -- an operator's action (``guard.refuse`` first),
  recorded (``aim check on`` / ``aim check off``). Switching on a camera a recording feeds
  is refused (409, one sentence); switched on, a camera the hub's source turns ``fed`` later
  says so on the page and is checked again when the recording is done.
* ``GET /aim/{camera}`` -- the check's state (JSON); ``GET /aim/{camera}/overlay.png`` -- the
  last check's picture (the LED-on picture with the markers and their edge widths, the SPECT
  FOV, the table and the gantry's opening drawn), ``X-Aim-Check`` its number.
* ``GET /aim/events?cameras=a,b`` -- server-sent events of its own: an ``aim`` event per camera
  whenever its state changes (switched, a check begun or done, a refusal), so the Room page's
  ``/events`` stream is untouched.
"""

from __future__ import annotations

import asyncio
import json

from starlette.requests import Request
from starlette.responses import JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from vts_hw.console import guard
from vts_hw.console.aim_checks import AimChecks

TICK_S = 0.1
KEEPALIVE_S = 15.0


def aim_routes(console, templates=None) -> list:
    """The routes of the aim checks of ``console``; makes ``console.aim`` (an :class:`AimChecks`),
    which whoever serves the console closes (``console.aim.close()``)."""
    checks = AimChecks(console)
    console.aim = checks

    def known(request: Request):
        name = request.path_params["camera"]
        if name not in console.hub.names:
            return name, JSONResponse({"error": f"no camera {name!r} in this rig"}, status_code=404)
        return name, None

    async def switch(request: Request):
        refused = guard.refuse(console, request, guard.OPERATOR)
        if refused is not None:
            return refused
        name, bad = known(request)
        if bad is not None:
            return bad
        try:
            body = await request.json()
        except ValueError:
            body = None
        if not isinstance(body, dict) or not isinstance(body.get("on"), bool):
            return JSONResponse({"error": 'the body must be JSON {"on": true} or {"on": false}'}, status_code=400)
        user, role = guard.user_of(console, request)
        if body["on"]:
            why = await asyncio.to_thread(checks.refusal, name)
            if why:
                return JSONResponse({"error": why, **checks.view(name)}, status_code=409)
        view = checks.switch(name, body["on"], user)
        await asyncio.to_thread(lambda: console.actions.record(
            user, f"aim check {'on' if body['on'] else 'off'}", {"camera": name}, role=role))
        return JSONResponse(view)

    async def state(request: Request):
        name, bad = known(request)
        return bad if bad is not None else JSONResponse(checks.view(name))

    async def overlay(request: Request):
        name, bad = known(request)
        if bad is not None:
            return bad
        png, n = checks.overlay(name)
        if png is None:
            return JSONResponse({"error": f"camera {name}: no aim check yet"}, status_code=404)
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-store", "X-Aim-Check": str(n)})

    async def events(request: Request):
        wanted = [n for n in request.query_params.get("cameras", ",".join(console.hub.names)).split(",")
                  if n in console.hub.names]

        async def stream():
            sent: dict[str, int | None] = {n: None for n in wanted}
            loop = asyncio.get_running_loop()
            last = loop.time()
            yield b"retry: 2000\n\n"
            while not console.closing.is_set():
                out = []
                for n in wanted:
                    v = checks.version(n)
                    if v != sent[n]:
                        sent[n] = v
                        out.append(f"event: aim\ndata: {json.dumps(checks.view(n), separators=(',', ':'))}\n\n"
                                   .encode())
                now = loop.time()
                if not out and now - last > KEEPALIVE_S:
                    out.append(b": keep-alive\n\n")
                if out:
                    last = now
                    yield b"".join(out)
                await asyncio.sleep(TICK_S)

        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    return [Route("/aim/events", events), Route("/aim/{camera}", switch, methods=["POST"]),
            Route("/aim/{camera}", state), Route("/aim/{camera}/overlay.png", overlay)]


__all__ = ["aim_routes"]
