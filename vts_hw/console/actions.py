"""What people did on the console: who, when, what (a scan started or stopped, an alert
acknowledged, a baseline set, a push, the LED switched).

``Actions`` is the one door (``record`` / ``recent``). ``MemoryActions`` keeps them for the
console's life only; the store-backed log (the results store's ``actions`` table) replaces it
where a store is given, so the history shows them.
"""

from __future__ import annotations

import threading
import time
from dataclasses import asdict, dataclass, field
from typing import Protocol


@dataclass(frozen=True)
class Action:
    at: float                      # unix time
    user: str
    what: str                      # a short verb phrase: "scan started", "alert acknowledged", ...
    detail: dict = field(default_factory=dict)   # never a password, token or camera URL

    def as_dict(self) -> dict:
        return asdict(self)


class Actions(Protocol):
    def record(self, user: str, what: str, detail: dict | None = None) -> Action: ...

    def recent(self, limit: int = 50) -> list[Action]: ...


class MemoryActions:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: list[Action] = []

    def record(self, user: str, what: str, detail: dict | None = None) -> Action:
        act = Action(time.time(), user, what, dict(detail or {}))
        with self._lock:
            self._items.append(act)
        return act

    def recent(self, limit: int = 50) -> list[Action]:
        with self._lock:
            return list(reversed(self._items[-limit:]))


__all__ = ["Action", "Actions", "MemoryActions"]
