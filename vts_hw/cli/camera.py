"""`vts camera ...`: snapshot, stream, LED, info and recording of the rig's cameras (any kind)."""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path

import click

from vts_hw.camera import Camera, CameraError, Illumination, Parameters, StreamFellShort, StreamGap
from vts_hw.camera_led import pulse_led, switch_led
from vts_hw.cli import cli
from vts_hw.cli.common import OutputFile, OutputFolder, PositiveSeconds, echo_json, fmt_time, json_option, with_rig
from vts_hw.drivers.registry import check_camera_kinds
from vts_hw.files import write_atomic
from vts_hw.room import Room


@cli.group()
def camera() -> None:
    """Talk to one camera of the rig (or several, for `record`)."""


@contextlib.contextmanager
def _open(rig, name: str) -> Iterator[Camera]:
    """Camera NAME of the rig's room, closed with the room."""
    with Room(rig) as room:
        yield room.camera(name)


@camera.command()
@click.argument("name")
@click.option("-o", "--output", type=OutputFile(), required=True, help="JPEG file to write.")
@with_rig
def snapshot(name: str, output: str, rig) -> None:
    """Save one JPEG from camera NAME, exactly as the camera sent it."""
    with _open(rig, name) as cam:
        frame = cam.snapshot()
    write_atomic(output, frame.jpeg)  # whole or not at all: never a 0-byte or cut JPEG
    click.echo(
        f"{output}: {len(frame.jpeg)} bytes, camera time {fmt_time(frame.camera_time)}, "
        f"received {fmt_time(frame.host_time)}"
    )
    for p in frame.problems:
        click.echo(f"  warning: {p}", err=True)


@camera.command()
@click.argument("name")
@click.option("--seconds", type=PositiveSeconds(), default=None, help="Stop after this long (default: until Ctrl-C).")
@click.option(
    "--fps", type=PositiveSeconds("a frame rate"), default=None, help="Frame rate to ask for (default: the config's)."
)
@with_rig
def stream(name: str, seconds: float | None, fps: float | None, rig) -> None:
    """Print a line per frame of camera NAME's MJPEG stream: sequence, times, latency, size.

    Latency is the host's receive time minus the camera's capture stamp, with the camera's
    clock offset (measured first) taken out; the stamps have 10 ms resolution. Drops and
    stalls reconnect; missing frames are printed as gaps.
    """
    with _open(rig, name) as cam:
        off = cam.clock_offset()
        click.echo(
            f"# clock: camera - host = {off.offset_s:+.4f} s (± {off.uncertainty_s * 1000:.0f} ms, "
            f"{off.method}); latency = receive - capture with that offset taken out",
            err=True,
        )
        # without --seconds, a camera that sends nothing is given up on, not waited for for ever
        s = cam.stream(
            fps=fps, duration=seconds, give_up_after=None if seconds else max(10.0, 3 * getattr(cam, "timeout", 5.0))
        )
        interrupted, given_up = False, None
        click.echo(f"{'frame':>6}  {'camera time':<23}  {'host receive time':<23}  {'latency':>10}  {'size':>9}")
        try:
            for item in s:
                if isinstance(item, StreamGap):
                    click.echo(f"GAP   after frame {item.after_seq}: {item.missing} frame(s) missing ({item.reason})")
                    continue
                lat = (
                    "-"
                    if item.camera_time is None
                    else f"{(item.host_time - item.camera_time + off.offset_s) * 1000:+7.1f} ms"
                )
                click.echo(
                    f"{item.seq:6d}  {fmt_time(item.camera_time)}  {fmt_time(item.host_time)}  "
                    f"{lat:>10}  {len(item.jpeg):7d} B"
                )
        except KeyboardInterrupt:
            s.stop()
            interrupted = True
        except CameraError as exc:  # gave up: the counts first, then why
            given_up = exc
        st = s.stats
        click.echo(
            f"{st.frames} frames, {st.missing} missing in {st.gaps} gap(s), {st.torn} torn, "
            f"{st.reconnects} reconnect(s)",
            err=True,
        )
        for note in st.problems:
            click.echo(f"  note: {note}", err=True)
    if given_up is not None:
        raise given_up
    short = s.shortfall(interrupted)
    if short:
        raise StreamFellShort(name, short)


@camera.command()
@click.argument("name")
@click.argument("state", type=click.Choice(["on", "off", "pulse"]))
@click.argument("ms", type=click.IntRange(1, 60000), required=False)
@with_rig
def led(name: str, state: str, ms: int | None, rig) -> None:
    """Switch the LED ring of camera NAME: on, off, or pulse MS milliseconds; then read it back
    from the camera. Exit 4 when the camera does not show the switch (it did not take)."""
    if state == "pulse" and ms is None:
        raise click.UsageError("pulse needs a duration in milliseconds, e.g. `led cam1 pulse 300`")
    with _open(rig, name) as cam:
        got = pulse_led(cam, ms) if state == "pulse" and ms is not None else switch_led(cam, state == "on")
    port = getattr(cam, "led_port", None) if isinstance(cam, Illumination) else None  # none sent to without the role
    where = f"output port {port}" if port is not None else "no port"
    noop = "" if isinstance(cam, Illumination) else " (a no-op on this camera: it cannot switch an LED)"
    if got.state is None:
        said = f"sent; whether it took is {got.words()}"
    elif state == "pulse":
        said = (
            f"read back: seen on, then {got.words()}"
            if got.seen_on
            else f"read back: {got.words()} after it; not seen on while it lasted (too short to read), not confirmed"
        )
    else:
        said = f"read back: {got.words()}"
    click.echo(f"{name}: LED {state}{f' {ms} ms' if state == 'pulse' else ''} ({where}): {said}{noop}")


@camera.command()
@click.argument("name")
@json_option
@with_rig
def info(name: str, as_json: bool, rig) -> None:
    """Device info, VAPIX version, image settings and clock offset of camera NAME."""
    cfg = rig.camera(name)
    with _open(rig, name) as cam:
        dev = cam.device_info()
        vapix = getattr(cam, "vapix_version", None) or None
        image = cam.get_params("Image.I0") if isinstance(cam, Parameters) else {}
        off = cam.clock_offset()
    data = {
        "camera": name,
        "kind": cfg.kind,
        "url": cfg.base_url,
        "vapix": vapix,
        "device": dev,
        "image": image,
        "clock_offset_s": round(off.offset_s, 4),
        "clock_offset_uncertainty_s": round(off.uncertainty_s, 4),
        "clock_method": off.method,
        "clock_source": off.source,
    }
    if as_json:
        echo_json(data)
        return
    click.echo(f"{name}  {cfg.base_url}  " + (f"VAPIX {vapix}" if vapix else f"kind {cfg.kind}"))
    for k, v in dev.items():
        click.echo(f"  {k}: {v}")
    for k, v in image.items():
        click.echo(f"  {k}: {v}")
    click.echo(
        f"  clock: camera - host = {off.offset_s:+.3f} s (± {off.uncertainty_s:.3f} s, {off.method})"
        + ("; no camera clock: times are host receipt times" if off.source == "receipt" else "")
    )


EXIT_CODES = {"complete": 0, "partial": 4, "failed": 4, "interrupted": 130}


@camera.command()
@click.argument("names", nargs=-1)
@click.option("--all", "all_cameras", is_flag=True, help="Record every camera of the rig.")
@click.option("--seconds", type=PositiveSeconds(), required=True, help="How long to record.")
@click.option(
    "-o", "--output", "out", type=OutputFolder("recording folder"), required=True, help="Recording folder to create."
)
@click.option(
    "--append", is_flag=True, help="Add to the recording already in the folder, keeping every entry of its manifest."
)
@with_rig
def record(names: tuple[str, ...], all_cameras: bool, seconds: float, out: str, append: bool, rig) -> None:
    """Record cameras NAMES... at once into a recording folder.

    Per camera: NAME.mjpeg (the JPEGs exactly as received), NAME.index.csv, and one
    manifest.json. Every frame is written as it arrives; Ctrl-C keeps what was recorded. A
    folder that already holds a recording is never changed, unless --append adds to it.

    \b
    Exit status: 0 complete (every camera streamed the whole time; frames a camera
    skipped are counted and shown); 4 partial or failed (a camera recorded nothing, failed,
    or lost its stream: one sentence per camera says why); 3 a file could not be written
    (e.g. disk full: what was kept is said); 2 bad input; 130 interrupted.
    """
    from vts_hw.cli.progress import record_with_progress
    from vts_hw.recording.capture import FrameRecorder

    if all_cameras:
        names = tuple(c.name for c in rig.cameras)
    if not names:
        raise click.UsageError("name at least one camera, or give --all")
    cfgs = [rig.camera(n) for n in names]  # unknown names and unset passwords: before any file
    for cfg in cfgs:
        cfg.password()
    check_camera_kinds(cfgs)
    meta = {"rig": rig.rig, "seconds_asked": seconds, "rig_digest": rig.digest}
    with Room(rig) as room:  # the cameras closed with it, however the recording ends
        rec = FrameRecorder([room.camera(c.name) for c in cfgs], out, seconds=seconds, meta=meta, append=append)
        manifest = record_with_progress(rec, seconds)
    status = manifest["status"]
    click.echo(f"{out}: status {status}" + (" (added to the recording already there)" if append else ""))
    for name in names:
        m = manifest["cameras"][name]
        added = f" (+{rec.recording.writers[name].frames_added})" if append else ""
        click.echo(
            f"  {name}: {m['frames']} frames{added}, {m['dropped_frames']} dropped, "
            f"{m.get('torn_frames_discarded', 0)} torn, {m.get('reconnects', 0)} reconnect(s) "
            f"-> {Path(out) / m['mjpeg']}"
        )
    for problem in rec.problems():
        click.echo(f"vts: {problem}", err=True)
    if rec.write_failure is not None:
        sys.exit(rec.write_failure.exit_code)
    code = EXIT_CODES.get(status, 4)
    if code == 130:
        click.echo(f"vts: interrupted; what was recorded is kept in {out}", err=True)
    sys.exit(code)
