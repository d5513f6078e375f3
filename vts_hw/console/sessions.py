"""Who is logged in to the console: sessions that expire, kept in the console's memory only.

A session is a random key (32 bytes, ``secrets``) in a cookie that is HttpOnly, SameSite=Strict
and Secure when the console is reached over HTTPS (then named ``__Host-vts_session``, which the
browser only accepts from a secure page, for the whole site). The key never leaves the cookie:
it is not logged, not stored, not put in a page. Each session has its own page token (the
``X-Console-Token`` every POST carries, guard.py) and ends:

* after ``idle_s`` without a request from any page of it (default 15 min: a page left open
  keeps it, its pictures and events being requests; a browser closed or gone ends it), or
* ``max_s`` after login whatever happens (default 12 h: log in once a working day), or
* when the user logs out, is disabled or has their role changed (seen within ``USERS_EVERY_S``),
  or the console stops (sessions are not kept across restarts).

Five wrong passwords in a row for one name lock that name out for ``LOCK_S`` (the login page
says so), whether or not the name exists; past ``FAILS_KEPT`` names tried, the counts of those
not locked are forgotten (a spray of names cannot fill the console's memory). docs/decisions/0063-console-users.md.
"""

from __future__ import annotations

import contextvars
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from vts_hw.console.users import dummy_check, verify_password
from vts_hw.store.records import User

IDLE_S = 15 * 60.0
MAX_S = 12 * 3600.0
USERS_EVERY_S = 10.0  # how often serve() reads the users again (a disabled user is out within it)
LOCK_AFTER = 5
LOCK_S = 60.0
FAILS_KEPT = 10_000  # names with wrong passwords remembered; beyond, those not locked are forgotten

#: the session of the request being served (set by the login middleware; None without users):
#: it lets ``Console.token`` give each session's page its own token
current: contextvars.ContextVar[Session | None] = contextvars.ContextVar("console_session", default=None)


@dataclass
class Session:
    key: str  # the cookie's value: never logged, stored or shown
    user: str
    role: str
    token: str  # this session's page token
    created: float
    seen: float


class Auth:
    """The console's users (a copy of the store's active ones) and its sessions.

    ``required``: whether pages need a login (off this machine, behind a proxy, or --login);
    ``secure``: the console is reached over HTTPS (the cookie is then Secure);
    ``load_users()``: the store's active users (blocking: call from a thread)."""

    def __init__(
        self,
        *,
        required: bool,
        secure: bool = False,
        load_users: Callable[[], list[User]] | None = None,
        idle_s: float = IDLE_S,
        max_s: float = MAX_S,
        clock: Callable[[], float] = time.time,
    ):
        self.required = required
        self.secure = secure
        self.idle_s = float(idle_s)
        self.max_s = float(max_s)
        self._load = load_users
        self._clock = clock
        self._lock = threading.Lock()
        self._users: dict[str, User] = {}
        self._sessions: dict[str, Session] = {}
        self._fails: dict[str, tuple[int, float]] = {}  # name -> (wrong in a row, locked until)

    @property
    def cookie_name(self) -> str:
        return "__Host-vts_session" if self.secure else "vts_session"

    # -- users ---------------------------------------------------------------------------------------
    def refresh_users(self) -> int:
        """Read the active users again (blocking); sessions of users gone, disabled or with another
        role end. Returns how many users may log in."""
        if self._load is None:
            return 0
        fresh = {u.name: u for u in self._load()}
        with self._lock:
            self._users = fresh
            for key, s in list(self._sessions.items()):
                u = fresh.get(s.user)
                if u is None or u.role != s.role:
                    del self._sessions[key]
        return len(fresh)

    def known_names(self) -> set[str]:
        with self._lock:
            return set(self._users)

    # -- logging in and out ----------------------------------------------------------------------------
    def locked_for(self, name: str) -> float:
        """Seconds ``name`` is still locked out for (0: may try)."""
        with self._lock:
            n, until = self._fails.get(name, (0, 0.0))
        return max(0.0, until - self._clock())

    def login(self, name: str, password: str) -> Session | None:
        """A new session when ``password`` is ``name``'s (blocking: the hash takes ~0.1 s); None
        for a wrong name or password (the same time for both) or a locked name."""
        if self.locked_for(name) > 0:
            return None
        with self._lock:
            user = self._users.get(name)
        ok = verify_password(user.password, password) if user is not None else dummy_check(password)
        now = self._clock()
        with self._lock:
            if not ok or user is None:  # no user: dummy_check said no
                n, _ = self._fails.get(name, (0, 0.0))
                n += 1
                self._fails[name] = (0, now + LOCK_S) if n >= LOCK_AFTER else (n, 0.0)
                if len(self._fails) > FAILS_KEPT:  # many names tried (a spray): memory stays bounded
                    self._fails = {k: v for k, v in self._fails.items() if v[1] > now}
                return None
            self._fails.pop(name, None)
            s = Session(secrets.token_urlsafe(32), user.name, user.role, secrets.token_urlsafe(24), now, now)
            self._sessions[s.key] = s
            return s

    def logout(self, key: str) -> Session | None:
        with self._lock:
            return self._sessions.pop(key, None)

    # -- checking ---------------------------------------------------------------------------------------
    def alive(self, s: Session) -> bool:
        now = self._clock()
        return self._sessions.get(s.key) is s and now - s.seen <= self.idle_s and now - s.created <= self.max_s

    def session(self, key: str | None) -> Session | None:
        """The live session of cookie value ``key`` (an expired one is forgotten), without touching it."""
        if not key:
            return None
        with self._lock:
            s = self._sessions.get(key)
        if s is None:
            return None
        if not self.alive(s):
            self.logout(key)
            return None
        return s

    def touch(self, s: Session) -> None:
        s.seen = self._clock()

    def ends(self, s: Session) -> float:
        """When ``s`` ends if it stays in use (its absolute limit)."""
        return s.created + self.max_s

    def sweep(self) -> int:
        """Forget expired sessions; how many."""
        with self._lock:
            gone = [k for k, s in self._sessions.items() if not self.alive(s)]
            for k in gone:
                del self._sessions[k]
        return len(gone)


__all__ = ["Auth", "Session", "current", "IDLE_S", "MAX_S", "USERS_EVERY_S", "LOCK_AFTER", "LOCK_S"]
