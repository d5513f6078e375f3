"""What a camera's FrameStream yields, sorted for a test: its frames and its StreamGaps."""

from __future__ import annotations

import time

from vts_hw.drivers.axis_stream import StreamGap


def collect(stream, limit_s: float = 30.0):
    """(frames, gaps) of ``stream`` until it ends; stopped after ``limit_s`` (a hang guard)."""
    frames, gaps = [], []
    t0 = time.monotonic()
    for item in stream:
        (gaps if isinstance(item, StreamGap) else frames).append(item)
        if time.monotonic() - t0 > limit_s:
            stream.stop()
    return frames, gaps
