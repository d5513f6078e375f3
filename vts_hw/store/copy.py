"""Copy one results store into another (`vts store migrate`), and verify the copy.

Identity across stores (docs/decisions/0039-store-migrate.md): a run is its ``uid``; a
tolerance window is its content (metric, bounds, unit, effective_from, recorded, note).
Local ids are never carried over: each copied row gets the target's next id, and the
references (measurements.run_id/tolerance_id, artifacts.run_id, outbox.run_id) are remapped.
A run already in the target (by uid) is skipped with its children, so a second copy adds
nothing, and several room stores can be merged into one department store.

Two things may move on in the source after a copy, and a later copy brings them over: a run
copied while still "running" that has ended since (its end, measurements and artifacts: the
one change a run ever has), and an outbox row whose push went on (the later ``updated`` wins;
a row new to a run already copied is added).

The console's action log is copied too (an action is its content: time, user, role, what,
detail, rig; one already in the target is not added again): moving a room's store to the
department's must not lose who did what. The console's users are NOT copied: their password
hashes stay in the store they were made for, and a console on the new store has its users
added there (docs/decisions/0063-console-users.md); ``source.users()`` says how many stayed.

Runs are copied in batches, each batch one write transaction of the target (a run and its
children are never split): an interrupted copy leaves whole runs, and the next copy goes on.

Verification reads both stores afresh and compares, per table, the source's rows expressed
without local ids (runs by uid; measurements, artifacts and outbox rows by their run's uid
and their fields; measurements' windows by content; windows by content) with the rows of
the target that belong to the source's runs and windows: how many of the source's rows are
found in the target, and a sha256 over each side's sorted rows.
"""

from __future__ import annotations

import hashlib
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

from sqlalchemy import Connection, insert, select, update

from vts_hw.store.schema import actions, artifacts, measurements, outbox, runs, tolerances

#: the tables copied, in the order they are reported
TABLES = ("runs", "tolerances", "measurements", "artifacts", "outbox", "actions")
#: runs per write transaction of the target
BATCH = 200

_WINDOW_COLS = (
    "metric",
    "action_low",
    "tolerance_low",
    "tolerance_high",
    "action_high",
    "unit",
    "effective_from",
    "recorded",
    "note",
)
_RUN_COLS = tuple(c.name for c in runs.c if c.name != "id")
_MEAS_COLS = ("subject", "metric", "value", "unit", "status")
_ART_COLS = ("path", "sha256", "kind")
_OUT_COLS = ("target", "key", "state", "attempts", "last_error", "created", "updated", "remote")
_ACT_COLS = ("at", "user_name", "role", "what", "detail", "rig")


@dataclass
class TableCheck:
    """One table of the verification: the source's rows, how many of them the target holds,
    how many this copy added, and each side's checksum."""

    table: str
    source: int
    found: int
    new: int
    source_sum: str
    target_sum: str

    @property
    def ok(self) -> bool:
        return self.found == self.source and self.source_sum == self.target_sum


@dataclass
class CopyReport:
    new: dict[str, int] = field(default_factory=lambda: {t: 0 for t in TABLES})
    skipped_runs: int = 0  # already in the target (by uid), nothing to bring
    running_copied: int = 0  # copied while still "running" in the source
    ended_runs: int = 0  # copied running before, ended since: their end brought now
    outbox_updated: int = 0  # outbox rows whose push went on in the source since
    checks: list[TableCheck] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(c.ok for c in self.checks)

    @property
    def mismatched(self) -> list[str]:
        return [c.table for c in self.checks if not c.ok]


def _num(v):
    """Numbers as float (SQLite may hand back an int where PostgreSQL gives a float)."""
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v


def _window_key(row) -> tuple:
    return tuple(
        _num(row._mapping[c]) if c not in ("metric", "unit", "note") else row._mapping[c] for c in _WINDOW_COLS
    )


def _pick(row, cols) -> dict:
    return {c: row._mapping[c] for c in cols}


def copy_store(source, target, progress: Callable[[int, int], None] | None = None) -> CopyReport:
    """Copy every run (with its measurements, artifacts and outbox rows) and every tolerance
    window of ``source`` that ``target`` lacks; then verify (``report.checks``).
    ``progress(done, total)`` is called after each batch of runs."""
    rep = CopyReport()
    with source._read() as conn:
        conn = _snapshot(conn)
        src_windows = conn.execute(select(tolerances).order_by(tolerances.c.id)).all()
        src_runs = conn.execute(select(runs).order_by(runs.c.id)).all()
    with target._read() as conn:
        have = {r.uid: (r.id, r.status) for r in conn.execute(select(runs.c.uid, runs.c.id, runs.c.status))}

    # windows first (measurements refer to them), deduplicated by content
    window_ids: dict[int, int] = {}
    with target._write(windows=True) as conn:
        by_key = {_window_key(r): r.id for r in conn.execute(select(tolerances).order_by(tolerances.c.id))}
        for r in src_windows:
            key = _window_key(r)
            if key not in by_key:
                by_key[key] = conn.execute(insert(tolerances).values(**_pick(r, _WINDOW_COLS))).inserted_primary_key[0]
                rep.new["tolerances"] += 1
            window_ids[r.id] = by_key[key]

    # new runs, and runs the target holds as "running" that have ended in the source since
    todo = [r for r in src_runs if r.uid not in have or (have[r.uid][1] == "running" and r.status != "running")]
    rep.skipped_runs = len(src_runs) - len(todo)
    for start in range(0, len(todo), BATCH):
        ids = [r.id for r in todo[start : start + BATCH]]
        with source._read() as conn:
            conn = _snapshot(conn)  # a run and its rows as of one moment (a writer may be finishing it)
            batch = conn.execute(select(runs).where(runs.c.id.in_(ids)).order_by(runs.c.id)).all()
            ms = conn.execute(
                select(measurements).where(measurements.c.run_id.in_(ids)).order_by(measurements.c.id)
            ).all()
            arts = conn.execute(select(artifacts).where(artifacts.c.run_id.in_(ids)).order_by(artifacts.c.id)).all()
            outs = conn.execute(select(outbox).where(outbox.c.run_id.in_(ids)).order_by(outbox.c.id)).all()
        with target._write() as conn:
            run_ids, added, ended = {}, set(), 0
            for r in batch:
                if r.uid not in have:
                    run_ids[r.id] = conn.execute(insert(runs).values(**_pick(r, _RUN_COLS))).inserted_primary_key[0]
                    added.add(r.id)
                    rep.running_copied += r.status == "running"
                    continue
                tid = have[r.uid][0]  # running in the target, ended in the source: its end, once
                done = conn.execute(
                    update(runs)
                    .where(runs.c.id == tid, runs.c.status == "running")
                    .values(status=r.status, finished=r.finished, notes=r.notes)
                )
                if done.rowcount == 1:
                    run_ids[r.id] = tid
                    ended += 1
            ms = [m for m in ms if m.run_id in run_ids]
            arts = [a for a in arts if a.run_id in run_ids]
            outs = [o for o in outs if o.run_id in added]  # an ended run's: _bring_outbox
            _insert_many(
                conn,
                measurements,
                [
                    dict(
                        _pick(m, _MEAS_COLS),
                        run_id=run_ids[m.run_id],
                        tolerance_id=None if m.tolerance_id is None else window_ids[m.tolerance_id],
                    )
                    for m in ms
                ],
            )
            _insert_many(conn, artifacts, [dict(_pick(a, _ART_COLS), run_id=run_ids[a.run_id]) for a in arts])
            _insert_many(conn, outbox, [dict(_pick(o, _OUT_COLS), run_id=run_ids[o.run_id]) for o in outs])
        rep.new["runs"] += len(added)
        rep.ended_runs += ended
        rep.new["measurements"] += len(ms)
        rep.new["artifacts"] += len(arts)
        rep.new["outbox"] += len(outs)
        if progress is not None:
            progress(start + len(batch), len(todo))
    _bring_outbox(source, target, rep)
    _bring_actions(source, target, rep)
    rep.checks = verify(source, target, rep.new)
    return rep


def _bring_outbox(source, target, rep: CopyReport) -> None:
    """Outbox rows of runs copied before whose push went on in the source: the later ``updated``
    wins; a row new to such a run is added. One write transaction."""
    q = select(outbox, runs.c.uid).join_from(outbox, runs, outbox.c.run_id == runs.c.id)
    with source._read() as conn:
        src = conn.execute(q).all()
    with target._write() as conn:
        tgt = {(r.uid, r.target): r for r in conn.execute(q)}
        run_of = (
            {
                r.uid: r.id
                for r in conn.execute(select(runs.c.uid, runs.c.id).where(runs.c.uid.in_({o.uid for o in src})))
            }
            if src
            else {}
        )
        for o in src:
            t = tgt.get((o.uid, o.target))
            if t is None and o.uid in run_of:
                conn.execute(insert(outbox).values(**_pick(o, _OUT_COLS), run_id=run_of[o.uid]))
                rep.new["outbox"] += 1
            elif t is not None and float(o.updated) > float(t.updated):
                conn.execute(update(outbox).where(outbox.c.id == t.id).values(**_pick(o, _OUT_COLS)))
                rep.outbox_updated += 1


def _action_key(row) -> tuple:
    return tuple(_num(row._mapping[c]) if c == "at" else row._mapping[c] for c in _ACT_COLS)


def _bring_actions(source, target, rep: CopyReport) -> None:
    """The console's actions the target lacks (by content), in one write transaction."""
    with source._read() as conn:
        src = conn.execute(select(actions).order_by(actions.c.at, actions.c.id)).all()
    if not src:
        return
    with target._write() as conn:
        have = Counter(_action_key(r) for r in conn.execute(select(actions)))
        new = []
        for r in src:
            key = _action_key(r)
            if have[key]:
                have[key] -= 1
            else:
                new.append(_pick(r, _ACT_COLS))
        _insert_many(conn, actions, new)
    rep.new["actions"] += len(new)


def _snapshot(conn: Connection) -> Connection:
    """The connection reading one snapshot for all its statements: PostgreSQL's READ COMMITTED
    gives each statement its own, so ask for REPEATABLE READ; an SQLite read transaction
    already is one snapshot."""
    if conn.dialect.name == "postgresql":
        return conn.execution_options(isolation_level="REPEATABLE READ")
    return conn


def _insert_many(conn: Connection, table, rows: list[dict]) -> None:
    if rows:
        conn.execute(insert(table), rows)


# -- verification ------------------------------------------------------------------------------


def _content(store, uids: set[str] | None, windows: set[tuple] | None) -> dict[str, Counter]:
    """Per table, the multiset of rows without local ids; restricted to runs whose uid is in
    ``uids`` and windows whose content is in ``windows`` when those are given."""
    with store._read() as conn:
        conn = _snapshot(conn)
        win_rows = conn.execute(select(tolerances)).all()
        run_rows = conn.execute(select(runs)).all()
        meas_rows = conn.execute(select(measurements)).all()
        art_rows = conn.execute(select(artifacts)).all()
        out_rows = conn.execute(select(outbox)).all()
        act_rows = conn.execute(select(actions)).all()
    win_key = {r.id: _window_key(r) for r in win_rows}
    uid_of = {r.id: r.uid for r in run_rows}

    def mine(run_id) -> bool:
        return uids is None or uid_of[run_id] in uids

    out = {
        "runs": Counter(
            tuple(_num(r._mapping[c]) if c in ("started", "finished") else r._mapping[c] for c in _RUN_COLS)
            for r in run_rows
            if mine(r.id)
        ),
        "tolerances": Counter(k for k in win_key.values() if windows is None or k in windows),
        "measurements": Counter(
            (uid_of[m.run_id], m.subject, m.metric, _num(m.value), m.unit, m.status, win_key.get(m.tolerance_id))
            for m in meas_rows
            if mine(m.run_id)
        ),
        "artifacts": Counter(
            (uid_of[a.run_id],) + tuple(_pick(a, _ART_COLS).values()) for a in art_rows if mine(a.run_id)
        ),
        "outbox": Counter(
            (uid_of[o.run_id],)
            + tuple(_num(v) if k in ("created", "updated") else v for k, v in _pick(o, _OUT_COLS).items())
            for o in out_rows
            if mine(o.run_id)
        ),
        "actions": Counter(_action_key(a) for a in act_rows),
    }
    return out


def _checksum(rows: Counter) -> str:
    h = hashlib.sha256()
    for row in sorted(rows.elements(), key=repr):
        h.update(repr(row).encode())
        h.update(b"\n")
    return h.hexdigest()[:16]


def verify(source, target, new: dict[str, int] | None = None) -> list[TableCheck]:
    """Per table: the source's rows, how many the target holds, and the checksums (see module doc)."""
    src = _content(source, None, None)
    uids = {row[_RUN_COLS.index("uid")] for row in src["runs"]}
    tgt = _content(target, uids, set(src["tolerances"]))
    # windows are one row per content in a copy; a target holding the same window twice (its own
    # history, before any copy) still holds the source's one
    tgt["tolerances"] = tgt["tolerances"] & src["tolerances"]
    tgt["actions"] = tgt["actions"] & src["actions"]  # the target's own actions are not the source's
    checks = []
    for t in TABLES:
        found = sum((src[t] & tgt[t]).values())
        checks.append(
            TableCheck(t, sum(src[t].values()), found, (new or {}).get(t, 0), _checksum(src[t]), _checksum(tgt[t]))
        )
    return checks


def table_counts(store) -> dict[str, int]:
    """Rows per table of a store."""
    from sqlalchemy import func

    tables = {
        "runs": runs,
        "tolerances": tolerances,
        "measurements": measurements,
        "artifacts": artifacts,
        "outbox": outbox,
        "actions": actions,
    }
    with store._read() as conn:
        return {name: conn.scalar(select(func.count()).select_from(t)) for name, t in tables.items()}
