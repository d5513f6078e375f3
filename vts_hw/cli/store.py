"""`vts store ...`: what a results store holds, and copying one into another."""

from __future__ import annotations

import sys

import click

from vts_hw.cli import cli
from vts_hw.cli.common import config_option, echo_json, json_option, rig_if_any, store_target
from vts_hw.errors import DataError, UsageError


@cli.group()
def store() -> None:
    """The results store: its contents, and copies between stores (SQLite <-> PostgreSQL).

    A store URL is sqlite:////path/results.sqlite (or a plain file path) or
    postgresql://user@host[:port]/db; a password never goes in it (refused, exit 2): name the
    environment variable that holds it (--store-password-env, or store.password_env in rig.yaml).
    """


def _open(url, password_env, what: str, mode: str):
    from vts_hw.store import ResultsStore
    from vts_hw.store.target import checked

    target = checked(url, password_env, what, f"{what}-password-env")
    try:
        return ResultsStore(target, mode=mode)
    except DataError as exc:
        raise type(exc)(f"{what}: {exc}") from None


@store.command()
@config_option
@json_option
def info(config_path, as_json) -> None:
    """Where the store is (its URL, password masked), its schema version and its rows per table.

    The store is the one every command uses: `vts --store URL`, else $VTS_STORE, else
    rig.yaml's store.url, else the per-user SQLite file. An older schema is upgraded; nothing
    is created: a store that does not exist yet, an empty database or one that is not a vts-hw
    results store is refused in one sentence and left as it was (`vts store init` makes one).

    Exit status: 0; 2 a bad URL or config; 3 the store cannot be opened or read, or is not one.
    """
    from vts_hw.store import ResultsStore
    from vts_hw.store.copy import table_counts

    target = store_target(rig_if_any(config_path))
    with ResultsStore(target, mode="read") as s:
        counts = table_counts(s)
        data = {"url": s.url, "from": target.source, "schema_version": s.schema_version, "rows": counts}
    if as_json:
        echo_json(data)
        return
    click.echo(f"store: {data['url']} ({target.source})")
    click.echo(f"schema version: {data['schema_version']}")
    for table, n in counts.items():
        click.echo(f"  {table:<13} {n:>9}")


@store.command()
@click.option(
    "--from",
    "src",
    required=True,
    metavar="URL",
    help="The store to copy from (URL or SQLite file; it must be a vts-hw results store).",
)
@click.option(
    "--to",
    "dst",
    required=True,
    metavar="URL",
    help="The store to copy into: a vts-hw results store (it may hold other rooms' runs), a new "
    "SQLite file, or an empty PostgreSQL database.",
)
@click.option(
    "--from-password-env",
    metavar="NAME",
    default=None,
    help="Environment variable holding the source database's password.",
)
@click.option(
    "--to-password-env",
    metavar="NAME",
    default=None,
    help="Environment variable holding the target database's password.",
)
@json_option
def migrate(src, dst, from_password_env, to_password_env, as_json) -> None:
    """Copy every run, measurement, tolerance window, artifact record and outbox row of one
    store into another, then verify the copy.

    The console's action log (who did what) is copied; its users are not (add them again on
    the target with `vts console user add`, which the command reminds).

    Runs are the same run in both stores by their uid: a run already in the target is skipped
    with everything of it, so running the copy twice adds nothing, and several rooms' stores
    can be merged into one department store. Tolerance windows are the same by their content.
    Local ids are given afresh by the target. Runs still running in the source are copied as
    they are (and said so); a later copy brings their end (status, measurements, artifacts)
    once they have ended, and the outbox rows whose push went on since.

    The check, per table: how many of the source's rows the target holds, and a checksum of
    those rows on each side (expressed without local ids). Progress goes to stderr.

    A database that is not a vts-hw results store (other tables, not SQLite at all) is never
    written, whichever side it is named on; an empty one is refused as --from.

    Exit status: 0 copied and verified; 2 a bad URL (or one holding a password), the same
    store twice; 3 a store that cannot be opened, read or written, a source that does not
    exist or is not a vts-hw results store, a target that is not one, or a copy that does not
    match its source (the table is named).
    """
    from vts_hw.store.copy import copy_store

    with (
        _open(src, from_password_env, "--from", mode="read") as source,
        _open(dst, to_password_env, "--to", mode="create") as target,
    ):
        if source.url == target.url:
            raise UsageError(f"--from and --to are the same store ({source.url})")

        def progress(done, total):
            if not as_json:
                click.echo(f"copying runs: {done}/{total}", err=True)

        if not as_json:
            click.echo(f"copying {source.url} -> {target.url}", err=True)
        rep = copy_store(source, target, progress=progress)
        users_left = len(source.users())  # the console's users are not copied (copy.py)
        where = (source.url, target.url)
    new_total = sum(rep.new.values())
    if as_json:
        echo_json(
            {
                "from": where[0],
                "to": where[1],
                "new": rep.new,
                "skipped_runs": rep.skipped_runs,
                "running_copied": rep.running_copied,
                "ended_runs": rep.ended_runs,
                "outbox_updated": rep.outbox_updated,
                "ok": rep.ok,
                "users_not_copied": users_left,
                "tables": [
                    {
                        "table": c.table,
                        "source": c.source,
                        "in_target": c.found,
                        "new": c.new,
                        "checksum_source": c.source_sum,
                        "checksum_target": c.target_sum,
                        "ok": c.ok,
                    }
                    for c in rep.checks
                ],
            }
        )
    else:
        click.echo(
            f"{'table':<13} {'source':>8} {'in target':>10} {'new':>7}  {'checksum source':<17} {'checksum target':<17}"
        )
        for c in rep.checks:
            click.echo(
                f"{c.table:<13} {c.source:>8} {c.found:>10} {c.new:>7}  {c.source_sum:<17} "
                f"{c.target_sum:<17} {'ok' if c.ok else 'MISMATCH'}"
            )
        if rep.ended_runs or rep.outbox_updated:
            click.echo(
                f"brought over: {rep.ended_runs} run(s) that have ended since an earlier copy, "
                f"{rep.outbox_updated} outbox row(s) whose push went on"
            )
        if new_total == 0:
            click.echo(f"0 new: the target already held all {rep.skipped_runs} run(s) and their windows")
        else:
            click.echo(f"{rep.new['runs']} new run(s) copied ({rep.skipped_runs} already there)")
        if rep.running_copied:
            click.echo(
                f"note: {rep.running_copied} run(s) still running in the source were copied as running; "
                "a later copy brings their end",
                err=True,
            )
        if users_left:
            click.echo(
                f"note: the source's {users_left} console user(s) were not copied (their password hashes "
                "stay where they were made): add them on the target with `vts console user add`",
                err=True,
            )
    if not rep.ok:
        click.echo(
            f"vts: the copy does not match its source in table(s) {', '.join(rep.mismatched)} "
            "(rows of the source missing or different in the target)",
            err=True,
        )
        sys.exit(3)


@store.command()
@click.argument("url", metavar="URL")
@click.option(
    "--password-env", metavar="NAME", default=None, help="Environment variable holding the database's password."
)
@json_option
def init(url, password_env, as_json) -> None:
    """Make URL a results store: an SQLite file (new, or an empty database) or an empty
    PostgreSQL database gets the vts-hw schema.

    Commands that write results create a store in a new file by themselves; this is for a
    database made beforehand (a PostgreSQL database from `createdb`, an empty SQLite file
    made by another tool), or to create the store before the first run. A store that is
    already one is left as it is (an older schema is upgraded). A database that holds
    anything else is never written.

    Exit status: 0 the store is ready; 2 a bad URL (or one holding a password); 3 the database
    cannot be opened or written, or is not empty and not a vts-hw results store.
    """
    from vts_hw.store.copy import table_counts

    with _open(url, password_env, "vts store init", mode="init") as s:
        data = {"url": s.url, "created": s.created, "schema_version": s.schema_version, "rows": table_counts(s)}
    if as_json:
        echo_json(data)
        return
    click.echo(
        f"{data['url']}: "
        + (
            "results store created"
            if data["created"]
            else f"already a results store ({data['rows'].get('runs', 0)} run(s))"
        )
        + f", schema version {data['schema_version']}"
    )
