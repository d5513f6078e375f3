"""Push runs to QATrack+ through the store's outbox: never twice, never lost.

For each run: ``outbox_add(run, "qatrack", "vts-run-<uid>")`` first (the row is the promise),
then one attempt:

1. the payload is built from the store (a measurement with no macro: "refused" here, nothing
   posted);
2. QATrack+ is asked for an instance with that ``user_key``; one there: the row is "sent" with
   its URL and nothing is posted (a push that got through but whose answer was lost);
3. the instance is posted: 201 -> "sent" with its URL; a 400 saying the user key exists (a
   race) -> asked again, "sent"; another 4xx -> "refused" with QATrack+'s own words (kept until
   the user fixes the mapping and names the run again); down, timeout, 5xx, 429 -> "pending"
   with the error (retried by ``vts qa push --pending``).

When QATrack+ is not answering at all, or refuses the credentials, the batch stops: the runs
not yet tried stay "pending" (nothing is lost; the next --pending takes them).
See docs/decisions/0042-qatrack-push.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

from vts_hw.errors import UsageError, VtsError
from vts_hw.qatrack.client import AuthRefused, QATrackClient, Refused, Unreachable
from vts_hw.qatrack.payload import (
    PUSHABLE_STATUSES,
    NotMapped,
    RepeatedHour,
    build_payload,
    run_key,
    tests_of,
    work_instants,
    work_times,
)
from vts_hw.site_time import instant_of, site_zone, zone_disagreement

TARGET = "qatrack"
#: the outcomes that stop a batch and make the push exit 4 although nothing was refused for the run
STOPPERS = ("credentials refused", "wrong time zone", "posted at a wrong time")
#: exit codes of `vts qa push` (and what --push adds to nothing: the QA's own code stands)
EXIT_SENT, EXIT_PENDING, EXIT_REFUSED = 0, 3, 4


class ZoneMismatch(VtsError):
    """The site shows times in another zone than qatrack.time_zone: the batch stops."""

    def __init__(self, message: str, outcome=None):
        super().__init__(message)
        self.outcome = outcome


@dataclass
class Outcome:
    """What became of one run: ``state`` is the outbox state after the attempt ("sent",
    "pending", "refused"); ``how`` says more ("posted", "already there", "already sent",
    "not mapped", "not tried", "failed", "refused", "credentials refused")."""

    run_id: int
    procedure: str
    key: str
    state: str
    how: str
    message: str = ""
    remote: str = ""

    def as_dict(self) -> dict:
        return asdict(self)

    def line(self) -> str:
        head = f"run {self.run_id} ({self.procedure})"
        if self.state == "sent":
            return f"{head}: {self.how} in QATrack+ {self.remote}".rstrip() + (
                f" ({self.message})" if self.message else ""
            )
        if self.state == "refused":
            return f"{head}: refused, kept in the outbox: {self.message}"
        return f"{head}: left pending ({self.how}): {self.message}"


def exit_code(outcomes: list[Outcome]) -> int:
    """0 every run sent (or already there); 4 any refused (or the credentials or the site's time
    zone wrong); else 3 any left pending."""
    states = {o.state for o in outcomes}
    if "refused" in states or any(o.how in STOPPERS for o in outcomes):
        return EXIT_REFUSED
    if "pending" in states:
        return EXIT_PENDING
    return EXIT_SENT


def select_runs(store, qcfg, rig_name: str, run_ids=(), pending: bool = False) -> list:
    """The runs to push. Named ids: those (UsageError for one not in the store, not this rig's,
    or not a finished result). ``pending``: the outbox's pending rows of this rig (a refusal
    is not repeated by a cron job). Neither: every finished run of this rig whose procedure
    has a list in ``qatrack.lists`` and that is not sent yet (never tried, pending or refused:
    what a person runs after fixing the mapping)."""
    if run_ids:
        out = []
        for rid in run_ids:
            try:
                run = store.run(int(rid))
            except KeyError:
                raise UsageError(f"no run {rid} in the results store {store.url}") from None
            if run.rig != rig_name:
                raise UsageError(
                    f"run {rid} is rig {run.rig!r}'s, not {rig_name!r}'s: push it with that "
                    f"rig's config (its QATrack+ unit)"
                )
            if run.status not in PUSHABLE_STATUSES:
                raise UsageError(
                    f"run {rid} is {run.status}: only finished QA results ({', '.join(PUSHABLE_STATUSES)}) are pushed"
                )
            out.append(run)
        return out
    if pending:
        ids = [i.run_id for i in store.outbox_items(TARGET, states=("pending",))]
        runs = [store.run(i) for i in ids]
        return [r for r in runs if r.rig == rig_name]
    sent = {i.run_id for i in store.outbox_items(TARGET, states=("sent",))}
    return [
        r
        for r in store.runs(procedure=tuple(qcfg.lists), status=PUSHABLE_STATUSES)
        if r.rig == rig_name and r.id not in sent
    ]


def _record(store, item, state: str, how: str, run, message: str = "", remote: str | None = None) -> Outcome:
    store.outbox_record(item.id, state, error=message, remote=remote)
    return Outcome(run.id, run.procedure, item.key, state, how, message, remote or "")


def push_one(store, qcfg, client: QATrackClient, run, item=None, before_post=None) -> Outcome:
    """One attempt at one run (its outbox row ``item``, added first when not given). Unreachable
    (down) and AuthRefused propagate after the row is recorded "pending", so that the caller
    can stop the batch."""
    if item is None:
        item = store.outbox_add(run.id, TARGET, run_key(run))
    if item.state == "sent":
        return Outcome(run.id, run.procedure, item.key, "sent", "already sent", remote=item.remote)
    try:
        tests_of(store, qcfg, run)  # the mapping and the times first: cheap, and before any request
        work_times(qcfg, run)
    except RepeatedHour as exc:
        return _record(store, item, "refused", "repeated hour", run, str(exc))
    except NotMapped as exc:
        return _record(store, item, "refused", "not mapped", run, str(exc))
    lst = qcfg.lists[run.procedure]
    try:
        utc = client.assignment(qcfg.unit, lst.test_list)
        there = client.instance_with_key(item.key)
        if there:
            return _record(store, item, "sent", "already there", run, remote=there)
        if before_post is not None:
            before_post()
        try:
            payload = build_payload(store, qcfg, run)  # the attachments are rendered only to be posted
        except (VtsError, OSError) as exc:  # e.g. no room for the report in the temporary folder
            return _record(store, item, "pending", "failed", run, f"the attachments could not be made: {exc}")
        try:
            made = client.create_instance(payload.body(utc))
        except Refused as exc:
            if exc.status == 400 and "user key" in exc.words.lower():  # posted meanwhile
                there = client.instance_with_key(item.key)
                if there:
                    return _record(store, item, "sent", "already there", run, remote=there)
            raise
        dropped = sorted(set(payload.data["tests"]) - set(made.get("tests") or payload.data["tests"]))
        note = (
            (
                f"QATrack+ kept no value for {', '.join(dropped)}: not tests of its list "
                f"{lst.test_list!r} (check the macro names)"
            )
            if dropped
            else ""
        )
        wrong = landed_wrong(qcfg, run, made)
        if wrong:
            return _record(store, item, "sent", "posted at a wrong time", run, wrong, remote=str(made.get("url") or ""))
        return _record(store, item, "sent", "posted", run, note, remote=str(made.get("url") or ""))
    except AuthRefused as exc:
        _record(store, item, "pending", "credentials refused", run, str(exc))
        raise
    except ZoneMismatch as exc:
        _record(store, item, "pending", "wrong time zone", run, str(exc))
        raise
    except Refused as exc:
        return _record(store, item, "refused", "refused", run, str(exc))
    except Unreachable as exc:
        out = _record(store, item, "pending", "failed", run, str(exc))
        if exc.down:
            raise
        return out


def landed_wrong(qcfg, run, made: dict) -> str:
    """ "" when QATrack+ shows the new instance's work times at the run's true instants (to the
    second); else one sentence (qatrack.time_zone is not the site's zone, or its clock rules differ)."""
    for what, key, t in zip(("start", "end"), ("work_started", "work_completed"), work_instants(run)):
        try:
            shown = instant_of(str(made.get(key)))  # "None" when missing: a ValueError
        except (TypeError, ValueError):
            return f"QATrack+ answered the new instance without its {key} as a time with an offset"
        if abs(shown - t) >= 1.0:
            return (
                f"QATrack+ shows the run's {what} as {made.get(key)}, {shown - t:+.0f} s from the "
                f"true instant: qatrack.time_zone {qcfg.time_zone} is not the site's TIME_ZONE (correct "
                f"rig.yaml, and this instance's times in QATrack+)"
            )
    return ""


def check_zone(qcfg, client: QATrackClient) -> str:
    """ "" when the times the site shows agree with ``qatrack.time_zone``; else one sentence."""
    differs = zone_disagreement(site_zone(qcfg.time_zone), client.shown_times())
    return (
        (
            f"qatrack.time_zone {qcfg.time_zone} is not the site's TIME_ZONE: {differs}; set qatrack.time_zone to "
            f"the site's zone so that the work times land at their true instants"
        )
        if differs
        else ""
    )


def push_runs(
    store,
    qcfg,
    runs: list,
    client: QATrackClient | None = None,
    progress: Callable[[int, int, Outcome], None] | None = None,
) -> list[Outcome]:
    """Push ``runs`` one by one; every run gets its outbox row before the first request.
    Before the first post, the times the site shows are checked against ``qatrack.time_zone``.
    Stops at the first run QATrack+ does not answer at all or whose credentials it refuses, or
    when the site's zone is not ``qatrack.time_zone``: the rest stay "pending" ("not tried")."""
    items = {r.id: store.outbox_add(r.id, TARGET, run_key(r)) for r in runs}
    own = client is None
    site = QATrackClient(qcfg.url, qcfg.credentials(), timeout=qcfg.timeout_s) if client is None else client
    out: list[Outcome] = []
    zone = {"checked": False}

    def before_post():
        """The site's zone against qatrack.time_zone, once a batch (again if it could not be asked)."""
        if zone["checked"]:
            return
        try:
            wrong = check_zone(qcfg, site)
        except Unreachable as exc:
            if exc.down:
                raise
            return  # asked again before the next post; each post is checked too
        zone["checked"] = True
        if wrong:
            raise ZoneMismatch(wrong)

    try:
        for n, run in enumerate(runs, 1):
            try:
                o = push_one(store, qcfg, site, run, items[run.id], before_post)
                if o.how == "posted at a wrong time":
                    raise ZoneMismatch(o.message, o)
            except (Unreachable, AuthRefused, ZoneMismatch) as exc:
                if isinstance(exc, ZoneMismatch) and exc.outcome is not None:
                    out.append(exc.outcome)
                else:
                    why = (
                        "credentials refused"
                        if isinstance(exc, AuthRefused)
                        else "wrong time zone"
                        if isinstance(exc, ZoneMismatch)
                        else "failed"
                    )
                    out.append(Outcome(run.id, run.procedure, items[run.id].key, "pending", why, str(exc)))
                if progress:
                    progress(n, len(runs), out[-1])
                for rest in runs[n:]:
                    it = items[rest.id]
                    if it.state != "sent":
                        out.append(
                            Outcome(
                                rest.id,
                                rest.procedure,
                                it.key,
                                it.state if it.state == "refused" else "pending",
                                "not tried",
                                f"not tried: {exc}",
                            )
                        )
                    else:
                        out.append(Outcome(rest.id, rest.procedure, it.key, "sent", "already sent", remote=it.remote))
                break
            out.append(o)
            if progress:
                progress(n, len(runs), o)
    finally:
        if own:
            site.close()
    return out


def dry_run(store, qcfg, runs: list) -> list[dict]:
    """What a push would post for each run (nothing rendered, nothing sent, no credential)."""
    rows = []
    for run in runs:
        item = next(iter(store.outbox_items(TARGET, run_ids=[run.id])), None)
        row = {
            "run_id": run.id,
            "procedure": run.procedure,
            "key": run_key(run),
            "outbox": item.state if item else "not in the outbox",
            "qatrack": qcfg.url,
            "unit": qcfg.unit,
            "time_zone": qcfg.time_zone,
        }
        try:
            p = build_payload(store, qcfg, run, attach=False)
        except NotMapped as exc:
            row.update(error=str(exc))
        else:
            row.update(
                test_list=p.test_list,
                work_started=p.data["work_started"],
                work_completed=p.data["work_completed"],
                comment=p.data["comment"],
                values=p.values,
                attachments=p.attachments,
            )
        rows.append(row)
    return rows
