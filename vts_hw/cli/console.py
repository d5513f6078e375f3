"""`vts console`: serve the room console (a local web page) for the rig."""

from __future__ import annotations

import click

from vts_hw.cli import cli
from vts_hw.cli.common import config_option


@cli.command()
@config_option
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to serve on. Only this machine (127.0.0.1, ::1, localhost) for now: off it the "
                   "console needs users and login, which are not built yet (refused, exit 2).")
@click.option("--port", type=click.IntRange(0, 65535), default=8040, show_default=True,
              help="Port to serve on (0: any free one; the address is printed).")
@click.option("--scans-dir", type=click.Path(file_okay=False), default=".", show_default=True,
              help="Folder the Scan page's scans go into, each a new scan-YYYYmmddTHHMMSSZ folder as `vts scan "
                   "start` names it; the motion report and exports go into the scan's folder.")
def console(config_path: str | None, host: str, port: int, scans_dir: str) -> None:
    """Serve the room console: a web page of the room's cameras, live.

    The Room page shows every camera's live picture with the markers found on it (numbered),
    what the camera is doing (LIVE, RECORDING, IDLE, NOT ANSWERING), its LED ring with a
    switch, its clock offset and its latest daily QA from the results store. A picture that is
    not live is greyed with its age. The console opens a camera's stream only while a page
    watches it, one stream per camera whatever the number of pages, and never a second one to
    a camera that a recording in the console reads. Open the printed address in a browser
    (Chromium, Firefox); Ctrl-C stops it (exit 0). A port in use or a bad rig.yaml: one
    sentence, exit 2.
    """
    from vts_hw.config import load_rig
    from vts_hw.console.serve import check_host, serve
    from vts_hw.cli.common import store_target
    from vts_hw.store import ResultsStore

    check_host(host)
    rig = load_rig(config_path)
    target = store_target(rig)

    def open_store():
        return ResultsStore(target, mode="read")

    serve(rig, host=host, port=port, open_store=open_store, scans_dir=scans_dir,
          on_ready=lambda url: click.echo(f"room console of rig {rig.rig}: open {url} (Ctrl-C stops it)"))
    click.echo("room console stopped")
