"""`vts demo`: the main job on a simulated rig, end to end."""

from __future__ import annotations

import time
from pathlib import Path

import click

from . import cli


@cli.command()
@click.option("-o", "--output", "out", type=click.Path(file_okay=False), default="demo-out", show_default=True,
              help="Folder for what the demo writes.")
@click.option("--seconds", type=float, default=3.0, show_default=True, help="Length of the recording.")
@click.option("--cameras", "n_cameras", type=click.IntRange(1, 8), default=2, show_default=True)
def demo(out: str, seconds: float, n_cameras: int) -> None:
    """Bring up a simulated rig, snapshot every camera, light the LEDs, record both, and say what was written."""
    from ..drivers.axis import AxisCamera
    from ..recorder import Recorder
    from ..recording import info
    from ..sim_devices.rig import SimRig
    from .progress import record_with_progress

    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    with SimRig(n_cameras=n_cameras) as rig, rig.env():
        rig.write(out_dir / "sim")
        cfg = rig.config()
        click.echo(f"simulated rig up: {', '.join(f'{c.name} at {c.base_url}' for c in cfg.cameras)}")
        cams = [AxisCamera.from_config(c) for c in cfg.cameras]
        for cam in cams:
            dev = cam.device_info()
            off = cam.clock_offset()
            click.echo(f"{cam.name}: {dev.get('ProdNbr', '?')} firmware {dev.get('Version', '?')}, "
                       f"VAPIX {cam.vapix_version}, clock {off.offset_s:+.3f} s against this host")
            cam.led_off()
            dark = cam.snapshot()
            cam.led_on()
            time.sleep(0.05)
            lit = cam.snapshot()
            (out_dir / f"{cam.name}-led-off.jpg").write_bytes(dark.jpeg)
            (out_dir / f"{cam.name}-led-on.jpg").write_bytes(lit.jpeg)
            click.echo(f"  wrote {out_dir / f'{cam.name}-led-on.jpg'} and {cam.name}-led-off.jpg "
                       f"({_bright(lit.jpeg)} vs {_bright(dark.jpeg)} bright pixels)")
        rec_dir = out_dir / "recording"
        click.echo(f"recording {seconds:g} s from {len(cams)} cameras into {rec_dir} ...")
        manifest = record_with_progress(Recorder(cams, rec_dir, seconds=seconds, meta={"rig": cfg.rig}), seconds)
    for s in info(rec_dir):
        gaps = sum(g["missing"] for g in s.gaps)
        click.echo(f"  {rec_dir / (s.source + '.mjpeg')}: {s.frames} frames at {s.fps} fps, {gaps} missing")
    click.echo(f"  {rec_dir / 'manifest.json'}: status {manifest['status']}")
    click.echo(f"done; inspect with: vts recording info {rec_dir}")


def _bright(jpeg: bytes) -> int:
    import cv2
    import numpy as np
    img = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_GRAYSCALE)
    return int((img > 128).sum())
