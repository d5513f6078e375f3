"""Live progress of a recording in the terminal (rich), with Ctrl-C handled."""

from __future__ import annotations

import sys
import time

from rich.console import Console
from rich.live import Live
from rich.table import Table

from vts_hw.recording.capture import FrameRecorder


def _table(rec: FrameRecorder, seconds: float | None, t0: float) -> Table:
    elapsed = time.monotonic() - t0
    title = f"recording {elapsed:5.1f} s" + (f" of {seconds:g} s" if seconds else "") + "  (Ctrl-C stops)"
    t = Table(title=title, title_justify="left")
    for col in ("camera", "frames", "fps", "dropped", "reconnects", "state"):
        t.add_column(col, justify="right" if col not in ("camera", "state") else "left")
    for p in rec.progress.values():
        state = p.error or ("ok" if p.last_frame and time.monotonic() - p.last_frame < 2 else "waiting")
        t.add_row(p.name, str(p.frames), f"{p.fps:.1f}", str(p.dropped), str(p.reconnects), state)
    return t


def record_with_progress(rec: FrameRecorder, seconds: float | None) -> dict:
    """Run a recording to its end (or Ctrl-C) showing a live table on a terminal."""
    console = Console(stderr=True)
    t0 = time.monotonic()
    rec.start()
    status = None
    try:
        if console.is_terminal:
            with Live(_table(rec, seconds, t0), console=console, refresh_per_second=4) as live:
                rec.wait(on_tick=lambda r: live.update(_table(r, seconds, t0)))
        else:
            last = [time.monotonic()]

            def tick(r):
                if time.monotonic() - last[0] >= 5:
                    last[0] = time.monotonic()
                    parts = [f"{p.name} {p.frames} frames" for p in r.progress.values()]
                    print(f"[{time.monotonic() - t0:5.1f} s] " + ", ".join(parts), file=sys.stderr)

            rec.wait(on_tick=tick)
    except KeyboardInterrupt:
        status = "interrupted"
    return rec.finish(status)
