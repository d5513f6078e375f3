"""Refused requests in the action log (docs/security.md, "Audit"): every POST the console
refuses (another site's, one without a session, one without the page's token, a role too low)
is recorded with what was asked, why it was refused and where it came from.

A page in the operator's browser can send refused requests as fast as it likes, so they are
recorded at most once per kind of refusal every :data:`EVERY_S`; the ones held back meanwhile
are counted into the next line (``held back since the last``), so the log says how many there
were without a flood of rows. The line is written after the answer is sent (a Starlette
background task, in a thread): a refusal never waits on the store. Nothing from the request is
kept but the method and path asked (cut to 200 characters), why, and the peer's address.
"""

from __future__ import annotations

import logging
import threading
import time

from starlette.background import BackgroundTask
from starlette.requests import Request

log = logging.getLogger(__name__)

EVERY_S = 10.0
WHAT = "action refused"
ANOTHER_SITE, NO_SESSION, NOT_THE_PAGE, ROLE = "another site", "no session", "not the page's", "role"


class Refusals:
    """The refusals of one console, into ``actions`` (actions.py: ``record``)."""

    def __init__(self, actions, clock=time.monotonic):
        self.actions = actions
        self._clock = clock
        self._lock = threading.Lock()
        self._next: dict[str, float] = {}
        self._held: dict[str, int] = {}

    def note(self, kind: str, request: Request, why: str, user: str = "") -> BackgroundTask | None:
        """The task recording this refusal (give it to the refusing response), or None when one
        of its ``kind`` was recorded less than EVERY_S ago (it is counted into the next)."""
        now = self._clock()
        with self._lock:
            if now < self._next.get(kind, float("-inf")):
                self._held[kind] = self._held.get(kind, 0) + 1
                return None
            self._next[kind] = now + EVERY_S
            held = self._held.pop(kind, 0)
        detail: dict[str, str | int] = {
            "asked": f"{request.method} {request.url.path}"[:200],
            "why": why[:200],
            "kind": kind,
            "from": request.client.host if request.client else "",
        }
        if held:
            detail["held back since the last"] = held
        return BackgroundTask(self._record, user or "(no session)", detail)

    def _record(self, user: str, detail: dict) -> None:
        try:
            self.actions.record(user, WHAT, detail, role="")
        except Exception as exc:  # the store away: said in the log, the answer already sent
            log.warning("a refused request could not be recorded (%s)", type(exc).__name__)


__all__ = ["Refusals", "EVERY_S", "WHAT", "ANOTHER_SITE", "NO_SESSION", "NOT_THE_PAGE", "ROLE"]
