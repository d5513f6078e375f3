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

from starlette.requests import Request
from starlette.responses import JSONResponse, Response
from starlette.routing import Route

from vts_hw.console import guard
from vts_hw.console.aim_checks import AimChecks
from vts_hw.console.web import event_stream, no_camera, sse, switch_asked, wanted_cameras

TICK_S = 0.1


def aim_routes(console, templates=None) -> list:
    """The routes of the aim checks of ``console``; makes ``console.aim`` (an :class:`AimChecks`),
    which whoever serves the console closes (``console.aim.close()``)."""
    checks = AimChecks(console)
    console.aim = checks

    def known(request: Request):
        name = request.path_params["camera"]
        return name, no_camera(console, name)

    async def switch(request: Request):
        name, on, refused = await switch_asked(console, request)
        if refused is not None:
            return refused
        user, role = guard.user_of(console, request)
        if on:
            why = await asyncio.to_thread(checks.refusal, name)
            if why:
                return JSONResponse({"error": why, **checks.view(name)}, status_code=409)
        view = checks.switch(name, on, user)
        await asyncio.to_thread(
            lambda: console.actions.record(user, f"aim check {'on' if on else 'off'}", {"camera": name}, role=role)
        )
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
        wanted = wanted_cameras(console, request)
        sent: dict[str, int | None] = {n: None for n in wanted}

        async def poll(now: float) -> list[bytes]:
            out = []
            for n in wanted:
                v = checks.version(n)
                if v != sent[n]:
                    sent[n] = v
                    out.append(sse("aim", checks.view(n)))
            return out

        return event_stream(console, TICK_S, poll)

    return [
        Route("/aim/events", events),
        Route("/aim/{camera}", switch, methods=["POST"]),
        Route("/aim/{camera}", state),
        Route("/aim/{camera}/overlay.png", overlay),
    ]


__all__ = ["aim_routes"]
