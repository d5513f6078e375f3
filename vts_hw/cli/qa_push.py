"""`vts qa push`: results to the clinic's QATrack+, through the store's outbox; and the
`--push` of `vts qa daily` / `vts qa steps`."""

from __future__ import annotations

import sys
import time

import click

from vts_hw.cli.common import echo_json, json_option, open_store, with_rig
from vts_hw.errors import ConfigError, VtsError


def qatrack_config(rig):
    if rig.qatrack is None:
        src = rig._source or "rig.yaml"
        raise ConfigError(
            f"{src}: no qatrack: section (url, unit, token_env or user_env/password_env, "
            f"lists); see docs/operate/qatrack.md"
        )
    return rig.qatrack


@click.command("push")
@click.argument("runs", nargs=-1, type=click.IntRange(min=1))
@click.option(
    "--pending",
    is_flag=True,
    help="Retry only the runs left pending (QATrack+ was down, slow "
    "or failing); refused ones wait for a push without --pending.",
)
@click.option("--dry-run", is_flag=True, help="Show what would be posted (no request is made, no secret shown).")
@json_option
@with_rig
def push(rig, runs, pending, dry_run, as_json) -> None:
    """Post QA runs to QATrack+ as test list instances.

    RUN... are run ids of the results store. Without RUN or --pending: every finished run of
    this rig whose procedure has a list in rig.yaml's qatrack.lists and that is not sent yet
    (including the ones refused before: after fixing the mapping, this retries them all).
    --pending retries only the runs left pending (cron-friendly: a refusal is not repeated
    until someone fixes it and pushes without --pending). Each run is
    posted once: it carries the key vts-run-<uid> (QATrack+'s user_key), asked for before
    posting; every push goes through the store's outbox (pending, sent, refused).
    Credentials come from the environment variables qatrack.token_env (or user_env and
    password_env) name; they are never printed or stored.

    Exit status: 0 every run sent (or already in QATrack+); 3 some left pending (QATrack+
    down, too slow, 5xx, or the store failed): `vts qa push --pending` retries them; 4
    QATrack+ refused something (a run's values, the test list assignment, or the
    credentials): fix rig.yaml's qatrack: section (or QATrack+), then push again without
    --pending; 2 bad usage or config.
    """
    from vts_hw.qatrack import dry_run as plan
    from vts_hw.qatrack import push_runs, select_runs

    if pending and runs:
        raise click.UsageError("give RUN ids or --pending, not both")
    qcfg = qatrack_config(rig)
    if not dry_run:
        qcfg.credentials()  # an unset variable: one sentence before anything is touched
    with open_store(rig, mode="read") as store:
        chosen = select_runs(store, qcfg, rig.rig, runs, pending=pending)
        if dry_run:
            rows = plan(store, qcfg, chosen)
            _print_plan(rows, as_json)
            return
        outcomes = push_runs(store, qcfg, chosen, progress=_progress(len(chosen), as_json))
    sys.exit(_report(outcomes, as_json, what="runs" if len(chosen) != 1 else "run"))


def _progress(total: int, as_json: bool):
    t0 = time.monotonic()

    def say(n, total_, outcome):
        if not as_json:
            click.echo(outcome.line())
        if total > 10 and (n % 10 == 0 or n == total):
            click.echo(f"pushed {n}/{total} runs ({time.monotonic() - t0:.1f} s)", err=True)

    return say


def _report(outcomes, as_json: bool, what: str = "runs") -> int:
    from vts_hw.qatrack import exit_code

    code = exit_code(outcomes)
    if as_json:
        echo_json({"outcomes": [o.as_dict() for o in outcomes], "exit_code": code})
        return code
    if not outcomes:
        click.echo("QATrack+: nothing to push")
        return code
    sent = [o for o in outcomes if o.state == "sent"]
    posted = sum(1 for o in sent if o.how == "posted")
    pending = sum(1 for o in outcomes if o.state == "pending")
    refused = sum(1 for o in outcomes if o.state == "refused")
    click.echo(
        f"QATrack+: {len(sent)} of {len(outcomes)} {what} sent ({posted} posted now, "
        f"{len(sent) - posted} already there), {pending} pending, {refused} refused"
    )
    not_tried = sum(1 for o in outcomes if o.how == "not tried")
    if not_tried:
        click.echo(
            f"vts: QATrack+ stopped the batch: {not_tried} more {'run' if not_tried == 1 else 'runs'} not tried",
            err=True,
        )
    if pending:
        click.echo("vts: runs left pending stay in the outbox; `vts qa push --pending` retries them", err=True)
    if refused:
        click.echo(
            "vts: refused runs stay in the outbox; fix rig.yaml's qatrack: section (or QATrack+), "
            "then `vts qa push` (without --pending) retries them",
            err=True,
        )
    return code


def _print_plan(rows, as_json: bool) -> None:
    if as_json:
        echo_json({"dry_run": True, "runs": rows})
        return
    if not rows:
        click.echo("QATrack+: nothing to push")
    for r in rows:
        click.echo(f"run {r['run_id']} ({r['procedure']}), key {r['key']}, outbox: {r['outbox']}")
        if "error" in r:
            click.echo(f"  would be refused: {r['error']}")
            continue
        click.echo(
            f"  to {r['qatrack']}: unit {r['unit']!r}, test list {r['test_list']!r}, "
            f"{r['work_started']} .. {r['work_completed']} ({r['time_zone']}, the site's clock)"
        )
        for macro, value in r["values"].items():
            click.echo(f"    {macro:<20} {'skipped (not measured)' if value is None else value}")
        click.echo(f"  attachments: {', '.join(r['attachments']) or '-'}")
    click.echo(f"dry run: {len(rows)} run(s), nothing posted")


push_option = click.option(
    "--push",
    "push_after",
    is_flag=True,
    help="Then post the stored run to QATrack+ (rig.yaml's qatrack: section); a "
    "failed push is said in one line and left in the outbox, the exit "
    "status stays the QA's.",
)


def check_push_config(rig) -> None:
    """--push: the qatrack section and its credentials, before the QA runs."""
    qatrack_config(rig).credentials()


def push_after_qa(rig, run_id, as_json: bool, store_url: str | None = None) -> None:
    """Push the run just stored (--push); one line on stderr for how it went (never an exit code)."""
    from vts_hw.qatrack import push_runs
    from vts_hw.store import ResultsStore

    if run_id is None:
        click.echo("vts: --push: the run was not stored, so nothing was pushed", err=True)
        return
    qcfg = qatrack_config(rig)
    try:
        from vts_hw.cli.common import store_target

        with ResultsStore(store_target(rig, store_url), mode="read") as store:
            outcomes = push_runs(store, qcfg, [store.run(run_id)])
    except (
        VtsError,
        OSError,
        KeyError,
    ) as exc:  # the QA is done and stored; a push problem is one line, not its exit code
        click.echo(f"vts: --push: run {run_id} was not pushed to QATrack+: {exc}", err=True)
        return
    o = outcomes[0]
    if o.state == "sent":
        click.echo(f"QATrack+: {o.line()}", err=True)
    else:
        click.echo(
            f"vts: QATrack+: {o.line()}"
            + (
                "; `vts qa push --pending` retries it"
                if o.state == "pending"
                else f"; after a fix, `vts qa push {run_id}` retries it"
            ),
            err=True,
        )
