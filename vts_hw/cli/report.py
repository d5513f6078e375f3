"""`vts report ...`: trend reports from the results store."""

from __future__ import annotations

import click

from vts_hw.cli import cli
from vts_hw.cli.common import OutputFile, config_option, echo_json, json_option, rig_if_any

ALL_RIGS = "all"

rig_option = click.option(
    "--rig",
    "rig_name",
    default=None,
    metavar="NAME|all",
    help="The rig (room) whose runs the report shows: a rig name as runs are stored with it "
    "(rig.yaml's `rig:`), or `all` for every rig in the store (default: the config's rig).",
)

since_option = click.option(
    "--since",
    default="60d",
    show_default=True,
    help="Period to show: 60d, 8w, 12h, a UTC date such as 2026-09-01, or all. A period "
    "reaching back before 1970 or starting in the future is refused (exit 2).",
)


@cli.group()
def report() -> None:
    """Reports from the results store."""


@report.command()
@since_option
@click.option(
    "-o",
    "--output",
    "out",
    type=OutputFile(),
    default="drift-report.html",
    show_default=True,
    help="report.html (self-contained) or report.pdf.",
)
@rig_option
@json_option
@config_option
def drift(since: str, out: str, rig_name: str | None, as_json: bool, config_path) -> None:
    """Drift trend per camera: drift in x and y over time with tolerance and action bands,
    control limits, the LED checks, and a forecast of the day the action level is reached;
    the step test, and the history of the sync checks, SPECT mappings, calibrations and
    motion analyses.

    A trend needs 5 runs over 7 days since the latest baseline, a forecast a significant slope
    (p < 0.05); the report says why when there is none. With --rig all, each rig of the store
    gets its own section (its own cameras, step test and history) in the one file. The file is
    written whole or not at all.

    Exit status: 0 written; 2 a bad --since, -o or --rig; 3 the store or the file could not be
    read or written (a previous report is left as it was).

    Without a rig config (a department's workstation: `vts --store URL report drift --rig
    NAME`), --rig is needed.
    """
    from vts_hw.cli.common import open_store
    from vts_hw.report.renderers import report_format
    from vts_hw.report.times import parse_since

    report_format(out)  # ReportError: one sentence, exit 2 (before the plots' libraries load)
    start = parse_since(since)  # BadSince: one sentence, exit 2
    from vts_hw.report.build import build_drift_report, build_drift_report_every_rig

    rig = rig_if_any(config_path)
    if rig_name is not None:
        name = rig_name
    elif rig is not None:
        name = rig.rig
    else:
        from vts_hw.errors import UsageError

        raise UsageError("no rig config (--config, $VTS_CONFIG or ./rig.yaml), so give --rig NAME or --rig all")
    with open_store(rig, mode="read") as store:
        if name == ALL_RIGS:
            reps = build_drift_report_every_rig(store, out, since=start)
        else:
            _known_rig(store, name, rig_name)
            reps = [build_drift_report(store, out, since=start, rig=name)]
    if as_json:
        echo_json(
            reps[0].results_data()
            if name != ALL_RIGS
            else {"report": "drift", "rig": ALL_RIGS, "out": out, "rooms": [r.results_data() for r in reps]}
        )
    else:
        empty = not any(r.cameras for r in reps)
        click.echo(
            f"wrote {out}"
            + (f" ({len(reps)} rig(s))" if name == ALL_RIGS else "")
            + (" (no completed drift runs in the period)" if empty else "")
        )


def _known_rig(store, name: str, given: str | None) -> None:
    """A --rig NAME that the store holds no run of is a usage mistake (exit 2); the config's
    own rig may have no runs yet (the report then says so)."""
    if given is None:
        return
    rigs = store.rigs()
    if name not in rigs:
        from vts_hw.errors import UsageError

        known = ", ".join(repr(r) for r in rigs) or "none: the store holds no runs"
        raise UsageError(
            f"--rig {name!r}: the store has no runs of that rig (rigs in the store: {known}; or give --rig all)"
        )


@report.command()
@since_option
@click.option(
    "-o",
    "--output",
    "out",
    type=OutputFile(),
    default="rooms.html",
    show_default=True,
    help="rooms.html (self-contained) or rooms.pdf; each room's drift report is "
    "written beside it as <name>-<rig>-drift.html (or .pdf) and linked.",
)
@rig_option
@json_option
@config_option
def rooms(since: str, out: str, rig_name: str | None, as_json: bool, config_path) -> None:
    """One page over every rig (room) in the results store: each camera's latest daily QA state
    (OK / TOLERANCE / ACTION, or "no daily QA yet" — never OK without data) with a drift
    sparkline, the days since the last step test, calibration and SPECT mapping, the open ACTION
    items, and a link to the room's full drift report (written beside the page).

    An ACTION item is open while the latest completed result of the same check (procedure,
    camera or subject, quantity) is ACTION; a later OK or TOLERANCE result closes it. The
    page's footnote says so; motion analyses (a patient's scan) are not listed.

    --rig NAME shows one room; the default (and --rig all) every rig in the store. Every file
    is written whole or not at all. The store is `vts --store URL`, $VTS_STORE, else the rig
    config's (a department's workstation needs no rig config).

    Exit status: 0 written; 2 a bad --since, -o or --rig; 3 the store or a file could not be
    read or written (a previous file is left as it was).
    """
    from vts_hw.cli.common import open_store
    from vts_hw.report.renderers import report_format
    from vts_hw.report.times import parse_since

    report_format(out)
    start = parse_since(since)
    from vts_hw.report.build import build_rooms_report

    rig = rig_if_any(config_path)
    with open_store(rig, mode="read") as store:
        rigs = None
        if rig_name not in (None, ALL_RIGS):
            _known_rig(store, rig_name, rig_name)
            rigs = [rig_name]
        rep = build_rooms_report(
            store, out, since=start, rigs=rigs, progress=None if as_json else (lambda m: click.echo(m, err=True))
        )
    if as_json:
        echo_json(rep.results_data())
    else:
        no_daily = [r.label for r in rep.rooms if not r.has_daily]
        click.echo(
            f"wrote {out} ({len(rep.rooms)} room(s)"
            + (f"; no daily QA in the period: {', '.join(no_daily)}" if no_daily else "")
            + ")"
        )
