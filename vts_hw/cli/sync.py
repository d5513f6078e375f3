"""`vts sync ...`: line the VTS and the SPECT list-mode up in time."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import click

from vts_hw.cli import cli
from vts_hw.cli.common import config_option, echo_json, json_option

EXIT_CODES = {"OK": 0, "TOLERANCE": 10, "ACTION": 20}   # as the QA procedures (procedures/daily.py)


@cli.group()
def sync() -> None:
    """Time synchronisation of a scan session with the SPECT list-mode."""


def _calibration_files(config_path, calibration, mapping):
    """--calibration/--mapping, else the rig config's calibration section (relative paths from
    the rig.yaml's folder), and the rig config (None without one).
    ConfigError when there is no stereo calibration at all."""
    from vts_hw.config import load_rig
    from vts_hw.errors import ConfigError, VtsError

    why = ""
    rig = None
    try:
        rig = load_rig(config_path)
    except VtsError as exc:
        if config_path is not None:   # named explicitly: its error is the answer
            raise
        why = f" (no rig config: {exc})"
    if calibration and mapping:
        return Path(calibration), Path(mapping), rig
    base = Path(rig._source).parent if rig is not None and rig._source is not None else Path(".")

    def from_rig(p):
        if p is None:
            return None
        p = Path(p)
        return p if p.is_absolute() else base / p

    cal = Path(calibration) if calibration else from_rig(rig.calibration.stereo if rig else None)
    mp = Path(mapping) if mapping else from_rig(rig.calibration.spect if rig else None)
    if cal is None:
        raise ConfigError("no stereo calibration: give --calibration FILE or set calibration.stereo in "
                          f"rig.yaml{why}")
    return cal, mp, rig


class _Progress:
    """Frame pairs processed, on stderr: a line per 10 % (and the last)."""

    def __init__(self):
        self.last = -1
        self.t0 = time.monotonic()

    def __call__(self, done: int, total: int) -> None:
        step = int(10 * done / max(total, 1))
        if step != self.last or done == total:
            self.last = step
            click.echo(f"processing the recording: {done}/{total} frame pairs "
                       f"({time.monotonic() - self.t0:.1f} s)", err=True)


@sync.command()
@click.argument("session", type=click.Path())
@click.argument("more", nargs=-1, type=click.Path(), metavar="[LISTMODE]...")
@click.option("--listmode", "listmode", type=click.Path(), multiple=True, metavar="FILE",
              help="The SPECT list-mode file of the same scan. Several files may follow it (a shell "
                   "glob such as sim/spect/scan-*.vtslm): the one whose acquisition overlaps the "
                   "session is taken.")
@click.option("--clock-slack", type=click.FloatRange(0, 3600), default=None, metavar="SECONDS",
              help="How far the SPECT's wall clock may be off the host's when matching a list-mode to "
                   "the session (default: 10 s).")
@click.option("--calibration", type=click.Path(dir_okay=False), default=None,
              help="Stereo calibration file (default: the rig config's calibration.stereo).")
@click.option("--mapping", type=click.Path(dir_okay=False), default=None,
              help="VTS -> SPECT transform file (default: the rig config's calibration.spect).")
@click.option("-o", "--output", "out", type=click.Path(dir_okay=False), default=None,
              help="Write the HTML report here (self-contained: the plot inline).")
@click.option("--plot", "plot_path", type=click.Path(dir_okay=False), default=None,
              help="Also write the plot as a PNG here.")
@click.option("--export", "export_dir", type=click.Path(file_okay=False), default=None,
              help="Export the marker trajectories in the SPECT frame on SPECT time to DIR "
                   "(trajectories.csv and .json, docs/trajectory-format.md).")
@click.option("--marker", type=int, default=None,
              help="The marker id to follow (default: the one with the largest axial range).")
@click.option("--workers", type=click.IntRange(1, 256), default=None,
              help="Processes for the recording (default: every core).")
@json_option
@config_option
def analyze(session, more, listmode, clock_slack, calibration, mapping, out, plot_path, export_dir, marker,
            workers, as_json, config_path) -> None:
    """Put a scan SESSION and its SPECT list-mode on one clock.

    The gating signal gives the SPECT start delay, clock and dead time; the recording gives the
    marker's motion on the host clock; the motion events found in both give the time
    difference of each and the overall offset (VTS - SPECT, median).

    A list-mode whose acquisition (its header's start time and duration) does not overlap the
    session is refused (exit 3), as is a choice of several that overlap; when none belongs, a
    failure record the SPECT left beside the files says why it recorded nothing.

    Exit status like the QA procedures: 0 OK (every event seen by both within 20 ms), 10
    TOLERANCE (within 100 ms, or an event seen by one system only), 20 ACTION. The windows
    are the tolerance table's sync_max_abs_dt_ms, sync_events_one_system and
    sync_events_both (rig.yaml may override them). The check is stored as a run of
    procedure "sync" in the results store (rig.yaml's results.url); when the store cannot take
    it, its figures go to a file that `vts qa import` stores later, and the exit status is 3.
    """
    from vts_hw.procedures.sync import CLOCK_SLACK_S, SyncAnalysis, check_session, export_trajectories
    from vts_hw.report.sync_html import write_sync_html
    from vts_hw.store.results import store_result

    candidates = [*listmode, *more]
    if not candidates:
        raise click.UsageError("give the scan's list-mode: --listmode FILE")
    check_session(session)           # a bad folder says so before anything else is read
    cal, mp, rig = _calibration_files(config_path, calibration, mapping)
    a = SyncAnalysis(session, candidates, cal, mp, marker=marker, workers=workers, progress=_Progress(),
                     clock_slack_s=CLOCK_SLACK_S if clock_slack is None else clock_slack)
    a.analyze(tolerances=rig.tolerances if rig is not None else None)
    data = a.results_data()
    png = None
    if out or plot_path:
        png = a.plot(plot_path)
    if out:
        write_sync_html(data, png, out)
        data["report"] = str(out)
    if export_dir:
        csv_path, json_path = export_trajectories(a.tracks, a.gating, export_dir, mp)
        data["export"] = [str(csv_path), str(json_path)]
    stored = store_result(rig.results.url if rig is not None else None, a,
                          rig=rig.rig if rig is not None else "", notes=f"session {session}",
                          config_digest=rig.digest if rig is not None else "",
                          artifacts=[p for p in (plot_path,) if p])
    data["stored"] = {"run_id": stored.run_id, "unsaved_file": str(stored.unsaved) if stored.unsaved else None}
    if as_json:
        echo_json(data)
    else:
        click.echo(a.results())
        if out:
            click.echo(f"report: {out}")
        if plot_path:
            click.echo(f"plot: {plot_path}")
        if export_dir:
            click.echo(f"trajectories (SPECT frame, SPECT time): {', '.join(data['export'])}")
        if stored.ok:
            click.echo(f"stored: run {stored.run_id} in the results store")
    sys.stdout.flush()
    if not stored.ok:
        where = (f"its figures are above and in {stored.unsaved} (`vts qa import {stored.unsaved}` stores them "
                 "later)" if stored.unsaved else "its figures are above only: no fallback file could be written")
        click.echo(f"vts: the sync check was NOT stored: {stored.error}; {where}", err=True)
        sys.exit(3)
    code = EXIT_CODES[data["summary"]["state"]]
    if code:
        sys.exit(code)
