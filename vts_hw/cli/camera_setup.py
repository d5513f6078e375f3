"""`vts camera setup NAME|--all`: set each Axis camera for the VTS and lock what was set."""

from __future__ import annotations

import sys

import click

from vts_hw.camera import CameraError, Parameters, Setup
from vts_hw.cli.camera import camera
from vts_hw.cli.common import echo_json, json_option, with_rig
from vts_hw.drivers.registry import kind_has
from vts_hw.errors import UsageError
from vts_hw.rig_file import check_rewritable
from vts_hw.room import Room


@camera.command("setup")
@click.argument("names", nargs=-1)
@click.option("--all", "all_cameras", is_flag=True, help="Set up every camera of the rig.")
@click.option("--dry-run", is_flag=True, help="Say what would be set, touching no camera and no file.")
@json_option
@with_rig
def setup(names: tuple[str, ...], all_cameras: bool, dry_run: bool, as_json: bool, rig) -> None:
    """Set and read back what the VTS needs on each camera NAME (or --all).

    Resolution, frame rate and compression (the camera's entry), exposure and white balance
    held, no text overlay, the clock on NTP and its time zone (rig.yaml's camera_setup:
    section; the Time API on current firmware, VAPIX 2 parameters on old firmware). What was
    set and read back is written into rig.yaml as each camera's locked_params (its comments
    kept; the previous file kept as rig.yaml.bak), so the daily QA checks exactly that.

    \b
    Exit status: 0 every camera set; 2 bad input (unknown camera, not an Axis camera, unset
    password variable); 3 rig.yaml could not be written (the cameras are set: run again);
    4 a camera refused a value or could not be reached (one sentence each says which and
    why; the cameras that took everything are written).
    """
    if all_cameras:
        names = tuple(c.name for c in rig.cameras)
    if not names:
        raise click.UsageError("name at least one camera, or give --all")
    cfgs = [rig.camera(n) for n in names]
    for cfg in cfgs:
        if not kind_has(cfg, Setup):
            lacks = "no setup" if kind_has(cfg, Parameters) else "no parameters"
            raise UsageError(
                f"camera {cfg.name} is of kind {cfg.kind}, which has {lacks}: only Axis cameras are set up"
            )
        cfg.password()
    source = getattr(rig, "_source", None)
    if source is None:
        raise UsageError("the rig config was not read from a file: nowhere to write locked_params")
    if not dry_run:  # a rig.yaml that cannot be replaced is said before any camera is set
        check_rewritable(source)
    if dry_run:
        with Room(rig) as room:
            for cfg in cfgs:
                cam = room.camera(cfg.name)
                assert isinstance(cam, Setup)  # (its kind has the role: checked above)
                plan = cam.setup_plan(cfg, rig.camera_setup)
                click.echo(f"{cfg.name}: " + ", ".join(f"{k}={v}" for k, v, _ in plan))
        return
    with Room(rig) as room:
        results, failures = _set_all(room, cfgs, rig.camera_setup, as_json)
    written = backup = None
    if results:
        from vts_hw.rig_file import set_locked_params

        backup = set_locked_params(source, {r.camera: r.locked for r in results})
        written = source
    if as_json:
        echo_json(
            {
                "cameras": [
                    {"camera": r.camera, "locked_params": r.locked, "changed": r.changed, "notes": r.notes}
                    for r in results
                ],
                "failed": [{"camera": n, "error": e} for n, e in failures],
                "written": str(written) if written else None,
                "backup": str(backup) if backup else None,
            }
        )
    elif written:
        click.echo(
            f"{written}: locked_params of {', '.join(r.camera for r in results)} written "
            f"(the previous file is {backup})"
        )
    for _name, error in failures:
        click.echo(f"vts: {error}", err=True)
    if failures:
        sys.exit(4)


def _set_all(room, cfgs, setup_cfg, quiet: bool):
    """Each camera of the room in turn: a camera that fails does not stop the others."""
    results, failures = [], []
    for cfg in cfgs:
        try:
            cam = room.camera(cfg.name)
            assert isinstance(cam, Setup)  # (its kind has the role: checked before)
            r = cam.set_up(cfg, setup_cfg)
        except CameraError as exc:
            failures.append((cfg.name, str(exc)))
            continue
        results.append(r)
        if not quiet:
            click.echo(f"{cfg.name}: {len(r.locked)} parameters set and read back ({len(r.changed)} changed)")
            for k, v in r.locked.items():
                click.echo(f"    {k} = {v}" + ("   (changed)" if k in r.changed else ""))
            for note in r.notes:
                click.echo(f"    note: {note}")
    return results, failures
