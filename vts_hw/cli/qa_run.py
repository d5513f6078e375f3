"""The glue between `vts qa` and the procedures: open the store, run, print, exit code."""

from __future__ import annotations

import time
from pathlib import Path

import click

from vts_hw.cli.common import echo_json, fmt_time, open_store, store_target
from vts_hw.room import Room

# the one way a QA run is recorded, shared with the console (vts_hw/console/qa_job.py)
from vts_hw.store.qa_record import artifacts_dir, record_qa  # noqa: F401


def run_qa(rig, steps, cameras, frames, plots, dry_run, operator, as_json, clock=time.time, push=False) -> int:
    from vts_hw.procedures.daily import QARun

    if dry_run:
        run = QARun(rig, steps=steps, cameras=cameras or None, n_frames=frames)
        for i, step in enumerate(run.plan(store_target(rig).url or "the default results store"), 1):
            click.echo(f"{i:2d}. {step}")
        return 0
    from vts_hw.drivers.registry import check_camera_kinds

    check_camera_kinds(rig.camera(n) for n in (cameras or [c.name for c in rig.cameras]))
    with Room(rig, clock=clock, store=store_target(rig)) as room:  # the store first; each camera when its turn comes
        store = room.store
        run = QARun(
            rig,
            steps=steps,
            cameras=cameras or None,
            n_frames=frames,
            plots=plots,
            artifacts_dir=artifacts_dir(store),
            clock=clock,
            open_camera=lambda cfg: room.camera(cfg.name),
            progress=lambda m: click.echo(m, err=True) if not as_json else None,
        )
        result, stored = record_qa(store, run, rig, operator=operator, clock=clock)
    data = result.results_data()
    if result.store_error:
        data["unsaved_file"] = str(stored.unsaved) if stored.unsaved else None
    if as_json:
        echo_json(data)
    else:
        click.echo(result.results())
        if result.artifacts:
            click.echo(f"  saved: {Path(result.artifacts[0]).parent}")
    if push:  # --push: the stored run to QATrack+; how it went is one line, never the exit code
        from vts_hw.cli.qa_push import push_after_qa

        push_after_qa(rig, None if result.store_error else result.run_id, as_json)
    if result.store_error:
        unsaved = stored.unsaved
        where = (
            f"its figures are above and in {unsaved} (`vts qa import {unsaved}` stores them later)"
            if unsaved
            else "its figures are above only: no fallback file could be written either ("
            + "; ".join(stored.tried)
            + ")"
        )
        click.echo(f"vts: the {result.procedure} run was NOT stored: {result.store_error}; {where}", err=True)
        return 3
    return result.exit_code


def import_runs(rig, files) -> list[tuple[str, int]]:
    from vts_hw.store.recorder import import_unsaved

    with open_store(rig) as store:
        return [(f, import_unsaved(store, f)) for f in files]


def set_baseline(rig, cameras, frames, dry_run, operator, as_json, clock=time.time) -> None:
    from vts_hw.drivers.registry import check_camera_kinds
    from vts_hw.procedures.baseline import take_baselines
    from vts_hw.store.recorder import record

    names = cameras or [c.name for c in rig.cameras]
    cfgs = [rig.camera(n) for n in names]
    for cfg in cfgs:  # unknown names, kinds, unset password variables: before anything is touched
        cfg.password()
    check_camera_kinds(cfgs)
    if dry_run:
        for n in names:
            click.echo(f"{n}: LED on, {frames} snapshots, detect the wall markers, store them as the baseline")
        return
    with Room(rig, clock=clock, store=store_target(rig)) as room:  # the store first, then the cameras
        store = room.store
        cams = [room.camera(cfg.name) for cfg in cfgs]
        result = take_baselines(cams, frames=frames, clock=clock, rig=rig)
        started = clock()
        stored = record(
            store,
            result,
            rig=rig.rig,
            operator=operator,
            config_digest=rig.digest,
            tolerances=rig.tolerances,
            started=started,
            finished=started,
            clock=clock,
        )
    baselines, run_id = result.baselines, stored.run_id
    if as_json:
        echo_json(
            {
                "run_id": run_id,
                "baselines": [
                    {"camera": b.camera, "taken": b.taken, "markers": [m.__dict__ for m in b.markers]}
                    for b in baselines
                ],
                "not_wall": {b.camera: [{"x": x, "y": y, **r.to_dict()} for x, y, r in b.others] for b in baselines},
                "room": result.room_why or "placed",
                **({} if stored.ok else {"unsaved_file": str(stored.unsaved) if stored.unsaved else None}),
            }
        )
    else:
        for b in baselines:
            click.echo(
                f"{b.camera}: baseline of {len(b.markers)} markers set {fmt_time(b.taken)} "
                + (f"(run {run_id})" if run_id is not None else "(NOT stored)")
            )
            for m in b.markers:
                click.echo(f"    {m.id}: ({m.x:.2f}, {m.y:.2f}) px")
            for x, y, r in b.others:
                click.echo(f"    not a wall marker at ({x:.0f}, {y:.0f}) px: {r.role}: {r.reason}")
        if result.room_why:
            click.echo(f"  where the still markers lie was not checked: {result.room_why}")
    if not stored.ok:
        from vts_hw.cli.common import say_stored

        say_stored(stored, result, "baseline", as_json)
        raise SystemExit(3)
