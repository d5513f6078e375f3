"""`vts qa steps`: the 7-sphere step test, VTS against SPECT."""

from __future__ import annotations

import datetime as _dt
import os
import sys
from pathlib import Path

import click

from vts_hw.cli.common import FiniteFloat, OutputFolder, ask_a_person, config_option, echo_json, json_option
from vts_hw.cli.qa import qa
from vts_hw.tolerance import State


def _default_out() -> Path:
    return Path(f"steps-{_dt.datetime.now().strftime('%Y%m%d-%H%M%S')}")


def _print(analysis, extra_lines, as_json, data_extra=None) -> None:
    if as_json:
        data = analysis.results_data()
        data.update(data_extra or {})
        echo_json(data)
        return
    click.echo(analysis.results())
    for line in extra_lines:
        click.echo(line)


@qa.command()
@click.option(
    "--sim",
    is_flag=True,
    help="Run the whole chain on a simulated rig of its own: stereo "
    "calibration from rendered checkerboards, VTS -> SPECT mapping, then the steps with the "
    "simulated table and SPECT; scored against the truth.",
)
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the simulated rig (--sim).")
@config_option
@click.option(
    "-o",
    "--out",
    "out_dir",
    type=OutputFolder("step test folder"),
    default=None,
    help="Session folder: snapshots, positions.json, volumes (--sim), the plot [default: steps-YYYYmmdd-HHMMSS].",
)
@click.option(
    "--volumes",
    type=click.Path(file_okay=False),
    default=None,
    help="Folder of the SPECT's reconstructed volumes, one per position named after it "
    "(baseline.*, V01.*, ..., A01.*, ..., free.*). Real rig only.",
)
@click.option(
    "--calibration",
    "calibration_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="Camera calibration file (default: the config's calibration.cameras).",
)
@click.option(
    "--mapping",
    "mapping_path",
    type=click.Path(dir_okay=False),
    default=None,
    help="VTS -> SPECT transform file (default: the config's calibration.mapping).",
)
@click.option(
    "--analyze",
    "analyze_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="Do not acquire: analyse the positions a session saved in this folder (with "
    "--volumes), e.g. when the reconstructions arrive after the VTS part.",
)
@click.option(
    "--frames",
    type=click.IntRange(1, 100),
    default=10,
    show_default=True,
    help="Snapshots per camera and position (their centroids are averaged).",
)
@click.option("--vertical", type=click.IntRange(0, 50), default=10, show_default=True, help="Vertical steps.")
@click.option("--axial", type=click.IntRange(0, 50), default=10, show_default=True, help="Axial steps.")
@click.option(
    "--step-mm",
    type=FiniteFloat(1.0, 100.0, what="a step in mm"),
    default=10.0,
    show_default=True,
    help="Nominal step (what the operator is asked to move).",
)
@click.option(
    "--store",
    "store_url",
    default=None,
    help="Results store URL or SQLite file (default: the config's; with --sim OUT/results.sqlite).",
)
@click.option("--dry-run", is_flag=True, help="List the steps without touching the rig or the store.")
@click.option("--operator", default=lambda: os.environ.get("USER", ""), help="Who runs it.")
@click.option(
    "--push",
    "push_after",
    is_flag=True,
    help="Then post the stored run to QATrack+ (the rig config's qatrack: section, see `vts qa "
    "push`); a failed push is one line on stderr and stays in the outbox; the exit status "
    "stays the test's.",
)
@json_option
def steps(
    sim,
    seed,
    config_path,
    out_dir,
    volumes,
    calibration_path,
    mapping_path,
    analyze_dir,
    frames,
    vertical,
    axial,
    step_mm,
    store_url,
    dry_run,
    operator,
    push_after,
    as_json,
) -> None:
    """The 7-sphere step test: is the VTS a measuring instrument?

    Baseline, VERTICAL steps of about 1 cm up, AXIAL steps of about 1 cm along the table, then a
    free turn and shift of the phantom. On the real rig the operator moves the table when asked
    and presses Enter; the SPECT's reconstructions of the positions are read from --volumes. At
    each position a stereo snapshot gives the spheres in 3D, mapped into the SPECT frame.

    Reported and stored: per axis the regression of VTS against SPECT (slope, intercept, R²),
    the VTS-SPECT distances (max, mean, SD), and the 6-DOF move from the first position to the
    last as each system sees it, with the differences; tolerance states, and a plot.
    Exit status: 0 OK, 10 TOLERANCE, 20 ACTION; 2-5 when the test could not run.
    """
    from vts_hw.procedures.daily import EXIT_CODES
    from vts_hw.procedures.steps import step_plan

    plan = step_plan(vertical, axial, step_mm)
    push_rig = None
    if push_after and not dry_run:  # the qatrack section and its credentials, before the test runs
        from vts_hw.cli.qa_push import check_push_config
        from vts_hw.config import load_rig

        push_rig = load_rig(config_path)
        check_push_config(push_rig)
    out = Path(out_dir) if out_dir else (Path(analyze_dir) if analyze_dir else _default_out())
    if sim:
        if analyze_dir or volumes:
            raise click.UsageError("--sim makes its own volumes; it takes no --analyze or --volumes")
        if dry_run:
            click.echo("1. bring up a simulated rig (2 cameras on 127.0.0.1) with the 7-sphere phantom")
            click.echo("2. stereo calibration from 20 rendered checkerboard views (50 mm squares)")
            click.echo("3. VTS -> SPECT mapping from the phantom and a simulated SPECT volume")
            for i, p in enumerate(plan, 4):
                click.echo(
                    f"{i}. {p.label}: the simulated table moves; {frames} snapshots per camera; "
                    "the simulated SPECT writes its volume"
                )
            click.echo(
                f"{len(plan) + 4}. analyse, score against the truth, store in {store_url or out / 'results.sqlite'}"
            )
            return
        state, run_id, url, not_written = _run_sim(out, seed, frames, vertical, axial, store_url, operator, as_json)
    else:
        state, run_id, url, not_written = _run_rig(
            config_path,
            out,
            plan,
            volumes,
            calibration_path,
            mapping_path,
            analyze_dir,
            frames,
            store_url,
            dry_run,
            operator,
            as_json,
        )
    if push_rig is not None and not (dry_run and not analyze_dir):
        from vts_hw.cli.qa_push import push_after_qa

        push_after_qa(push_rig, run_id, as_json, store_url=url)
    if not_written:
        click.echo(f"vts: {not_written}", err=True)
        sys.exit(3)
    sys.exit(EXIT_CODES[state])


def _open_store(url):
    from vts_hw.store import ResultsStore

    return ResultsStore(url)


def _not_stored(stored, analysis, as_json) -> str | None:
    """The store did not take the run: one sentence (the unsaved file's) said now, exit 3 at the end."""
    from vts_hw.cli.common import say_stored

    if stored is None or stored.ok:
        return None
    say_stored(stored, analysis, "step test", as_json)
    return None if stored.unsaved is None else f"the step test is kept in {stored.unsaved}"


def _run_sim(out, seed, frames, vertical, axial, store_url, operator, as_json):
    from vts_hw.sim_devices.scenarios.step_chain import run_sim_steps

    say = (lambda m: None) if as_json else (lambda m: click.echo(m, err=True))
    url = store_url or f"sqlite:///{(out / 'results.sqlite').resolve()}"
    out.mkdir(parents=True, exist_ok=True)
    with _open_store(url) as store:
        res = run_sim_steps(
            out,
            seed,
            frames=frames,
            n_vertical=vertical,
            n_axial=axial,
            store=store,
            operator=operator or "sim",
            progress=say,
        )
    s = res.scores
    lines = [
        "Against the simulated truth:",
        f"  VTS 3D positions: RMS {s['position_rms_mm']:.3f} mm, max {s['position_max_mm']:.3f} mm "
        f"(through the measured mapping: RMS {s['mapped_rms_mm']:.3f} mm)",
        f"  6-DOF move: rotation off by {s['move_rotation_error_deg']:.4f} deg, translation by "
        f"{s['move_translation_error_mm']:.3f} mm",
        f"  SPECT centroids: RMS {s['spect_centroid_rms_mm']:.3f} mm",
        (f"run {res.run_id} stored in {url}" if res.run_id is not None else "NOT stored")
        + f"; plot {res.artifacts[0] if res.artifacts else '-'}",
    ]
    _print(res.analysis, lines, as_json, {"sim_truth": s, "run_id": res.run_id, "out": str(out)})
    return res.analysis.state, res.run_id, url, _not_stored(res.stored, res.analysis, as_json)


def _run_rig(
    config_path,
    out,
    plan,
    volumes,
    calibration_path,
    mapping_path,
    analyze_dir,
    frames,
    store_url,
    dry_run,
    operator,
    as_json,
):
    from vts_hw.config import load_rig
    from vts_hw.drivers.registry import check_camera_kinds
    from vts_hw.procedures.mapping_inputs import calibrated_cameras
    from vts_hw.procedures.step_test import run_step_test, step_session, step_test_inputs
    from vts_hw.room import Room

    rig = load_rig(config_path)
    inputs = step_test_inputs(rig, calibration_path, mapping_path, volumes)
    say = (lambda m: None) if as_json else (lambda m: click.echo(m, err=True))

    def ask(text):
        return ask_a_person(
            text, "the step test", "run it at a terminal, or analyse steps already recorded with --analyze DIR"
        )

    with Room(rig) as room:  # the cameras it opens are closed with it
        cfgs = [] if analyze_dir else calibrated_cameras(rig, inputs.calibration)
        check_camera_kinds(cfgs)
        cameras = [room.camera(c.name) for c in cfgs]
        if dry_run and not analyze_dir:
            for i, step in enumerate(step_session(cameras, inputs, out, plan, frames=frames).plan(), 1):
                click.echo(f"{i:2d}. {step}")
            return State.OK, None, None, None
        from vts_hw.cli.common import store_target
        from vts_hw.store.recorder import record

        # opened first: a store that cannot be opened stops here, before the operator's work
        with _open_store(store_target(rig, store_url)) as store:
            res = run_step_test(
                rig, inputs, out, plan, cameras=cameras, analyze_dir=analyze_dir, frames=frames, ask=ask, progress=say
            )
            stored = record(
                store,
                res.analysis,
                rig=rig.rig,
                operator=operator,
                config_digest=rig.digest,
                tolerances=rig.tolerances,
                started=res.started,
                artifacts=res.artifacts,
            )
    run_id = stored.run_id
    _print(
        res.analysis,
        [(f"run {run_id} stored" if stored.ok else "NOT stored") + f"; plot {res.plot or 'not written'}"],
        as_json,
        {
            "run_id": run_id,
            "out": str(out),
            "not_written": [str(res.plot_error)] if res.plot_error else [],
            **({} if stored.ok else {"unsaved_file": str(stored.unsaved) if stored.unsaved else None}),
        },
    )
    # the test is stored and printed; a plot a full disk could not take is said at the end (exit 3)
    lost = _not_stored(stored, res.analysis, as_json)
    if res.plot_error:
        kept = f"stored as run {run_id}" if stored.ok else "not stored"
        lost = f"{res.plot_error}; the step test is {kept} and its figures are above"
    return res.analysis.state, run_id, store_url, lost
