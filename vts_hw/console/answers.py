"""How the console answers a request it cannot serve: one sentence, never a traceback.

* :func:`answer` -- the sentence as the asker reads it: a small HTML page (escaped) for a
  browser's page request (GET/HEAD with ``text/html`` in Accept), else JSON ``{"error": ...}``.
* :func:`refused_input` -- Starlette's handler of a refused input (inputs.BadInput: its
  sentence and status, 400, 413, 414 or 415).
* :func:`unexpected` -- Starlette's handler of any other exception: one sentence, HTTP 500,
  never a traceback or the exception's words in the answer; logged (where, and the server's
  traceback, by app.py: never the exception's words). The aim is that no input reaches it (tests/console/test_console_inputs.py walks every
  route with bad inputs): it is the floor, not the door.
"""

from __future__ import annotations

import html
import logging
import traceback

from starlette.requests import Request
from starlette.responses import HTMLResponse, JSONResponse, Response

log = logging.getLogger("vts_hw.console")

UNEXPECTED = (
    "the console could not answer this request: an unexpected error (what it was is in the console's log, not here)"
)


def wants_page(method: str, accept: str) -> bool:
    """Whether the asker is a browser loading a page (it reads HTML, not JSON)."""
    return method in ("GET", "HEAD") and "text/html" in accept


def answer(request: Request, sentence: str, status: int) -> Response:
    """``sentence`` with HTTP ``status``, as the asker reads it (module docstring)."""
    headers = {"Cache-Control": "no-store"}
    if wants_page(request.method, request.headers.get("accept", "")):
        return HTMLResponse(
            f"<!doctype html><meta charset='utf-8'><title>Not served</title>"
            f"<p class='error' role='alert'>{html.escape(sentence)}</p>"
            f"<p><a href='/'>Back to the room</a></p>",
            status_code=status,
            headers=headers,
        )
    return JSONResponse({"error": sentence}, status_code=status, headers=headers)


async def refused_input(request: Request, exc: Exception) -> Response:
    """Starlette's exception handler for inputs.BadInput (its ``status``: 400 unless said)."""
    return answer(request, str(exc), getattr(exc, "status", 400))


async def unexpected(request: Request, exc: Exception) -> Response:
    """Starlette's handler of any other exception (its ServerErrorMiddleware, outermost): the
    sentence ``UNEXPECTED``, HTTP 500. The console's log gets one line: the request, the
    exception's type and where it was raised (never its words: they might hold what the request
    carried); the exception then ends in app.py (after_answer), never in the server's traceback."""
    where = traceback.extract_tb(exc.__traceback__)[-1] if exc.__traceback__ is not None else None
    log.error(
        "the console could not answer %s %s: %s at %s",
        request.method,
        request.url.path[:200],
        type(exc).__name__,
        f"{where.filename}:{where.lineno}" if where else "?",
    )
    return answer(request, UNEXPECTED, 500)


def after_answer(exc: BaseException) -> None:
    """An unexpected exception already answered by :func:`unexpected`: its frames (files, lines,
    functions; never its words) to the debug log, in place of the server's traceback."""
    frames = traceback.extract_tb(exc.__traceback__) if exc.__traceback__ is not None else []
    log.debug(
        "%s raised through: %s",
        type(exc).__name__,
        " <- ".join(f"{f.filename}:{f.lineno} {f.name}" for f in reversed(frames)) or "?",
    )


__all__ = ["answer", "refused_input", "unexpected", "after_answer", "wants_page", "UNEXPECTED"]
