"""What people did on the console: who, when, what (a scan started or stopped, an alert
acknowledged, a baseline set, a push, the LED switched, a login).

Both kinds have one door: ``record``, ``recent`` and ``page`` (for the History page).
``StoreActions`` writes each to the results store's ``actions`` table (store/people.py) the
moment it is recorded, so the History page shows them; `vts console` serves only with one
(:func:`durable_actions`: its first action, ``console started``, must reach the store, else
the console is refused before it serves: a store that is not ours, or one it cannot write).
``MemoryActions`` keeps them for the life of an object only (the tests' consoles). A detail never holds a secret: keys
that name one (password, token, cookie, session, credential, authorization) are masked and a
URL's user and password are cut out (``clean``) before anything is kept.
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

from vts_hw.console.guard import LOCAL_USER
from vts_hw.console.sessions import current
from vts_hw.errors import UsageError, VtsError
from vts_hw.store.errors import StoreError

log = logging.getLogger(__name__)

SECRET_KEY = re.compile(r"pass|secret|token|cookie|session|credential|authoriz|api[_-]?key", re.I)
URL_USERINFO = re.compile(r"([A-Za-z][A-Za-z0-9+.-]*://)[^/@\s]*@")


@dataclass(frozen=True)
class Action:
    at: float  # unix time
    user: str
    what: str  # a short verb phrase: "scan started", "alert acknowledged", ...
    detail: dict = field(default_factory=dict)  # never a password, token or camera URL
    role: str = ""  # the role the user had then
    rig: str = ""

    def as_dict(self) -> dict:
        return asdict(self)


def clean(value):
    """``value`` (a detail) with secrets masked: see the module docstring."""
    if isinstance(value, dict):
        return {str(k): ("***" if SECRET_KEY.search(str(k)) else clean(v)) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [clean(v) for v in value]
    if isinstance(value, str):
        return URL_USERINFO.sub(r"\1***@", value)
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)  # (JSON has no inf or nan: the store's and the pages' JSON stays JSON)
    if value is None or isinstance(value, (bool, int, float)):
        return value
    return clean(str(value))


def new_action(rig: str, user: str, what: str, detail: dict | None, role: str) -> Action:
    """The action now, its detail cleaned; its role the one given, else the role of the session
    acting (the caller's, seen through sessions.current: the pages need not pass it)."""
    if not role:
        s = current.get()
        role = s.role if s is not None and s.user == user else ""
    return Action(time.time(), user, what, clean(dict(detail or {})), role, rig)


def _keep(a: Action, start, end, user) -> bool:
    return (start is None or a.at >= start) and (end is None or a.at < end) and (not user or a.user == user)


class MemoryActions:
    def __init__(self, rig: str = "") -> None:
        self.rig = rig
        self._lock = threading.Lock()
        self._items: list[Action] = []

    def record(self, user: str, what: str, detail: dict | None = None, *, role: str = "") -> Action:
        act = new_action(self.rig, user, what, detail, role)
        with self._lock:
            self._items.append(act)
        return act

    def page(
        self,
        start: float | None = None,
        end: float | None = None,
        user: str | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> tuple[list[Action], int]:
        """Newest first, done in [start, end), by ``user``; and how many the filters keep."""
        with self._lock:
            kept = [a for a in reversed(self._items) if _keep(a, start, end, user)]
        return kept[offset : offset + limit], len(kept)

    def recent(self, limit: int = 50) -> list[Action]:
        return self.page(limit=limit)[0]


class StoreActions:
    """The action log in the results store: ``open_write()`` gives the store to append to (opened
    for each action: nothing held between them), ``open_read()`` the store to read (read-only).

    An action the store cannot take (disk full, the database away) is kept in memory, said in
    the console's log (what and who, never a secret), written with the next action that can be,
    and listed by ``page`` meanwhile: it is never lost while the console runs."""

    def __init__(self, open_write: Callable, open_read: Callable, rig: str = ""):
        self.rig = rig
        self._open_write = open_write
        self._open_read = open_read
        self._lock = threading.Lock()
        self.pending: list[Action] = []
        self._recent: tuple[float, int, list[Action]] | None = None  # (when read, limit, actions)

    def record_now(self, user: str, what: str, detail: dict | None = None, *, role: str = "") -> Action:
        """Record an action that must reach the store now (with any waiting): StoreError (or the
        store's other VtsError) when it does not, and nothing is kept in memory."""
        act = new_action(self.rig, user, what, detail, role)
        with self._lock:
            self._recent = None
            with self._open_write() as store:
                store.log_actions([a.as_dict() for a in [*self.pending, act]])
            self.pending = []
        return act

    def record(self, user: str, what: str, detail: dict | None = None, *, role: str = "") -> Action:
        act = new_action(self.rig, user, what, detail, role)
        with self._lock:
            self._recent = None
            todo = [*self.pending, act]
            try:
                with self._open_write() as store:
                    store.log_actions([a.as_dict() for a in todo])
                self.pending = []
            except VtsError as exc:
                self.pending = todo
                log.warning(
                    "the action %r by %s is kept in memory: the results store did not take it (%s)", what, user, exc
                )
        return act

    def page(
        self,
        start: float | None = None,
        end: float | None = None,
        user: str | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> tuple[list[Action], int]:
        """As MemoryActions.page, from the store (and any action waiting to be written)."""
        with self._lock:
            waiting = [a for a in reversed(self.pending) if _keep(a, start, end, user)]
        with self._open_read() as store:
            rows, total = store.actions(start, end, user, limit=limit, offset=max(0, offset - len(waiting)))
        stored = [Action(r.at, r.user, r.what, r.detail, r.role, r.rig) for r in rows]
        return (waiting[offset:] + stored)[:limit], total + len(waiting)

    def recent(self, limit: int = 50) -> list[Action]:
        """The newest actions; read from the store at most every ``RECENT_S`` (a page's view asks
        several times a second: opening the store each time cost the live path, bench/console.py),
        at once after an action recorded here."""
        now = time.monotonic()
        with self._lock:
            held = self._recent
        if held is not None and now - held[0] < RECENT_S and limit <= held[1]:
            return held[2][:limit]
        acts = self.page(limit=limit)[0]
        with self._lock:
            self._recent = (now, limit, acts)
        return acts


RECENT_S = 5.0  # actions of other consoles on the same store reach a page within this


def durable_actions(open_write, open_read, rig: str, address: str) -> StoreActions:
    """The action log of a console about to serve at ``address``: the results store's, its
    first action (``console started``, by the person at this machine) written now. A console
    without a store (``open_write`` None) is UsageError (exit 2); a store that is not a vts-hw
    store, or that cannot take the action (read-only, disk full, a database that refuses
    writes), StoreError (exit 3) in one sentence naming it: the action log is never only in
    memory, to be lost when the console stops. docs/decisions/0080-console-inputs-and-audit.md."""
    if open_write is None or open_read is None:
        raise UsageError("the console needs a results store to keep its action log in (who did what): none was given")
    log_ = StoreActions(open_write, open_read, rig)
    try:
        log_.record_now(LOCAL_USER, "console started", {"address": address})
    except VtsError as exc:
        raise StoreError(
            f"refused to serve the console: its action log cannot be kept in the results store "
            f"({exc}); name a vts-hw results store this user can write (vts --store, $VTS_STORE, "
            f"rig.yaml's store:)"
        ) from None
    return log_


__all__ = ["Action", "new_action", "MemoryActions", "StoreActions", "durable_actions", "clean"]
