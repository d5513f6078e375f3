"""The console's users and its action log in the results store (schema version 4).

A mixin of :class:`~vts_hw.store.ResultsStore`: the statements are SQLAlchemy Core built here,
one transaction each. A user's ``password`` column holds what the console's hashing made of
the password (vts_hw/console/users.py); the store never sees the password itself. Users are
never deleted: one who leaves is disabled (``disabled`` = when), so every action logged under
a name stays that person's. The action log is append-only.
"""

from __future__ import annotations

import json
import time
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING

from sqlalchemy import Connection, Select, func, insert, select, update

from vts_hw.store.records import ROLES, LoggedAction, User
from vts_hw.store.schema import actions, users


def user_from_row(row) -> User:
    return User(row.id, row.name, row.role, row.password, row.created, row.changed, row.disabled)


def action_from_row(row) -> LoggedAction:
    try:
        detail = json.loads(row.detail or "{}")
    except ValueError:
        detail = {"unreadable": row.detail}
    return LoggedAction(
        row.id,
        row.at,
        row.user_name,
        row.role,
        row.what,
        detail if isinstance(detail, dict) else {"detail": detail},
        row.rig,
    )


def _filtered(q: Select, start: float | None, end: float | None, user: str | None) -> Select:
    """``q`` kept to actions done in [start, end) when given, by ``user`` when given."""
    if start is not None:
        q = q.where(actions.c.at >= start)
    if end is not None:
        q = q.where(actions.c.at < end)
    if user:
        q = q.where(actions.c.user_name == user)
    return q


def select_actions(
    start: float | None = None, end: float | None = None, user: str | None = None, limit: int = 50, offset: int = 0
) -> Select:
    """Actions newest first, done in [start, end) when given, by ``user`` when given."""
    return (
        _filtered(select(actions), start, end, user)
        .order_by(actions.c.at.desc(), actions.c.id.desc())
        .limit(int(limit))
        .offset(int(offset))
    )


def count_actions(start: float | None = None, end: float | None = None, user: str | None = None) -> Select:
    return _filtered(select(func.count()).select_from(actions), start, end, user)


class PeopleMixin:
    """Users and actions; needs the store's ``_read``/``_write`` and ``url``."""

    if TYPE_CHECKING:  # ResultsStore's own (store.py), said here for the type checker

        def _read(self) -> AbstractContextManager[Connection]: ...

        def _write(self, windows: bool = False) -> AbstractContextManager[Connection]: ...

    # -- users -------------------------------------------------------------------------------------
    def users(self, active_only: bool = False) -> list[User]:
        """The console's users by name (disabled ones too unless ``active_only``)."""
        q = select(users).order_by(users.c.name)
        if active_only:
            q = q.where(users.c.disabled.is_(None))
        with self._read() as conn:
            return [user_from_row(r) for r in conn.execute(q)]

    def user(self, name: str) -> User | None:
        with self._read() as conn:
            row = conn.execute(select(users).where(users.c.name == name)).first()
        return None if row is None else user_from_row(row)

    def put_user(self, name: str, role: str, password_hash: str) -> tuple[User, str]:
        """Add user ``name``, or enable again a disabled one with this role and password; returns
        (the user, "added" or "enabled again"). ValueError for a bad role or a user already active."""
        if role not in ROLES:
            raise ValueError(f"a role is one of {', '.join(ROLES)}, not {role!r}")
        now = time.time()
        with self._write() as conn:
            row = conn.execute(select(users).where(users.c.name == name)).first()
            if row is None:
                conn.execute(
                    insert(users).values(
                        name=name, role=role, password=password_hash, created=now, changed=now, disabled=None
                    )
                )
                how = "added"
            elif row.disabled is None:
                article = "an" if row.role[:1] in "aeiou" else "a"
                raise ValueError(f"user {name} already exists ({article} {row.role}); remove it first to replace it")
            else:
                conn.execute(
                    update(users)
                    .where(users.c.id == row.id)
                    .values(role=role, password=password_hash, changed=now, disabled=None)
                )
                how = "enabled again"
            return user_from_row(conn.execute(select(users).where(users.c.name == name)).one()), how

    def disable_user(self, name: str) -> User:
        """Disable user ``name`` (it can no longer log in; its actions keep its name). KeyError if none."""
        with self._write() as conn:
            row = conn.execute(select(users).where(users.c.name == name)).first()
            if row is None:
                raise KeyError(name)
            if row.disabled is None:
                conn.execute(update(users).where(users.c.id == row.id).values(disabled=time.time()))
            return user_from_row(conn.execute(select(users).where(users.c.id == row.id)).one())

    # -- the action log --------------------------------------------------------------------------------
    def log_actions(self, items: list[dict]) -> int:
        """Append actions (dicts with at, user, role, what, detail, rig) in one transaction."""
        if not items:
            return 0
        rows = [
            dict(
                at=float(a["at"]),
                user_name=str(a["user"]),
                role=str(a.get("role", "")),
                what=str(a["what"]),
                detail=json.dumps(a.get("detail") or {}, sort_keys=True, default=str),
                rig=str(a.get("rig", "")),
            )
            for a in items
        ]
        with self._write() as conn:
            conn.execute(insert(actions), rows)
        return len(rows)

    def actions(
        self,
        start: float | None = None,
        end: float | None = None,
        user: str | None = None,
        limit: int = 50,
        offset: int = 0,
    ) -> tuple[list[LoggedAction], int]:
        """One page of the action log, newest first, and how many the filters keep (one snapshot)."""
        with self._read() as conn:
            total = conn.execute(count_actions(start, end, user)).scalar_one()
            rows = conn.execute(select_actions(start, end, user, limit, offset)).all()
        return [action_from_row(r) for r in rows], int(total)
